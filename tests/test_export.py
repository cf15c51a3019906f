"""Scene export round trip: every shipped aorta reloads from its folder and simulates."""

import subprocess
import sys

import mujoco
import numpy as np
import pytest
from shipped import aorta_params

from cathsim_dmc import tasks
from cathsim_dmc.sim import geom_groups
from cathsim_dmc.sim.export import START_KEY, export_scene


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """`exported(aorta, **options)`: the reset bca environment and its exported scene, built once
    per module (an export writes thousands of wall meshes); the tests only read them."""
    built = {}

    def get(aorta, **options):
        key = (aorta, tuple(sorted(options.items())))
        if key not in built:
            env = tasks.load("bca", aorta, seed=0, **options)
            env.reset()
            folder = tmp_path_factory.mktemp("export") / aorta
            built[key] = env, export_scene(env, folder)
        return built[key]

    yield get
    for env, _ in built.values():
        env.close()


# The export does not depend on the anatomy: type I runs by default, the other aortas with -m slow.
@pytest.mark.parametrize(
    "aorta", [p if p.values[0] == "type1" else pytest.param(*p.values, marks=pytest.mark.slow) for p in aorta_params()]
)
def test_exported_scene_reloads_and_steps(aorta, exported):
    env, scene = exported(aorta)
    original = env.physics.model.ptr
    model = mujoco.MjModel.from_xml_path(str(scene))

    assert np.array_equal(np.bincount(model.geom_group, minlength=5), np.bincount(original.geom_group, minlength=5))
    assert (model.geom_group == geom_groups.WIRE).sum() > 0
    wall = [
        mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, mujoco.mj_id2name(original, mujoco.mjtObj.mjOBJ_GEOM, i))
        for i in env.task.aorta.wall_geom_ids(env.physics)
    ]
    assert len(wall) == env.task.aorta.asset.hull_count and min(wall) >= 0
    assert env.task.aorta.visual_geom_id(env.physics) >= 0
    # A wall piece's STL holds its hull, so a point inside the hull is dropped; the hull stays.
    assert (model.nq, model.nu, model.nmeshface) == (original.nq, original.nu, original.nmeshface)
    np.testing.assert_allclose(model.geom_pos, original.geom_pos, atol=1e-8)
    np.testing.assert_allclose(model.geom_rbound, original.geom_rbound, atol=1e-8)
    for field in (
        "body_mass",
        "body_inertia",
        "jnt_stiffness",
        "dof_armature",
        "dof_damping",
        "geom_friction",
        "geom_solref",
        "geom_solimp",
        "actuator_gainprm",
        "qpos0",
    ):
        np.testing.assert_array_equal(getattr(model, field), getattr(original, field), err_msg=field)
    assert (model.opt.timestep, model.opt.integrator) == (original.opt.timestep, original.opt.integrator)

    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, START_KEY))
    np.testing.assert_array_equal(data.qpos, env.physics.data.qpos)
    data.ctrl[:] = 1.0  # push the wire in
    for _ in range(100):
        mujoco.mj_step(model, data)
    assert np.isfinite(data.qpos).all()


def test_the_distance_field_wall_exports_as_prisms(exported):
    """MuJoCo alone cannot simulate the field wall (`physics=fast_field`): its export is
    the prism wall's (the default, `physics=fast`), file for file."""
    field_env, field_scene = exported("type1", physics="fast_field")
    prism_env, prism_scene = exported("type1")
    assert (field_env.task.physics_setting, prism_env.task.physics_setting) == ("fast_field", "fast")
    assert field_scene.read_text() == prism_scene.read_text()
    field_meshes, prism_meshes = field_scene.parent / "meshes", prism_scene.parent / "meshes"
    files = sorted(p.name for p in field_meshes.iterdir())
    assert files and files == sorted(p.name for p in prism_meshes.iterdir())
    assert all((field_meshes / f).read_bytes() == (prism_meshes / f).read_bytes() for f in files)


def test_cli_writes_the_scene_and_refuses_to_overwrite(tmp_path):
    out = tmp_path / "scene"
    run = lambda *extra: subprocess.run(
        [sys.executable, "-m", "cathsim_dmc.app.cli.export", "task=lcca", "aorta=type1", f"out={out}", *extra],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    first = run()
    assert first.returncode == 0, first.stderr
    assert (out / "scene.xml").is_file() and any((out / "meshes").glob("*.stl"))
    second = run()
    assert second.returncode == 2 and second.stderr.strip().count("\n") == 0 and "overwrite" in second.stderr
