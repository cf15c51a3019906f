"""The importer's volume path (repair=volume): isosurface, voxel lumen, closing, wall shells,
side-branch trimming, fold repair, and segmentation-style meshes imported in one command."""

import os
import pathlib
import re
import subprocess
import sys

import numpy as np
import pytest
import trimesh
from conftest import expert_successes

from cathsim_dmc.anatomy import load_asset
from cathsim_dmc.anatomy.corpus import VARIANTS, cap_files, make_variant
from cathsim_dmc.anatomy.crop import crop_to_paths, smooth_around
from cathsim_dmc.anatomy.isosurface import zero_surface
from cathsim_dmc.anatomy.sdf import SDFGrid
from cathsim_dmc.anatomy.surface_cleanup import folded_faces, repair_folds
from cathsim_dmc.anatomy.volume import VolumeError, trim_side_branches, volume_sdf_grid

ROOT = pathlib.Path(__file__).resolve().parents[1]
R = 0.010  # sphere radius (m)


def sphere_grid(radius=R, spacing=0.0005, pad=0.004) -> SDFGrid:
    n = int(np.ceil(2 * (radius + pad) / spacing)) + 1
    origin = np.full(3, -(radius + pad))
    axes = origin[0] + spacing * np.arange(n)
    x, y, z = np.meshgrid(axes, axes, axes, indexing="ij")
    return SDFGrid(origin=origin, spacing=spacing, values=np.sqrt(x * x + y * y + z * z) - radius)


def sphere_mesh(radius=R):
    m = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def test_zero_surface_of_a_sphere_is_closed_oriented_and_accurate():
    g = sphere_grid(spacing=0.001)
    v, f = zero_surface(g.values, g.origin, g.spacing)
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0  # outward
    assert abs(mesh.volume / (4 / 3 * np.pi * R**3) - 1) < 0.02
    assert np.abs(np.linalg.norm(v, axis=1) - R).max() < 0.05e-3


def test_volume_grid_closes_small_gaps_and_ignores_fins():
    v, f = sphere_mesh()
    c = v[f].mean(axis=1)
    # A slit about 2 mm wide and 10 mm long, curved with the sphere (not a flat vessel end).
    f = f[~((np.abs(c[:, 2]) < 0.0007) & (c[:, 0] > 0) & (np.abs(c[:, 1]) < 0.005))]
    # A fin: a third triangle on one edge (non-manifold), pointing out of the sphere.
    v = np.vstack([v, 1.3 * v[f[5, 0]]])
    f = np.vstack([f, [[f[5, 0], f[5, 1], len(v) - 1]]])
    grid, notes = volume_sdf_grid(
        v, f, 0.0005, 0.004, np.zeros(3), {"bca": np.array([0.0, 0.005, 0.0])}, max_gap_m=0.003
    )
    assert any("closed gaps" in n for n in notes), notes
    # Near the surface the grid is the sphere's signed distance to within a node.
    rng = np.random.default_rng(0)
    d = rng.normal(size=(500, 3))
    p = (d / np.linalg.norm(d, axis=1, keepdims=True)) * rng.uniform(R - 0.003, R + 0.003, (500, 1))
    assert np.abs(grid(p) - (np.linalg.norm(p, axis=1) - R)).max() < 0.5e-3
    assert grid(np.zeros((1, 3)))[0] < -0.009


def test_volume_grid_refuses_an_open_surface_and_a_site_in_another_piece():
    v, f = sphere_mesh()
    open_v, open_f = v, f[~np.all(v[f].mean(axis=1) > 0, axis=1)]  # an octant gone: not a flat end
    with pytest.raises(VolumeError, match=r"the surface is open: the outside reaches entry=\[0.0, 0.0, 0.0\] mm"):
        volume_sdf_grid(open_v, open_f, 0.0005, 0.004, np.zeros(3), {"bca": np.array([0.0, 0.0, -0.005])})
    two_v = np.vstack([v, v + [0.03, 0, 0]])
    two_f = np.vstack([f, f + len(v)])
    with pytest.raises(VolumeError, match=r"sites.bca=\[30.0, 0.0, 0.0\] mm is not in the same vessel as the entry"):
        volume_sdf_grid(two_v, two_f, 0.0005, 0.004, np.zeros(3), {"bca": np.array([0.03, 0.0, 0.0])})


