"""The distance-field wall (`cathsim_dmc.sim.wall_field`, physics `fast_field`): the sampled field
against analytic distances, the compiled contact test against known geometry, MuJoCo's
own SDF contacts left alone, and the aorta's wire against the prism wall's."""

import os
import subprocess
import sys
from types import SimpleNamespace

import mujoco
import numpy as np
import pytest

from cathsim_dmc.sim import wall_field
from cathsim_dmc.suite.gym import CathSimEnv

MARGIN_M = 1e-3  # the vessel wall's contact margin (Aorta.contact_margin_m)


def tube_triangles(radius_m, length_m, around=96, along=40):
    """A cylinder's side along z, normals pointing out."""
    angles = np.linspace(0, 2 * np.pi, around, endpoint=False)
    zs = np.linspace(-length_m / 2, length_m / 2, along + 1)
    ring = lambda z: np.column_stack([radius_m * np.cos(angles), radius_m * np.sin(angles), np.full(around, z)])
    triangles = []
    for z0, z1 in zip(zs[:-1], zs[1:]):
        a, b = ring(z0), ring(z1)
        for i in range(around):
            j = (i + 1) % around
            triangles += [[a[i], a[j], b[j]], [a[i], b[j], b[i]]]
    return np.asarray(triangles)


def test_the_field_is_the_signed_distance_to_a_tube():
    radius = 6e-3
    field = wall_field.build_field(tube_triangles(radius, 0.04), shift_m=0.0)
    rng = np.random.default_rng(0)
    rho = rng.uniform(radius - 2.5e-3, radius + 2.5e-3, 400)  # inside the stored band
    phi = rng.uniform(0, 2 * np.pi, 400)
    z = rng.uniform(-0.01, 0.01, 400)  # away from the open ends
    points = np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])
    measured = wall_field.distance(field, points)
    # Positive inside the lumen; the 96-gon lies at most 0.013 mm inside the circle.
    np.testing.assert_allclose(measured, radius - rho, atol=5e-5)
    # Far from the wall (the axis, or well outside) nothing is stored: no contact there.
    assert np.isnan(wall_field.distance(field, [[0, 0, 0], [0.012, 0, 0]])).all()


