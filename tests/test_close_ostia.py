"""Close ostia: the corpus class made from generated arches whose BCA and LCCA leave the arch close
together, the importer's wall thinned at a septum thinner than the wall, the thickened septum as a
fold remedy, and the import's time budget."""

import json
import os
import pathlib
import subprocess
import sys
import time

import numpy as np
import pytest
import trimesh
from conftest import expert_successes

from cathsim_dmc.anatomy import build_arch, load_asset
from cathsim_dmc.anatomy.corpus import CLOSE_OSTIA_PARAMS, CLOSE_OSTIA_VARIANTS, VARIANTS, make_variant
from cathsim_dmc.anatomy.crop import thicken_septa, thin_outside
from cathsim_dmc.anatomy.import_clock import ImportClock, import_budget
from cathsim_dmc.anatomy.import_error import MeshImportError
from cathsim_dmc.anatomy.importer import import_mesh
from cathsim_dmc.anatomy.lumen import Lumen
from cathsim_dmc.anatomy.sdf import SDFGrid
from cathsim_dmc.anatomy.triangles import vertex_normals
from cathsim_dmc.anatomy.volume import volume_sdf_grid
from cathsim_dmc.anatomy.wall import extrude_prisms, prism_offsets, septum_widths, thin_at_septa

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPT = pathlib.Path(sys.executable).with_name("cathsim-aorta")
ANSWER_S = 300.0  # every import answers (an asset or one line) within 5 minutes


def two_spheres(gap, radius=0.005, subdivisions=4):
    """Two spheres of `radius` along x, `gap` apart wall to wall, as one closed Lumen (no cap)."""
    a = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    va = np.asarray(a.vertices, dtype=np.float64)
    fa = np.asarray(a.faces, dtype=np.int64)
    shift = np.array([2 * radius + gap, 0.0, 0.0])
    v = np.vstack([va, va + shift])
    f = np.vstack([fa, fa + len(va)])
    return Lumen(vertices=v, faces=f, cap=np.zeros(len(f), dtype=bool), normals=vertex_normals(v, f))


def test_the_wall_is_thinned_only_where_another_lumen_is_closer_than_it():
    lumen = two_spheres(gap=0.001)
    offsets = prism_offsets(lumen, 0.002)
    width = septum_widths(lumen, offsets)
    # The vertices facing the other sphere across the 1 mm gap, and only they, meet it within their wall.
    facing = np.isfinite(width)
    assert facing.any() and width[facing].min() == pytest.approx(0.001, abs=2e-5)
    x = lumen.vertices[:, 0]
    assert np.all(np.abs(x[facing] - 0.0055) < 0.0035)  # around the gap (x = 5 to 6 mm)
    thinned, _ = thin_at_septa(lumen, offsets)
    thin = thinned < offsets
    np.testing.assert_allclose(thinned[thin], 0.5 * width[thin])
    np.testing.assert_array_equal(thinned[~thin], offsets[~thin])
    # No prism point reaches into the other sphere (beyond the icosphere's 4 um sag), as the full wall does.
    for offs, reaches in ((thinned, False), (offsets, True)):
        pts = extrude_prisms(lumen, 0.002, offsets=offs).reshape(2, -1, 3)  # the left sphere's, the right's
        depth = max(
            0.005 - np.linalg.norm(pts[0] - [0.011, 0, 0], axis=1).min(), 0.005 - np.linalg.norm(pts[1], axis=1).min()
        )
        assert (depth > 0.0005) == reaches and depth < (0.002 if reaches else 1e-5), depth
    # Far apart: nothing changes, and no offsets given is the generator's wall.
    far = two_spheres(gap=0.01)
    assert np.array_equal(thin_at_septa(far, prism_offsets(far, 0.002))[0], prism_offsets(far, 0.002))
    assert np.array_equal(extrude_prisms(far, 0.002), extrude_prisms(far, 0.002, offsets=prism_offsets(far, 0.002)))


def _two_ball_grid(gap, spacing=0.0002, radius=0.004):
    axes = [np.arange(-0.006, 0.006 + 2 * radius + gap, spacing), np.arange(-0.006, 0.006, spacing)]
    axes.append(axes[1])
    x, y, z = np.meshgrid(*axes, indexing="ij")
    a = np.sqrt(x * x + y * y + z * z) - radius
    b = np.sqrt((x - 2 * radius - gap) ** 2 + y * y + z * z) - radius
    return SDFGrid(origin=np.array([a_[0] for a_ in axes]), spacing=spacing, values=np.minimum(a, b))