def test_a_wall_shell_gives_its_inner_surface():
    v, f = sphere_mesh()
    outer_v, outer_f = sphere_mesh(R + 0.002)
    shell_v = np.vstack([outer_v, v])
    shell_f = np.vstack([outer_f, f[:, ::-1] + len(outer_v)])  # the inner surface faces the lumen
    grid, notes = volume_sdf_grid(shell_v, shell_f, 0.0005, 0.004, np.zeros(3), {"bca": np.array([0, 0.005, 0])})
    assert any("second surface" in n and "wall shell" in n for n in notes), notes
    on_axis = np.array([[R - 0.001, 0, 0], [R + 0.001, 0, 0]])
    np.testing.assert_allclose(grid(on_axis), [-0.001, 0.001], atol=0.3e-3)


def _sphere_with_stump(spacing=0.0005):
    """A sphere lumen with a 2.4 mm wide, 8 mm long side branch along +x."""
    g = sphere_grid(pad=0.012, spacing=spacing)
    n = g.values.shape[0]
    axes = g.origin[0] + g.spacing * np.arange(n)
    x, y, z = np.meshgrid(axes, axes, axes, indexing="ij")
    stump = np.sqrt(y * y + z * z) - 0.0012
    stump = np.maximum(stump, x - (R + 0.008))
    values = np.minimum(g.values, np.maximum(stump, -x))
    v, f = zero_surface(values, g.origin, g.spacing)
    return v, f


def test_side_stumps_are_trimmed_unless_a_path_uses_them():
    v, f = _sphere_with_stump()
    grid, _ = volume_sdf_grid(v, f, 0.0004, 0.004, np.zeros(3), {"bca": np.array([0, 0.005, 0])})
    in_stump = np.array([[R + 0.005, 0, 0]])
    assert grid(in_stump)[0] < 0
    to_site = [np.array([[0, 0, 0], [0, 0.005, 0]])]
    trimmed, notes = trim_side_branches(grid, to_site, np.zeros(3), 0.003)
    assert trimmed(in_stump)[0] > 0 and any("trimmed 1 side branch" in n for n in notes), notes
    # The rest of the lumen does not move.
    p = np.array([[0, R - 0.001, 0], [0, 0, -(R - 0.001)], [-(R - 0.001), 0, 0]])
    np.testing.assert_allclose(trimmed(p), grid(p), atol=1e-9)
    # A path through the stump keeps it; so does a smaller diameter.
    into_stump = [np.array([[0, 0, 0], [R + 0.006, 0, 0]])]
    assert trim_side_branches(grid, into_stump, np.zeros(3), 0.003)[0](in_stump)[0] < 0
    assert trim_side_branches(grid, to_site, np.zeros(3), 0.0015)[1] == []


def test_fold_repair_unfolds_a_pushed_in_vertex():
    grid = sphere_grid()
    v, f = sphere_mesh()
    v = v.copy()
    # Vertex 0 slid 1.6 mm (two edges) along the sphere, past its neighbours: its fan turns over.
    tangent = np.cross(v[0], [0.0, 0.0, 1.0])
    moved = v[0] + 0.0016 * tangent / np.linalg.norm(tangent)
    v[0] = R * moved / np.linalg.norm(moved)
    assert len(folded_faces(v, f, grid)) > 0
    v2, f2, left = repair_folds(v, f, grid)
    assert left == 0 and len(folded_faces(v2, f2, grid)) == 0
    assert trimesh.Trimesh(v2, f2, process=False).is_watertight
    assert np.abs(np.linalg.norm(v2, axis=1) - R).max() < 0.1e-3


