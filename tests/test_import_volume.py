"""The importer's volume path (repair=volume): isosurface, voxel lumen, closing, wall shells,
side-branch trimming, fold repair, and segmentation-style meshes imported in one command."""

import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from cathsim_dmc.anatomy import load_asset
from cathsim_dmc.anatomy.isosurface import zero_surface
from cathsim_dmc.anatomy.sdf import SDFGrid
from cathsim_dmc.anatomy.surface_cleanup import folded_faces, repair_folds
from cathsim_dmc.anatomy.volume import VolumeError, trim_side_branches, volume_sdf_grid
from cathsim_dmc.model_check import validate_and_compile

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from segmentation_corpus import VARIANTS, make_variant  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]
R = 0.010                      # sphere radius (m)


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
    assert mesh.volume > 0                                  # outward
    assert abs(mesh.volume / (4 / 3 * np.pi * R ** 3) - 1) < 0.02
    assert np.abs(np.linalg.norm(v, axis=1) - R).max() < 0.05e-3


def test_volume_grid_closes_small_gaps_and_ignores_fins():
    v, f = sphere_mesh()
    c = v[f].mean(axis=1)
    # A slit about 2 mm wide and 10 mm long, curved with the sphere (not a flat vessel end).
    f = f[~((np.abs(c[:, 2]) < 0.0007) & (c[:, 0] > 0) & (np.abs(c[:, 1]) < 0.005))]
    # A fin: a third triangle on one edge (non-manifold), pointing out of the sphere.
    v = np.vstack([v, 1.3 * v[f[5, 0]]])
    f = np.vstack([f, [[f[5, 0], f[5, 1], len(v) - 1]]])
    grid, notes = volume_sdf_grid(v, f, 0.0005, 0.004, np.zeros(3), {"bca": np.array([0.0, 0.005, 0.0])},
                                  max_gap_m=0.003)
    assert any("closed gaps" in n for n in notes), notes
    # Near the surface the grid is the sphere's signed distance to within a node.
    rng = np.random.default_rng(0)
    d = rng.normal(size=(500, 3))
    p = (d / np.linalg.norm(d, axis=1, keepdims=True)) * rng.uniform(R - 0.003, R + 0.003, (500, 1))
    assert np.abs(grid(p) - (np.linalg.norm(p, axis=1) - R)).max() < 0.5e-3
    assert grid(np.zeros((1, 3)))[0] < -0.009


def test_volume_grid_refuses_an_open_surface_and_a_site_in_another_piece():
    v, f = sphere_mesh()
    open_v, open_f = v, f[~np.all(v[f].mean(axis=1) > 0, axis=1)]   # an octant gone: not a flat end
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
    shell_f = np.vstack([outer_f, f[:, ::-1] + len(outer_v)])      # the inner surface faces the lumen
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


def _import(tmp_path, name):
    path, entry, sites = make_variant(name, tmp_path)
    vec = lambda p: "[" + ",".join(f"{x:.4f}" for x in p) + "]"
    script = pathlib.Path(sys.executable).with_name("cathsim-aorta")
    cmd = [str(script), "import", f"mesh={path}", f"entry={vec(entry)}", f"out={tmp_path / name}",
           *[f"sites.{k}={vec(p)}" for k, p in sorted(sites.items())]]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900, cwd=ROOT,
                          env=dict(os.environ, OMP_NUM_THREADS="1"))
    print(proc.stdout, proc.stderr)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""                                 # no stray warnings
    asset = load_asset(tmp_path / name)
    report = validate_and_compile(asset)
    assert report.ok and report.holes == 0 and report.max_intrusion_m == 0.0, report.summary()
    # The same anatomy as the arch it came from.
    src = load_asset(ROOT / "assets" / "type1")
    length = lambda a, k: np.linalg.norm(np.diff(a.centerlines[k].points, axis=0), axis=1).sum()
    for k in src.sites:
        assert abs(length(asset, k) / length(src, k) - 1) < 0.01, k
    vol = lambda a: trimesh.Trimesh(a.visual_vertices.astype(float), a.visual_faces, process=False).volume
    assert abs(vol(asset) / vol(src) - 1) < 0.03
    return proc.stdout


def test_a_pinched_segmentation_imports_in_one_command(tmp_path):
    out = _import(tmp_path, "pinched")
    assert "non-manifold surface" in out and "rebuilding it from a voxel volume" in out


@pytest.mark.slow
@pytest.mark.parametrize("name", [n for n in VARIANTS if n != "pinched"])
def test_segmentation_corpus_imports_in_one_command(tmp_path, name):
    out = _import(tmp_path, name)
    expected = {"noisy": "rebuilding the lumen from a voxel volume", "decimated": "non-manifold surface",
                "stump": "trimmed 1 side branch", "wall_shell": "second surface around the lumen"}[name]
    assert expected in out
