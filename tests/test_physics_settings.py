"""Physics settings (`tasks.load(physics=...)`): each reaches the compiled model, `fast` is
the default, `accurate` is the model as it was before the settings were explicit, `fast`
keeps the wire in the vessel; the wall in the world body and the cheaper contact reads
change no result; `fast_field` builds the distance-field wall, the others the prisms."""

import mujoco
import numpy as np
import pytest

from cathsim_dmc import tasks
from cathsim_dmc.control.policies import make_policy
from cathsim_dmc.sim import physics as cs_physics
from cathsim_dmc.suite.gym import CathSimEnv

# What the compiled model's options were before they were set explicitly (commit 74caa34):
# Newton with MuJoCo's defaults, noslip 5 (tolerance 0) inherited from dm_control's arena.
BEFORE = dict(
    timestep=0.005,
    solver=mujoco.mjtSolver.mjSOL_NEWTON,
    iterations=100,
    tolerance=1e-8,
    ls_iterations=50,
    ls_tolerance=0.01,
    noslip_iterations=5,
    noslip_tolerance=0.0,
    jacobian=mujoco.mjtJacobian.mjJAC_AUTO,
    cone=mujoco.mjtCone.mjCONE_ELLIPTIC,
    integrator=mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    ccd_iterations=35,
    impratio=1.0,
    disableflags=int(mujoco.mjtDisableBit.mjDSBL_MULTICCD),
    enableflags=0,
)
SLEEP = int(mujoco.mjtEnableBit.mjENBL_SLEEP)


def _options(env) -> dict:
    opt = env.physics.model.ptr.opt
    return {key: getattr(opt, key) for key in BEFORE}


def test_fast_is_the_default_and_accurate_the_model_as_before():
    assert _options(tasks.load("bca", "type1")) == _options(tasks.load("bca", "type1", physics="fast"))
    accurate = tasks.load("bca", "type1", physics="accurate")
    assert _options(accurate) == {k: int(v) if not isinstance(v, float) else v for k, v in BEFORE.items()}


@pytest.mark.parametrize("name", ["accurate", "fast", "fast_field"])
def test_each_setting_reaches_the_compiled_model(name):
    settings = cs_physics.PHYSICS_SETTINGS[name]
    env = tasks.load("bca", "type1", physics=name)
    opt = env.physics.model.ptr.opt
    assert opt.solver == int(getattr(mujoco.mjtSolver, f"mjSOL_{settings.solver.upper()}"))
    assert opt.jacobian == int(getattr(mujoco.mjtJacobian, f"mjJAC_{settings.jacobian.upper()}"))
    assert (opt.iterations, opt.tolerance, opt.noslip_iterations, opt.noslip_tolerance) == (
        settings.iterations,
        settings.tolerance,
        settings.noslip_iterations,
        settings.noslip_tolerance,
    )
    assert bool(opt.enableflags & SLEEP) == settings.sleep
    if name.startswith("fast"):
        assert (opt.solver, opt.iterations, opt.jacobian, opt.noslip_iterations) == (
            int(mujoco.mjtSolver.mjSOL_PGS),
            10,
            int(mujoco.mjtJacobian.mjJAC_DENSE),
            0,
        )
    # The wall: one SDF geom carrying its field, or one convex mesh per prism.
    model = env.physics.model.ptr
    wall = env.task.aorta.wall_geom_ids(env.physics)
    if settings.wall == "field":
        assert list(model.geom_type[wall]) == [mujoco.mjtGeom.mjGEOM_SDF]
        assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, model.geom(int(wall[0])).name) >= 0
    else:
        assert len(wall) == env.task.aorta.asset.hull_count
        assert (model.geom_type[wall] == mujoco.mjtGeom.mjGEOM_MESH).all()


@pytest.mark.parametrize(
    "load",
    [
        lambda: tasks.load("bca", "type1", physics="quick"),
        lambda: CathSimEnv(physics="quick"),
        lambda: tasks.check_options(physics="quick"),
    ],
)
def test_an_unknown_setting_is_one_value_error_naming_the_choices(load):
    with pytest.raises(ValueError) as raised:
        load()
    assert (
        str(raised.value)
        == "physics='quick' is not a physics setting; choose one of ['accurate', 'fast', 'fast_field']"
    )


@pytest.mark.parametrize("name", ["accurate", "fast"])
def test_the_wall_in_the_world_body_gives_the_same_trajectory(name):
    """The environment puts the wall pieces into the world body; the plain MJCF path
    leaves them in the aorta's attachment body. Same contacts, same trajectory, bit for bit."""
    world = tasks.load("bca", "type1", seed=0, physics=name)
    frame = tasks.load("bca", "type1", seed=0, physics=name, aorta_options=dict(hulls_in_mjcf=True))
    for env, in_world in ((world, True), (frame, False)):
        wall = env.task.aorta.wall_geom_ids(env.physics)
        assert (env.physics.model.geom_bodyid[wall] == 0).all() == in_world
    rng = np.random.default_rng(3)
    actions = [np.array([1.0, rng.uniform(-1, 1)]) for _ in range(70)]
    runs = []
    for env in (world, frame):
        env.reset()
        qpos, forces = [], []
        for action in actions:
            env.step(action)
            qpos.append(env.physics.data.qpos.copy())
            forces.append(env.task.step_info(env.physics).mean_contact_force_n)
        runs.append((np.array(qpos), np.array(forces)))
    assert max(runs[0][1]) > 0  # the wire reached the wall
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])