def _wall_and_capsule(triangles, capsule_from, capsule_to, radius=0.445e-3):
    """A static field wall from `triangles` and a capsule between two points, contacts read
    by mj_forward."""
    field = wall_field.build_field(triangles, shift_m=MARGIN_M)
    lo, hi = triangles.reshape(-1, 3).min(axis=0) - 0.004, triangles.reshape(-1, 3).max(axis=0) + 0.004
    spec = mujoco.MjSpec()
    spec.add_numeric(name="wall", data=field, size=len(field))
    spec.add_mesh(name="wall").uservert = np.array(
        [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    ).ravel()
    spec.worldbody.add_geom(name="wall", type=mujoco.mjtGeom.mjGEOM_SDF, meshname="wall", margin=MARGIN_M)
    body = spec.worldbody.add_body(name="capsule")
    body.add_freejoint()
    body.add_geom(
        type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=np.concatenate([capsule_from, capsule_to]), size=[radius, 0, 0]
    )
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    # Copies: a contact read from mjData is a view that dies with it.
    return [
        SimpleNamespace(
            dist=float(c.dist), includemargin=float(c.includemargin), pos=c.pos.copy(), frame=c.frame.copy()
        )
        for c in (data.contact[i] for i in range(data.ncon))
    ]


def flat_face(z=0.0, half=0.02):
    """A square at height z facing -z (the lumen below it)."""
    c = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    return np.stack([c[[0, 1, 2]], c[[0, 2, 3]]])


def test_a_capsule_lying_on_the_wall_touches_it_at_both_ends():
    wall_field.native()
    radius, depth = 0.445e-3, 0.1e-3
    z = -radius + depth  # the capsule sinks 0.1 mm into the face at z = 0
    contacts = _wall_and_capsule(flat_face(), [-0.005, 0, z], [0.005, 0, z], radius)
    assert len(contacts) == 2
    for con in contacts:
        assert con.includemargin - con.dist == pytest.approx(depth, abs=1e-6)  # penetration past the lumen
        np.testing.assert_allclose(con.frame[:3], [0, 0, 1], atol=1e-6)  # from the capsule into the wall
    assert sorted(round(con.pos[0], 6) for con in contacts) == [-0.005, 0.005]
    # Tilted: only the lower end is within the margin.
    contacts = _wall_and_capsule(flat_face(), [-0.005, 0, z], [0.005, 0, z - 0.003], radius)
    assert len(contacts) == 1 and contacts[0].pos[0] == pytest.approx(-0.005, abs=1e-4)


def test_a_capsule_across_a_ridge_touches_it_in_the_middle():
    """A ridge pointing into the lumen (below the faces; they rise 10 degrees away from
    x = 0, as the carina of a branch does): a level capsule under it touches at its
    middle, not at its ends."""
    slope = np.tan(np.radians(10))
    x = 0.02
    corners = {(sx, sy): [sx * x, sy * 0.02, slope * x] for sx in (-1, 1) for sy in (-1, 1)}
    top = {sy: [0.0, sy * 0.02, 0.0] for sy in (-1, 1)}
    triangles = np.array(
        [
            [corners[(-1, -1)], top[-1], top[1]],
            [corners[(-1, -1)], top[1], corners[(-1, 1)]],
            [top[-1], corners[(1, -1)], corners[(1, 1)]],
            [top[-1], corners[(1, 1)], top[1]],
        ]
    )
    radius = 0.445e-3
    z = -radius + 0.1e-3
    contacts = _wall_and_capsule(triangles, [-0.007, 0, z], [0.007, 0, z], radius)
    assert len(contacts) == 1
    assert contacts[0].pos[0] == pytest.approx(0.0, abs=3e-4)
    assert contacts[0].includemargin - contacts[0].dist == pytest.approx(0.1e-3, abs=2e-5)


SLAB_AND_SPHERE = """
import sys, mujoco, numpy as np
if sys.argv[1] == "installed":
    from cathsim_dmc.sim import wall_field
    wall_field.native()
spec = mujoco.MjSpec()
box = np.array([[x, y, z] for x in (-0.05, 0.05) for y in (-0.05, 0.05) for z in (-0.01, 0.0)])
spec.add_mesh(name="slab").uservert = box.ravel()
spec.worldbody.add_geom(name="slab", type=mujoco.mjtGeom.mjGEOM_SDF, meshname="slab")
body = spec.worldbody.add_body(pos=[0, 0, 0.009])
body.add_freejoint()
body.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.01, 0, 0])
model = spec.compile()
data = mujoco.MjData(model)
mujoco.mj_forward(model, data)
print(data.ncon, repr(data.contact.dist.tolist()), repr(data.contact.pos.tolist()))
"""


def test_sdf_geoms_without_a_field_keep_mujocos_own_contact():
    """The compiled test answers only for geoms carrying a field: a plain SDF geom (MuJoCo
    builds the distance of its mesh) gets the same contacts as without the test installed."""
    runs = [
        subprocess.run([sys.executable, "-c", SLAB_AND_SPHERE, mode], capture_output=True, text=True, timeout=120)
        for mode in ("installed", "plain")
    ]
    assert all(run.returncode == 0 for run in runs), [run.stderr for run in runs]
    assert runs[0].stdout == runs[1].stdout
    assert int(runs[0].stdout.split()[0]) >= 1


def test_a_missing_compiler_is_one_clear_error(tmp_path):
    env = dict(os.environ, CC=str(tmp_path / "no-such-cc"), CATHSIM_DMC_CACHE=str(tmp_path / "cache"))
    code = (
        "from cathsim_dmc.sim import wall_field\n"
        "try:\n    wall_field.native()\nexcept wall_field.NativeBuildError as e:\n    print(e)"
    )
    result = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "no-such-cc" in result.stdout and "physics=fast needs none" in result.stdout


def test_an_unwritable_cache_builds_in_the_temporary_folder(tmp_path):
    blocked = tmp_path / "a-file"
    blocked.write_text("not a folder")  # the cache's folders cannot be made under it
    env = dict(os.environ, CATHSIM_DMC_CACHE=str(blocked), TMPDIR=str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    code = "from cathsim_dmc.sim import wall_field\nprint(wall_field.native()._name)"
    result = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().startswith(str(tmp_path / "tmp"))


def test_an_asset_without_prisms_is_refused(tmp_path):
    """The field is built on the prisms' lumen triangles: an asset whose wall pieces are
    other convex sets (here the first prism with its last point dropped) is refused."""
    import shutil

    from cathsim_dmc.core.shipped import resolve_asset
    from cathsim_dmc.entities import Aorta

    folder = tmp_path / "odd"
    shutil.copytree(resolve_asset("type1"), folder)
    with np.load(folder / "collision.npz") as npz:
        vertices, offsets = npz["vertices"], npz["hull_offsets"].copy()
    vertices = np.delete(vertices, 5, axis=0)
    offsets[1:] -= 1
    np.savez(folder / "collision.npz", vertices=vertices, hull_offsets=offsets)
    aorta = Aorta(asset=str(folder), hulls_in_mjcf=False, wall="field")
    with pytest.raises(ValueError, match="has other wall pieces; use wall='prisms'"):
        aorta.add_geoms(mujoco.MjSpec())


def test_the_wire_moves_in_the_field_wall_as_in_the_prism_wall():
    """Full insertion with a slow turn, up the descending aorta into the arch: the wire
    stays in the vessel and ends near where it ends in the prism wall, pressing it about
    as hard (the field follows the lumen; the moved prisms round it off by up to 0.2 mm)."""
    ends, forces = {}, {}
    for setting in ("fast", "fast_field"):
        env = CathSimEnv(task="bca", aorta="type1", obs="internal", physics=setting)
        env.reset(seed=0)
        forces[setting] = []
        for _ in range(60):
            _, _, _, _, info = env.step(np.array([1.0, 0.2], np.float32))
            assert not info["escaped"] and not info["diverged"]
            forces[setting].append(info["mean_contact_force_n"])
        assert env.task.containment.contains(env.task.wire_points_m(env.physics)).all()
        ends[setting] = np.asarray(info["tip_position_m"])
        env.close()
    assert np.linalg.norm(ends["fast_field"] - ends["fast"]) < 0.005
    assert np.mean(forces["fast_field"]) == pytest.approx(np.mean(forces["fast"]), rel=0.3)
