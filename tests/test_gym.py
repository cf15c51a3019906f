"""The Gymnasium adapter: checkers, seeding, info."""

import gymnasium
import numpy as np
import pytest

import cathsim_dmc  # noqa: F401  (registers the ids)
from cathsim_dmc import tasks
from cathsim_dmc.core.registry import env_id
from cathsim_dmc.suite.gym import CathSimEnv


def test_every_pair_is_registered():
    for task, aorta in tasks.ALL_TASKS:
        assert env_id(task, aorta) in gymnasium.registry


def test_a_random_arch_has_an_id_of_its_own():
    env = gymnasium.make("cathsim_dmc/bca-random-v0", aorta_params={"pool_size": 1})
    _, info = env.reset(seed=0)
    assert env.spec.id == "cathsim_dmc/bca-random-v0" and info["aorta"].startswith("random")
    env.close()


def test_an_id_cannot_be_made_into_another_environment():
    # gymnasium.make's keywords would leave spec.id naming the id's own (task, aorta)
    with pytest.raises(ValueError, match="use gymnasium.make\\('cathsim_dmc/bca-type2-v0'\\)"):
        gymnasium.make("cathsim_dmc/bca-type1-v0", aorta="type2")
    with pytest.raises(ValueError, match="use CathSimEnv\\(task='bca', aorta='/a/folder'\\)"):
        gymnasium.make("cathsim_dmc/bca-type1-v0", aorta="/a/folder")


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
    assert {
        "tip_position_m",
        "target_distance_m",
        "contact_force_n",
        "mean_contact_force_n",
        "success",
        "diverged",
        "escaped",
    } <= set(info)
    done = False
    while not done:
        _, _, terminated, truncated, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
        done = terminated or truncated
        assert ("is_success" in info) == done  # the episode's outcome, at its last step only
    assert truncated and not terminated and info["step"] == 3 and not info["is_success"]
    env.close()


def test_invalid_actions_raise_before_physics_and_the_env_stays_usable():
    env = CathSimEnv("bca", "type1", max_steps=2)
    with pytest.raises(RuntimeError, match=r"call reset\(\)"):
        env.step(np.zeros(2))
    env.reset(seed=0)
    physics = env.physics
    for bad, match in [
        ([np.nan, 0.0], r"action=\[nan, 0\.0\] is not finite"),
        (np.array([0.0, -np.inf], np.float32), r"action=\[ 0\., -inf\] is not finite"),
        ([1.0], r"action=\[1\.0\] has shape \(1,\); expected shape \(2,\)"),
        (np.zeros((1, 2)), r"has shape \(1, 2\)"),
        ("ab", r"action='ab' is not numeric"),
    ]:
        time_s, qpos = physics.data.time, physics.data.qpos.copy()
        with pytest.raises(ValueError, match=match) as error:
            env.step(bad)
        assert "\n" not in str(error.value) and "[insertion, rotation] in [-1, 1]" in str(error.value)
        assert physics.data.time == time_s and np.array_equal(physics.data.qpos, qpos)
    # Out of range is clipped, as documented.
    _, _, terminated, truncated, _ = env.step(np.array([3.0, -2.0], np.float32))
    robot = env.task.robot
    np.testing.assert_allclose(
        physics.bind(robot.actuators).ctrl, [robot.max_insertion_speed_m_s, -robot.max_rotation_speed_rad_s]
    )
    assert not (terminated or truncated)
    _, _, terminated, truncated, _ = env.step(np.zeros(2))
    assert truncated
    with pytest.raises(RuntimeError, match=r"call reset\(\)"):
        env.step(np.zeros(2))
    env.reset()
    assert env.step(np.zeros(2))[1] < 0
    env.close()


# SAC as the recipe builds it (a small network: nothing is trained here).
ALGO = dict(
    learning_rate=3e-4,
    buffer_size=400,
    learning_starts=1000,
    batch_size=8,
    tau=0.005,
    gamma=0.99,
    train_freq=1,
    gradient_steps=1,
    target_update_interval=1,
    target_entropy=-2.0,
    ent_coef="auto_1.0",
    net_arch=[16],
    share_features_extractor=False,
)