def test_a_thin_septum_is_thickened_to_the_width_asked_and_nothing_else_moves():
    grid = _two_ball_grid(gap=0.0004)
    mid = np.array([0.0042, 0.0, 0.0])
    assert thin_outside(grid.values, grid.spacing, 0.001).any()
    thick, thinnest = thicken_septa(grid, mid, 0.003, 0.0012)
    assert thinnest == pytest.approx(0.0004, abs=2.5e-4)
    # Across the septum the outside is now at least the width asked.
    line = np.stack([np.linspace(0.003, 0.0054, 241), np.zeros(241), np.zeros(241)], axis=1)
    outside = line[thick(line) > 0]
    assert np.ptp(outside[:, 0]) >= 0.0012 - 2 * grid.spacing
    far = np.array([[-0.004, 0.0, 0.0], [0.0, 0.004, 0.0], [0.012, 0.0, 0.0]])
    np.testing.assert_array_equal(thick(far), grid(far))
    # Wide apart, there is no septum to thicken.
    assert thicken_septa(_two_ball_grid(gap=0.004), np.array([0.006, 0, 0]), 0.003, 0.0012)[1] == np.inf


def test_the_volume_fills_pockets_inside_the_lumen_and_finds_the_largest_piece_without_an_entry():
    big = trimesh.creation.icosphere(subdivisions=4, radius=0.010)
    speck = trimesh.creation.icosphere(subdivisions=2, radius=0.0015)
    loose = trimesh.creation.icosphere(subdivisions=2, radius=0.003)
    parts = [(big, [0, 0, 0]), (speck, [0.004, 0, 0]), (loose, [0.02, 0, 0])]
    v = np.vstack([np.asarray(m.vertices) + c for m, c in parts])
    sizes = np.cumsum([0] + [len(m.vertices) for m, _ in parts])
    f = np.vstack([np.asarray(m.faces) + o for (m, _), o in zip(parts, sizes)])
    grid, notes = volume_sdf_grid(v, f, 0.0005, 0.004, None, {})
    assert grid(np.array([[0.004, 0, 0]]))[0] < -0.005  # the speck's inside is lumen
    assert grid(np.array([[0.02, 0, 0]]))[0] > 0  # the loose piece is not
    assert any(n.startswith("filled 1 enclosed pocket inside the lumen") for n in notes), notes


def test_a_spent_budget_stops_with_one_line_naming_the_step(tmp_path):
    clock = ImportClock(tmp_path / "x.stl", budget_s=30.0)
    t0 = time.perf_counter()
    with pytest.raises(MeshImportError) as err:
        with import_budget(clock):
            clock.begin("meshing the lumen (remeshed at 1.50 mm edges)", 0.3)
            while True:  # a step that never ends
                sum(range(1000))
    assert time.perf_counter() - t0 < 2.0
    message = str(err.value)
    assert len(message.splitlines()) == 1
    assert "stopped: meshing the lumen (remeshed at 1.50 mm edges) ran 0 s and spent its 0 s budget" in message
    with pytest.raises(ValueError, match=r"time_budget_s=0 and remedy_budget_s=100 must be seconds"):
        import_mesh(tmp_path / "x.stl", tmp_path / "out", time_budget_s=0, remedy_budget_s=100)


# ----------------------------------------------------------------------------
# The corpus class and its import (slow: each mesh takes about 30 s to make, 50 s to import)


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    folder = tmp_path_factory.mktemp("close_ostia")
    return {name: make_variant(name, folder) for name in CLOSE_OSTIA_VARIANTS}


def _septum_mm(path):
    m = trimesh.load(path, process=False)
    m.merge_vertices()
    main = max(m.split(only_watertight=False), key=lambda c: len(c.faces))
    v, f = np.asarray(main.vertices) * 1e-3, np.asarray(main.faces, dtype=np.int64)
    lumen = Lumen(vertices=v, faces=f, cap=np.zeros(len(f), dtype=bool), normals=vertex_normals(v, f))
    return float(septum_widths(lumen, 0.004).min()) * 1e3


@pytest.mark.slow
def test_the_close_ostia_meshes_are_what_the_docstring_says(corpus):
    assert not set(CLOSE_OSTIA_VARIANTS) & set(VARIANTS)
    for name, (path, entry, sites) in corpus.items():
        mesh = trimesh.load(path, process=False)
        mesh.merge_vertices()
        assert 6500 <= len(mesh.faces) <= 9000, (name, len(mesh.faces))
        _, counts = np.unique(np.sort(mesh.edges, axis=1), axis=0, return_counts=True)
        assert int(np.sum(counts > 2)) == 4, name  # the fins
        closed = [p for p in mesh.split(only_watertight=True) if len(p.faces) == 80]
        assert len(closed) == 3, name  # the specks
        model = build_arch(CLOSE_OSTIA_PARAMS[name])
        np.testing.assert_allclose(sites["bca"], model.sites["bca"] * 1e3)
        if name == "close_ostia":
            c2c = np.linalg.norm(model.ostia["bca"] - model.ostia["lcca"]) * 1e3
            assert 10.0 <= c2c <= 16.0
            assert 0.5 <= _septum_mm(path) <= 2.0
        else:
            assert CLOSE_OSTIA_PARAMS[name].bovine


