"""Contact force averaged over a control step's physics steps (`mean_contact_force_n`)."""

import numpy as np
import pytest

from cathsim_dmc.control.policies import make_policy
from cathsim_dmc.sim import physics as cs_physics
from cathsim_dmc.suite.gym import CathSimEnv

INTO_THE_ARCH = 45  # expert steps after which the BCA type I wire (seed 0) touches the wall


def _drive_into_the_arch(env, sensing=True):
    """Expert steps from seed 0; returns the infos. `sensing=False` detaches the callback."""
    observation, _ = env.reset(seed=0)
    if not sensing:
        env.physics.after_constraint_solve = None
    policy = make_policy("expert", seed=0)
    infos = []
    for _ in range(INTO_THE_ARCH):
        observation, _, _, _, info = env.step(policy(observation, env))
        infos.append(info)
    return infos


@pytest.fixture(scope="module")
def env():
    env = CathSimEnv(task="bca", aorta="type1", obs="internal")
    yield env
    env.close()


def test_sensing_leaves_the_dynamics_unchanged(env):
    sensed = _drive_into_the_arch(env)
    joints_sensed = env.physics.data.qpos.copy()
    plain = _drive_into_the_arch(env, sensing=False)
    np.testing.assert_array_equal(env.physics.data.qpos, joints_sensed)
    np.testing.assert_array_equal([i["contact_force_n"] for i in plain], [i["contact_force_n"] for i in sensed])
    # Without the callback the mean falls back to the end-of-step force.
    assert all(i["mean_contact_force_n"] == i["contact_force_n"] for i in plain)


def test_mean_and_peak_are_over_every_physics_step(env):
    _drive_into_the_arch(env)
    physics, task = env.physics, env.task
    wire = np.zeros(physics.model.ngeom, dtype=bool)
    wire[physics.bind(task.guidewire.geoms).element_id] = True
    vessel = np.zeros(physics.model.ngeom, dtype=bool)
    vessel[task.aorta.wall_geom_ids(physics)] = True
    task_callback, samples = physics.after_constraint_solve, []

    def spy(p):
        # The full contact-frame path, at the point where contacts and forces agree.
        samples.append(cs_physics.wire_contacts(p, wire, recompute=False, is_vessel_geom=vessel).total_n)
        task_callback(p)

    physics.after_constraint_solve = spy
    means, ends = [], []
    for _ in range(10):
        samples.clear()
        _, _, _, _, info = env.step(np.array([0.5, 0.0], np.float32))
        assert len(samples) == round(task.control_timestep / physics.model.opt.timestep)
        assert info["mean_contact_force_n"] == pytest.approx(np.mean(samples), rel=1e-9, abs=1e-12)
        assert info["peak_contact_force_n"] == pytest.approx(np.max(samples), rel=1e-9, abs=1e-12)
        means.append(info["mean_contact_force_n"])
        ends.append(info["contact_force_n"])
    assert max(means) > 0.01  # the wire is pushed along the arch wall: contact throughout


def test_contact_force_observation_is_the_step_mean():
    """The `contact_force` observation (an extra) is the step's mean wall force, not the
    force of the step's last physics step; at reset, the start state's force."""
    env = CathSimEnv(task="bca", aorta="type1", obs="internal", extra_observations=("contact_force",))
    try:
        observation, info = env.reset(seed=0)
        assert observation["contact_force"][0] == pytest.approx(info["contact_force_n"], abs=1e-6)
        policy = make_policy("expert", seed=0)
        differ = 0
        for _ in range(INTO_THE_ARCH + 10):
            observation, _, terminated, truncated, info = env.step(policy(observation, env))
            assert observation["contact_force"][0] == pytest.approx(info["mean_contact_force_n"], rel=1e-6, abs=1e-6)
            differ += abs(info["mean_contact_force_n"] - info["contact_force_n"]) > 1e-3
            if terminated or truncated:  # the expert reaches the BCA in 54 steps under `fast`
                break
        assert differ >= 5  # the two readings do differ in contact
    finally:
        env.close()


def test_mean_and_end_of_step_force_agree_on_average_at_rest(env):
    """Held still against the wall, the wire's contacts keep chattering (the number of
    contacts changes from one physics step to the next). Both labels then estimate the
    same load: their averages over the hold agree, and the step mean jumps less from one
    step to the next (the load itself may still creep while the shaft settles, so the
    scatter is taken between consecutive steps, not around the hold's mean)."""
    _drive_into_the_arch(env)
    ends, means = [], []
    for step in range(50):
        _, _, _, _, info = env.step(np.zeros(2, np.float32))
        if step >= 20:  # after the push has relaxed
            ends.append(info["contact_force_n"])
            means.append(info["mean_contact_force_n"])
    assert np.mean(means) > 0.01
    assert np.mean(means) == pytest.approx(np.mean(ends), rel=0.15)
    assert np.std(np.diff(means)) < 0.5 * np.std(np.diff(ends))


def _expert_run(env, complete_stepped_state=True):
    """(state after each step, infos, observations) of the expert run, with or without the
    cheap completion of each stepped state (without it the binding read forwards in full).
    The state includes the acceleration stage (qacc, actuator forces), which the completion
    computes."""
    observation, _ = env.reset(seed=0)
    if not complete_stepped_state:
        env.physics.complete_stepped_state = lambda: None
    policy = make_policy("expert", seed=0)
    qpos, infos, observations = [], [], []
    for _ in range(INTO_THE_ARCH):
        observation, _, _, _, info = env.step(policy(observation, env))
        data = env.physics.data
        qpos.append(np.concatenate([data.qpos, data.qvel, data.qacc, data.actuator_force]))
        infos.append(info)
        observations.append(observation)
    if not complete_stepped_state:
        del env.physics.complete_stepped_state
    return qpos, infos, observations


def test_completing_the_stepped_state_changes_nothing_but_its_cost(env):
    qpos_cheap, infos_cheap, obs_cheap = _expert_run(env)
    # The completion ran: nothing left for a binding read to forward.
    assert not env.physics.is_dirty
    qpos_full, infos_full, obs_full = _expert_run(env, complete_stepped_state=False)
    np.testing.assert_array_equal(qpos_cheap, qpos_full)
    for cheap, full in zip(infos_cheap, infos_full):
        for key in ("contact_force_n", "mean_contact_force_n", "drive_force_n", "slack_m", "tip_position_m"):
            np.testing.assert_array_equal(cheap[key], full[key], err_msg=key)
    for cheap, full in zip(obs_cheap, obs_full):
        assert cheap.keys() == full.keys()
        for key in cheap:
            np.testing.assert_array_equal(cheap[key], full[key], err_msg=key)


def test_a_write_after_the_step_keeps_the_full_forward_due(env):
    env.reset(seed=0)
    physics = env.physics
    physics.bind(env.task.robot.actuators).ctrl = [1e-3, 0.0]
    physics.step()
    moved = physics.data.qpos.copy()
    moved[0] += 1e-3
    physics.bind(env.task.robot.joints[:1]).qpos = moved[:1]  # written after the step
    physics.complete_stepped_state()
    assert physics.is_dirty  # the next binding read forwards the written state in full
    physics.forward()
    physics.bind(env.task.robot.actuators).ctrl = [1e-3, 0.0]
    physics.step()
    physics.complete_stepped_state()
    assert not physics.is_dirty
