"""The Gymnasium adapter: checkers, seeding, info."""

import gymnasium
import numpy as np
import pytest

import cathsim_dmc  # noqa: F401  (registers the ids)
from cathsim_dmc import tasks
from cathsim_dmc.gym import env_id


def test_every_pair_is_registered():
    for task, aorta in tasks.ALL_TASKS:
        assert env_id(task, aorta) in gymnasium.registry


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