def _import(tmp_path, name, *options):
    """Import corpus variant `name` with `cathsim-aorta import` and default options (plus `options`);
    (exit status, stdout, stderr)."""
    path, entry, sites = make_variant(name, tmp_path)
    vec = lambda p: "[" + ",".join(f"{x:.4f}" for x in p) + "]"  # noqa: E731
    script = pathlib.Path(sys.executable).with_name("cathsim-aorta")
    caps = cap_files(path)
    cmd = [
        str(script),
        "import",
        f"mesh={path}",
        f"entry={vec(entry)}",
        f"out={tmp_path / name}",
        *[f"sites.{k}={vec(p)}" for k, p in sorted(sites.items()) if k in ("bca", "lcca")],
        *options,
    ]
    if caps:
        cmd.append("caps=[" + ",".join(str(c) for c in caps) + "]")
    proc = subprocess.run(
        cmd, capture_output=True, text=True, timeout=900, cwd=ROOT, env=dict(os.environ, OMP_NUM_THREADS="1")
    )
    print(proc.stdout, proc.stderr)
    return proc.returncode, proc.stdout, proc.stderr


# The lumen's narrowest depth along the paths, as a share of the source's radius: a voxel
# staircase of 1.5 mm steps narrows the 3.7 mm LCCA by up to about half a step (0.69 measured).
MIN_DEPTH_SHARE = {"staircase": 0.65}


def _check_import(tmp_path, name):
    """The import succeeds and validates, the paths and the lumen around them are the source's, and
    the scripted expert reaches both targets in at least 4 of 5 episodes. Returns stdout."""
    status, out, err = _import(tmp_path, name)
    assert status == 0, err
    assert err == ""  # no stray warnings
    asset = load_asset(tmp_path / name)
    # The import ends with the validation of what it wrote (validate_and_compile): its line.
    checked = [line for line in out.splitlines() if line.startswith(f"type1_{name}: OK; ")]
    assert checked and "max intrusion 0.000 mm" in checked[0] and " wall holes 0 of " in checked[0], out
    # The same anatomy along the paths as the arch it came from: their lengths, and the lumen's
    # width around them (the crop removes only what lies beyond them).
    src = load_asset(ROOT / "assets" / "type1")
    length = lambda a, k: np.linalg.norm(np.diff(a.centerlines[k].points, axis=0), axis=1).sum()  # noqa: E731
    from cathsim_dmc.anatomy.sdf import signed_distance

    lumen = (asset.visual_vertices.astype(float), asset.visual_faces)
    for k in ("bca", "lcca"):
        assert abs(length(asset, k) / length(src, k) - 1) < 0.01, k
        points, radius = src.centerlines[k].points[::4], src.centerlines[k].radius[::4]
        away = np.linalg.norm(points - points[0], axis=1) > 0.015  # the open end cuts the lumen behind the entry
        points, radius = points[away], radius[away]
        depth = signed_distance(*lumen, points)  # positive inside
        assert np.all(depth > MIN_DEPTH_SHARE.get(name, 0.8) * radius), (k, float(np.min(depth / radius)))
    for target in ("bca", "lcca"):
        reached = expert_successes(tmp_path / name, target, episodes=5)
        assert reached >= 4, f"the expert reached the {target} in {reached} of 5 episodes"
    return out


def test_a_pinched_segmentation_imports_in_one_command(tmp_path):
    out = _check_import(tmp_path, "pinched")
    assert "non-manifold surface" in out and "rebuilding it from a voxel volume" in out


EXPECTED_NOTE = {
    "noisy": "rebuilding the lumen from a voxel volume",
    "decimated": "non-manifold surface",
    "stump": "trimmed 1 side branch",
    "wall_shell": "second surface around the lumen",
    "jagged_cap": "cropped",
    "cfd_caps": "5 cap surfaces added",
    "cfd_open": "capped 5 flat open vessel ends",
    "staircase": "a terraced surface",
    "self_intersecting": "rebuilding",
}


