"""The Gymnasium adapter: checkers, seeding, info."""

import gymnasium
import numpy as np
import pytest

import cathsim_dmc  # noqa: F401  (registers the ids)
from cathsim_dmc import tasks
from cathsim_dmc.gym import CathSimEnv, env_id


def test_every_pair_is_registered():
    for task, aorta in tasks.ALL_TASKS:
        assert env_id(task, aorta) in gymnasium.registry


def test_action_space_is_the_tasks_action_spec():
    env = CathSimEnv("bca", "type1")
    spec = env.dm_env.action_spec()
    assert env.action_space.shape == spec.shape and env.action_space.dtype == spec.dtype
    np.testing.assert_array_equal(env.action_space.low, np.broadcast_to(spec.minimum, spec.shape))
    np.testing.assert_array_equal(env.action_space.high, np.broadcast_to(spec.maximum, spec.shape))
    env.close()


@pytest.mark.parametrize("obs", ["internal", "enn"])
def test_gymnasium_env_checker(obs):
    from gymnasium.utils.env_checker import check_env

    env = gymnasium.make("cathsim_dmc/bca-type1-v0", obs=obs, max_steps=20)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_stable_baselines3_env_checker():
    from stable_baselines3.common.env_checker import check_env

    env = gymnasium.make("cathsim_dmc/lcca-type1-v0", obs="enn", max_steps=20)
    check_env(env.unwrapped, warn=True)
    observation, _ = env.reset(seed=0)
    assert observation["pixels"].shape == (1, 80, 80) and observation["pixels"].dtype == np.uint8
    assert observation["guidewire_mask"].shape == (1, 80, 80)
    env.close()


def _rollout(env, seed, steps=15):
    observation, info = env.reset(seed=seed)
    actions = np.random.default_rng(123).uniform(-1, 1, (steps, 2)).astype(np.float32)
    tips = [info["tip_position_m"]]
    for action in actions:
        observation, reward, terminated, truncated, info = env.step(action)
        tips.append(info["tip_position_m"])
    return np.array(tips), observation["joint_pos"]


def test_seeded_reset_replays_identically():
    env = gymnasium.make("cathsim_dmc/bca-type1-v0")
    tips_a, joints_a = _rollout(env, seed=7)
    tips_b, joints_b = _rollout(env, seed=7)
    tips_c, _ = _rollout(env, seed=8)
    np.testing.assert_array_equal(tips_a, tips_b)
    np.testing.assert_array_equal(joints_a, joints_b)
    assert not np.array_equal(tips_a[0], tips_c[0])  # the start is randomised by the seed
    env.close()


def test_info_and_truncation():
    env = gymnasium.make("cathsim_dmc/bca-type1-v0", max_steps=3)
    _, info = env.reset(seed=0)
    assert {"tip_position_m", "target_distance_m", "contact_force_n", "mean_contact_force_n", "success",
            "diverged", "escaped"} <= set(info)
    done = False
    while not done:
        _, _, terminated, truncated, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
        done = terminated or truncated
    assert truncated and not terminated and info["step"] == 3
    env.close()


def test_invalid_actions_raise_before_physics_and_the_env_stays_usable():
    env = CathSimEnv("bca", "type1", max_steps=2)
    with pytest.raises(RuntimeError, match=r"call reset\(\)"):
        env.step(np.zeros(2))
    env.reset(seed=0)
    physics = env.physics
    for bad, match in [([np.nan, 0.0], r"action=\[nan, 0\.0\] is not finite"),
                       (np.array([0.0, -np.inf], np.float32), r"action=\[ 0\., -inf\] is not finite"),
                       ([1.0], r"action=\[1\.0\] has shape \(1,\); expected shape \(2,\)"),
                       (np.zeros((1, 2)), r"has shape \(1, 2\)"),
                       ("ab", r"action='ab' is not numeric")]:
        time_s, qpos = physics.data.time, physics.data.qpos.copy()
        with pytest.raises(ValueError, match=match) as error:
            env.step(bad)
        assert "\n" not in str(error.value) and "[insertion, rotation] in [-1, 1]" in str(error.value)
        assert physics.data.time == time_s and np.array_equal(physics.data.qpos, qpos)
    # Out of range is clipped, as documented.
    _, _, terminated, truncated, _ = env.step(np.array([3.0, -2.0], np.float32))
    robot = env.task.robot
    np.testing.assert_allclose(physics.bind(robot.actuators).ctrl,
                               [robot.max_insertion_speed_m_s, -robot.max_rotation_speed_rad_s])
    assert not (terminated or truncated)
    _, _, terminated, truncated, _ = env.step(np.zeros(2))
    assert truncated
    with pytest.raises(RuntimeError, match=r"call reset\(\)"):
        env.step(np.zeros(2))
    env.reset()
    assert env.step(np.zeros(2))[1] < 0
    env.close()