def _stored_episode(max_steps, seed=0, diverge_at=None):
    """One scripted-expert episode on the type I LCCA, stepped as SB3's off-policy loop
    steps it: a DummyVecEnv (which turns terminated/truncated into `done` and
    `TimeLimit.truncated` and resets) and SAC's own `_store_transition` into the replay
    buffer training uses. `diverge_at`: blow the state up before that step.
    Returns the buffer, the number of transitions and the last step's info."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from cathsim_dmc.control.expert import CenterlineExpert
    from cathsim_dmc.learning.rl.train import build_sac, make_env_fn

    vec = DummyVecEnv([make_env_fn("lcca", "type1", "internal", seed, {"max_steps": max_steps})])
    model = build_sac(vec, ALGO, seed, "cpu", None)
    model._setup_learn(max_steps)  # resets the vector env with `seed`, as learn() does
    env, expert = vec.envs[0].unwrapped, CenterlineExpert()
    for step in range(1, max_steps + 1):
        if step == diverge_at:
            env.physics.data.qvel[:] = np.nan
        action = model.policy.scale_action(expert(None, env))[None]
        new_obs, rewards, dones, infos = vec.step(action)
        model._store_transition(model.replay_buffer, action, new_obs, rewards, dones, infos)
        if dones[0]:
            break
    vec.close()
    return model.replay_buffer, step, infos[0]


def test_replay_buffer_bootstraps_time_limits_and_divergence_but_not_a_success():
    """SAC's target is r + gamma (1 - done) Q(s'): a time limit or a divergence must be
    stored as a timeout (done but bootstrapped), reaching the target as terminal, also
    when the target is reached on the last allowed step."""
    from cathsim_dmc.learning.rl.demos import expert_transitions

    # The same expert episode (seed 0) as demonstrations, the way training records them,
    # to find the step on which it reaches the target.
    demo_env = CathSimEnv("lcca", "type1", obs="internal")
    demos = expert_transitions(demo_env, episodes=1, seed=0)
    demo_env.close()
    reach = len(demos)
    assert demos.successes == 1 and 20 < reach < 300

    # Success on the last allowed step: terminal, not a timeout.
    buffer, steps, info = _stored_episode(max_steps=reach)
    assert steps == reach and info["step"] == reach and info["success"] and info["is_success"]
    assert not info["TimeLimit.truncated"]
    samples = buffer._get_samples(np.arange(steps))
    assert samples.dones[:, 0].tolist() == [0.0] * (steps - 1) + [1.0]
    assert samples.rewards[-1, 0] == pytest.approx(10.0)
    # The same episode: SB3's float32 action rescaling moves an action by an ulp, which the
    # `fast` solver (PGS, 10 iterations) carries on to micrometres by the end (6 um seen).
    np.testing.assert_allclose(buffer.rewards[:steps, 0], demos.rewards, atol=1e-4)

    # One step less: the time limit ends it one step short of the target. Stored done but
    # as a timeout, so sampled as not done, with the last state as the next observation
    # (not the next episode's first).
    buffer, steps, info = _stored_episode(max_steps=reach - 1)
    assert steps == reach - 1 and not info["success"] and info["TimeLimit.truncated"] and not info["is_success"]
    assert buffer.dones[steps - 1, 0] == 1.0 and buffer.timeouts[steps - 1, 0] == 1.0
    samples = buffer._get_samples(np.arange(steps))
    assert not samples.dones.any()
    assert samples.rewards[-1, 0] < 0  # dense: minus the remaining distance
    np.testing.assert_array_equal(
        buffer.next_observations["joint_pos"][steps - 1, 0], info["terminal_observation"]["joint_pos"]
    )
    # The demonstration's state at that step (the episodes drift apart by an ulp's worth, see
    # above: 0.017 rad at most in the wire's joints), far from the next episode's start.
    np.testing.assert_allclose(
        buffer.next_observations["joint_pos"][steps - 1, 0], demos.next_observations["joint_pos"][steps - 1], atol=0.05
    )

    # A divergence truncates: reward 0, a timeout, bootstrapped.
    buffer, steps, info = _stored_episode(max_steps=300, diverge_at=3)
    assert steps == 3 and info["diverged"] and not info["success"] and info["TimeLimit.truncated"]
    assert buffer.rewards[2, 0] == 0.0 and buffer.timeouts[2, 0] == 1.0
    assert not buffer._get_samples(np.arange(steps)).dones.any()

    # Demonstrations follow the same convention: the expert's success is terminal...
    from cathsim_dmc.learning.rl.demos import DemoReplayBuffer, add_transitions

    env = CathSimEnv("lcca", "type1", obs="internal", max_steps=5)
    buffer = DemoReplayBuffer(10, env.observation_space, env.action_space, device="cpu", demo_capacity=reach + 5)
    add_transitions(buffer, demos)
    assert buffer.demos._get_samples(np.arange(reach)).dones[:, 0].tolist() == [0.0] * (reach - 1) + [1.0]
    # ... and its time limit is not.
    add_transitions(buffer, expert_transitions(env, episodes=1, seed=0))
    env.close()
    assert buffer.demos.dones[reach + 4, 0] == 1.0 and buffer.demos.timeouts[reach + 4, 0] == 1.0
    assert not buffer.demos._get_samples(np.arange(reach, reach + 5)).dones.any()
