"""Every registered (task, aorta) pair: specs, rewards, termination, truncation."""

import numpy as np
import pytest
from shipped import task_params

from cathsim_dmc import tasks
from cathsim_dmc.anatomy import load_asset
from cathsim_dmc.core.shipped import available_aortas, resolve_asset


def test_all_tasks_lists_every_pair():
    assert tasks.ALL_TASKS, "no shipped aorta"
    assert set(tasks.ALL_TASKS) == {(t, a) for t in tasks.TARGETS for a in available_aortas()}


@pytest.mark.parametrize(
    "bad, match",
    [
        (dict(task="xyz"), "task='xyz'.*bca"),
        (dict(aorta="xyz"), "aorta='xyz'.*type1"),
        (dict(obs="xyz"), "obs='xyz'.*enn"),
    ],
)
def test_unknown_names_name_the_choices(bad, match):
    kwargs = dict(task="bca", aorta="type1", obs="internal") | bad
    with pytest.raises(ValueError, match=match):
        tasks.load(**kwargs)


@pytest.mark.parametrize("task, aorta", task_params())
def test_task_observations_rewards_and_truncation(task, aorta):
    env = tasks.load(task, aorta, obs="enn", seed=0, max_steps=5)
    spec = env.observation_spec()
    assert set(spec) == {"pixels", "guidewire_mask", "joint_pos", "joint_vel"}
    timestep = env.reset()
    for key, value in timestep.observation.items():
        assert value.shape == spec[key].shape, key
        assert value.dtype == spec[key].dtype, key
    assert spec["pixels"].shape == (80, 80, 1) and spec["pixels"].dtype == np.uint8
    rng = np.random.default_rng(0)
    target_m = load_asset(resolve_asset(aorta)).sites[task]  # from the asset's files
    tip = env.physics.bind(env.task.guidewire.tip_site)
    steps = 0
    while not timestep.last():
        timestep = env.step(rng.uniform(-1, 1, 2))
        steps += 1
        # Dense reward: minus the straight-line tip-to-target distance in metres (the tip
        # starts ~0.2 m away).
        assert timestep.reward == pytest.approx(-np.linalg.norm(tip.xpos - target_m))
        assert -0.5 < timestep.reward < -0.1
    assert steps == 5 and timestep.discount == 1.0  # time limit: truncation, not termination
    assert env.task.target_position_m.shape == (3,)


def _target_at_the_entry(tmp_path) -> str:
    """A copy of type1 whose lcca site is its entry site, about 1 cm from the wire tip's
    start: with the largest success radius (5 cm) the first step already succeeds."""
    import json
    import shutil

    folder = tmp_path / "lcca_at_entry"
    shutil.copytree(resolve_asset("type1"), folder)
    meta = json.loads((folder / "meta.json").read_text())
    meta["sites"]["lcca"] = meta["entry"]["position"]
    (folder / "meta.json").write_text(json.dumps(meta))
    return str(folder)


@pytest.mark.parametrize("max_steps", [300, 1])
def test_success_terminates_with_reward_and_zero_discount(max_steps, tmp_path):
    # The first step already succeeds. With max_steps=1 it is also the last allowed
    # step: a success still, not a time limit.
    env = tasks.load(
        "lcca",
        _target_at_the_entry(tmp_path),
        obs="internal",
        seed=0,
        delta_m=0.05,
        success_reward=10.0,
        max_steps=max_steps,
    )
    env.reset()
    timestep = env.step(np.zeros(2))
    assert timestep.last() and timestep.reward == 10.0 and timestep.discount == 0.0
    assert env.task.success and env.task.step_count == 1


def test_sparse_reward_is_zero_until_the_target_is_reached(tmp_path):
    rewards = {}
    for dense in (True, False):
        env = tasks.load("lcca", "type1", obs="internal", seed=0, dense=dense, max_steps=4)
        env.reset()
        steps = [env.step(np.array([1.0, 0.3])) for _ in range(4)]
        rewards[dense] = [timestep.reward for timestep in steps]
        assert steps[-1].last() and steps[-1].discount == 1.0
    assert rewards[False] == [0.0] * 4
    assert all(r < -0.1 for r in rewards[True])  # the same steps, dense: minus the ~0.2 m to go
    # Reaching the target pays the success reward, sparse or not.
    env = tasks.load(
        "lcca", _target_at_the_entry(tmp_path), obs="internal", seed=0, dense=False, delta_m=0.05, success_reward=7.0
    )
    env.reset()
    timestep = env.step(np.zeros(2))
    assert timestep.last() and timestep.reward == 7.0 and timestep.discount == 0.0


@pytest.mark.parametrize(
    "bad, match",
    [
        ([np.nan, 0.0], "is not finite"),
        ([0.0, np.inf], "is not finite"),
        ([1.0], r"has shape \(1,\)"),
        ([1.0, 0.0, 0.0], r"has shape \(3,\)"),
        ([[1.0, 0.0]], r"has shape \(1, 2\)"),
        (None, r"action=None has shape \(\)"),
        ("ab", "action='ab' is not numeric"),
        ([1.0, [0.0, 1.0]], r"action=\[1.0, \[0.0, 1.0\]\] is not numeric"),
    ],
)
def test_invalid_actions_raise_before_physics(bad, match):
    env = tasks.load("bca", "type1", seed=0)
    env.reset()
    time_s = env.physics.data.time
    with pytest.raises(ValueError, match=match + r"; expected shape \(2,\), finite, \[insertion, rotation\]"):
        env.step(bad)
    assert env.physics.data.time == time_s
    # Still usable; out-of-range values are clipped.
    timestep = env.step([-4.0, 9.0])
    assert timestep.mid() and env.physics.data.time > time_s
    robot = env.task.robot
    np.testing.assert_allclose(
        env.physics.bind(robot.actuators).ctrl, [-robot.max_insertion_speed_m_s, robot.max_rotation_speed_rad_s]
    )


def test_reset_does_not_recompile():
    env = tasks.load("bca", "type1", seed=0)
    env.reset()
    model = env.physics.model.ptr
    for _ in range(3):
        env.step(np.array([1.0, 0.0]))
    env.reset()
    assert env.physics.model.ptr is model


def test_custom_aorta_is_generated_and_cached(tmp_path, monkeypatch):
    monkeypatch.setenv("CATHSIM_DMC_CACHE", str(tmp_path))
    params = {"preset": "type2", "arch_width_m": 0.065}
    env = tasks.load("lcca", "custom", aorta_params=params, seed=0)
    env.reset()
    timestep = env.step(np.array([1.0, 0.0]))
    assert timestep.mid() and np.isfinite(timestep.reward)
    folders = list((tmp_path / "aortas").iterdir())
    assert len(folders) == 1 and (folders[0] / "meta.json").is_file()
    # Second use: same folder, no rebuild.
    before = (folders[0] / "meta.json").stat().st_mtime_ns
    tasks.load("bca", "custom", aorta_params=params)
    assert [p.name for p in (tmp_path / "aortas").iterdir()] == [folders[0].name]
    assert (folders[0] / "meta.json").stat().st_mtime_ns == before
    with pytest.raises(ValueError, match="only used with aorta='custom'"):
        tasks.load("bca", "type1", aorta_params=params)