def _import(path, out, *options):
    t0 = time.perf_counter()
    proc = subprocess.run(
        [str(SCRIPT), "import", f"mesh={path}", f"out={out}", *options],
        capture_output=True,
        text=True,
        timeout=900,
        cwd=ROOT,
        env=dict(os.environ, OMP_NUM_THREADS="1"),
    )
    print(proc.stdout, proc.stderr)
    return proc, time.perf_counter() - t0


def _on_branch(point, model, name):
    """Whether `point` (m) lies in generated branch `name`'s lumen, nearer its centreline than any
    other branch's."""
    d = {k: float(np.min(np.linalg.norm(b.points - point, axis=1) - b.radius)) for k, b in model.branches.items()}
    return d[name] < 0 and min(d, key=d.get) == name


@pytest.mark.slow
@pytest.mark.parametrize("name", CLOSE_OSTIA_VARIANTS)
def test_a_close_ostia_mesh_imports_with_defaults_and_finds_its_sites(corpus, tmp_path, name):
    path, _, sites = corpus[name]
    proc, seconds = _import(path, tmp_path / name)
    assert proc.returncode == 0, proc.stderr
    assert seconds < ANSWER_S
    checked = [line for line in proc.stdout.splitlines() if line.startswith(f"{name}: OK; ")]
    assert checked and " wall holes 0 of " in checked[0], proc.stdout
    meta = json.loads((tmp_path / name / "meta.json").read_text())
    assert meta["params"]["sites_found"] == "auto"
    model = build_arch(CLOSE_OSTIA_PARAMS[name])
    for k in ("bca", "lcca"):
        found = np.array(meta["sites"][k])
        assert _on_branch(found, model, k), (k, found, sites[k])
        assert np.linalg.norm(found * 1e3 - sites[k]) < 11.0, (k, found, sites[k])
    notes = meta["import"]["notes"]
    if name == "close_ostia":
        thinned = [n for n in notes if n.startswith("wall thinned at a septum: ")]
        assert len(thinned) == 1, notes
    if name == "shared_trunk":
        assert any("common trunk (bovine arch)" in n for n in notes), notes
    # The scripted expert reaches both targets past the thinned septum (at least 4 of 5 episodes).
    for target in ("bca", "lcca"):
        reached = expert_successes(tmp_path / name, target, episodes=5)
        if (name, target) == ("shared_trunk", "lcca") and reached < 4:
            # A known open problem: the wire alone stalls in the mouth of a bovine trunk's
            # LCCA (the expert's catheter rule does not fire there: a 55-76 degree turn).
            pytest.xfail(f"the expert reached the shared trunk's LCCA in {reached} of 5 episodes")
        assert reached >= 4, f"the expert reached the {target} in {reached} of 5 episodes"


@pytest.mark.slow
@pytest.mark.parametrize("options", [["sdf_mm=0.4"], ["edge_mm=1.5", "sdf_mm=0.4"]])
def test_every_option_set_answers_within_five_minutes(corpus, tmp_path, options):
    path, _, _ = corpus["close_ostia"]
    proc, seconds = _import(path, tmp_path / "out", *options)
    assert seconds < ANSWER_S, seconds
    if proc.returncode == 0:
        assert load_asset(tmp_path / "out").hull_count > 0
    else:
        assert proc.returncode == 2
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr


@pytest.mark.slow
def test_a_small_budget_stops_the_import_naming_the_slow_step(corpus, tmp_path):
    path, entry, sites = corpus["close_ostia"]
    t0 = time.perf_counter()
    with pytest.raises(MeshImportError, match=r"stopped: the voxel volume on a 0\.\d\d mm grid ran \d+ s") as err:
        # The points given: the voxel volume (about 20 s) is the first step longer than the budget.
        import_mesh(path, tmp_path / "out", entry=entry, sites=sites, time_budget_s=12.0, log=lambda s: None)
    assert time.perf_counter() - t0 < 20.0
    assert len(str(err.value).splitlines()) == 1 and not (tmp_path / "out").exists()