@pytest.fixture(scope="module", params=["accurate", "fast", "fast_field"])
def env_in_the_arch(request):
    env = CathSimEnv(task="bca", aorta="type1", obs="internal", physics=request.param)
    observation, _ = env.reset(seed=0)
    policy = make_policy("expert", seed=0)
    for _ in range(40):
        observation, _, _, _, _ = env.step(policy(observation, env))
    yield env
    env.close()


def test_the_end_of_step_forces_are_those_of_a_full_forward(env_in_the_arch):
    """`contact_forces` after a step skips the position and velocity stages, which the
    step left current; a state changed by hand gets a full mj_forward."""
    env = env_in_the_arch
    task, physics = env.task, env.physics
    nonzero = 0
    for step in range(8):
        env.step(np.array([0.6, 0.3 * (-1) ** step]))
        expected = _read_after_full_forward(task, physics)
        task.measurements._contacts = None  # the gym step's info has read them already: read again
        read = task.contact_forces(physics)
        np.testing.assert_array_equal(read.forces_n, expected.forces_n)
        np.testing.assert_array_equal(read.positions_m, expected.positions_m)
        nonzero += read.count > 0
    assert nonzero  # the wire touched the wall in some of these states
    # Moved by hand after the step (positions stale): the read sees the moved state.
    env.step(np.array([0.5, 0.0]))
    physics.data.qpos[:] += 2e-4
    expected = _read_after_full_forward(task, physics)
    task.measurements._contacts = None
    read = task.contact_forces(physics)
    assert read.count
    np.testing.assert_array_equal(read.positions_m, expected.positions_m)
    np.testing.assert_array_equal(read.forces_n, expected.forces_n)


def test_the_per_physics_step_total_is_the_reference_total(env_in_the_arch):
    """`WallForceTotal` (the step mean's callback) equals `total_contact_force_n` at every
    physics step, also with frictionless (one-row) contacts: the guide channel's."""
    env = env_in_the_arch
    task, physics = env.task, env.physics
    wire = task.measurements.wire_mask
    masks = [task.measurements.vessel_mask, ~wire]  # the wall; everything else, channel included
    readers = [cs_physics.WallForceTotal(wire, mask) for mask in masks]
    task_callback, pairs, one_row = physics.after_constraint_solve, [], [0]

    def spy(p):
        for mask, reader in zip(masks, readers):
            pairs.append((cs_physics.total_contact_force_n(p, wire, mask), reader.total_n(p.data.ptr)))
        data = p.data.ptr
        one_row[0] += int((data.contact.dim[: data.ncon] == 1).sum())
        task_callback(p)

    physics.after_constraint_solve = spy
    try:
        for step in range(6):
            env.step(np.array([1.0, 0.5 * (-1) ** step]))
    finally:
        physics.after_constraint_solve = task_callback
    reference, fast = np.array(pairs).T
    np.testing.assert_array_equal(fast, reference)
    assert reference.max() > 0 and one_row[0] > 0


def test_fast_keeps_the_wire_in_and_the_expert_reaches_the_bca():
    env = CathSimEnv(task="bca", aorta="type1", obs="internal", physics="fast")
    observation, _ = env.reset(seed=0)
    policy = make_policy("expert", seed=0)
    try:
        for _ in range(env.task.max_steps):
            observation, _, terminated, truncated, info = env.step(policy(observation, env))
            assert not info["escaped"] and not info["diverged"]
            assert env.task.containment.contains(env.task.wire_points_m(env.physics)).all()
            if terminated or truncated:
                break
        assert info["success"]
    finally:
        env.close()


def _read_after_full_forward(task, physics):
    """Wall contacts of `physics`'s state after a full mj_forward on a copy of its data."""
    model, data = physics.model.ptr, mujoco.MjData(physics.model.ptr)
    mujoco.mj_copyData(data, model, physics.data.ptr)
    mujoco.mj_forward(model, data)
    return cs_physics.wire_contacts(
        _Physics(model, data),
        task.measurements.wire_mask,
        recompute=False,
        is_vessel_geom=task.measurements.vessel_mask,
    )


class _Physics:
    """The two attributes `wire_contacts` reads, for a bare MjData."""

    def __init__(self, model, data):
        self.model = type("Model", (), {"ptr": model})()
        self.data = type("Data", (), {"ptr": data})()