@pytest.mark.slow
@pytest.mark.parametrize("name", [n for n in VARIANTS if n != "pinched"])
def test_segmentation_corpus_imports_in_one_command(tmp_path, name):
    out = _check_import(tmp_path, name)
    assert EXPECTED_NOTE[name] in out


@pytest.mark.slow
def test_an_import_that_cannot_be_repaired_ends_with_one_final_line(tmp_path):
    # Without the crop, the jagged cap's slanted rim folds the surface whatever the importer tries.
    status, out, err = _import(tmp_path, "jagged_cap", "crop=none")
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "no remedy undid it (tried: " in lines[0], err
    # Final: it names what was tried and suggests no option value to try next.
    message = lines[0].split(".stl: ", 1)[1]
    assert "pass " not in message and not re.search(r"\b[a-z_]+=\S", message), message


def _tee_grid(spacing=0.0005):
    """A 6 mm-radius tube along y (-40..70 mm) with a 3 mm-radius side tube along +x (0..40 mm) at y = 0."""
    axes = [np.arange(-0.012, 0.048, spacing), np.arange(-0.045, 0.075, spacing), np.arange(-0.010, 0.010, spacing)]
    x, y, z = np.meshgrid(*axes, indexing="ij")
    main = np.maximum(np.hypot(x, z) - 0.006, np.maximum(-0.040 - y, y - 0.070))
    side = np.maximum(np.hypot(y, z) - 0.003, np.maximum(-x, x - 0.040))
    origin = np.array([a[0] for a in axes])
    return SDFGrid(origin=origin, spacing=spacing, values=np.minimum(main, side))


def test_the_crop_keeps_the_margin_around_the_paths_and_caps_the_rest():
    grid = _tee_grid()
    path = [np.array([[0.0, -0.035 + 0.005 * i, 0.0] for i in range(15)])]  # entry y = -35 mm, site y = +35 mm
    cropped, notes = crop_to_paths(grid, path, path[0][0], 0.010)
    assert len(notes) == 1 and notes[0].startswith("cropped 2 regions more than 10 mm"), notes
    inside = lambda g, p: g(np.array([p], dtype=float))[0] < 0  # noqa: E731
    # Kept: the tube along the path, 5 mm past the site, and the side tube's first 10 mm beyond the main tube.
    for p in ([0, 0.040, 0], [0.012, 0, 0], [0, -0.030, 0.004]):
        assert inside(cropped, p), p
    # Cut: the main tube 25 mm past the site, the side tube 30 mm out.
    for p in ([0, 0.060, 0], [0.030, 0, 0]):
        assert inside(grid, p) and not inside(cropped, p), p
    # The wall along the path does not move.
    wall = np.array([[0.0058, y, 0.0] for y in np.linspace(-0.03, 0.03, 7)])
    np.testing.assert_allclose(cropped(wall), grid(wall), atol=1e-9)
    # A path through everything crops nothing.
    everything = [
        path[0],
        np.array([[0.0, 0.0, 0.0], [0.039, 0.0, 0.0]]),
        np.array([[0.0, 0.0, 0.0], [0.0, 0.069, 0.0]]),
    ]
    assert crop_to_paths(grid, everything, path[0][0], 0.010)[1] == []


def test_smoothing_around_a_point_leaves_the_rest_of_the_volume_alone():
    grid = _tee_grid()
    where = np.array([0.0, 0.0, 0.0])
    smoothed = smooth_around(grid, where, 0.008, 0.002)
    far = np.array([[0.0058, 0.04, 0.0], [0.0, -0.03, 0.0058]])
    np.testing.assert_array_equal(smoothed(far), grid(far))
    corner = np.array([[0.0045, 0.0042, 0.0]])  # the sharp edge where the side tube meets the main one
    assert smoothed(corner)[0] != grid(corner)[0]
