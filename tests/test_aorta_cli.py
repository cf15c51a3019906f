"""cathsim-aorta: build a generated arch, import a lumen mesh (round trip and broken meshes), validate.

Everything runs through a subprocess, as a user would run it.
"""

import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from cathsim_dmc.anatomy import load_asset
from cathsim_dmc.anatomy.validate import PROBE_RADIUS_M
from cathsim_dmc.sim.model_check import validate_and_compile

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPT = pathlib.Path(sys.executable).with_name("cathsim-aorta")


def run(*args, env=None, timeout=600):
    cmd = [str(SCRIPT)] if SCRIPT.exists() else [sys.executable, "-m", "cathsim_dmc.app.cli.aorta"]
    full_env = dict(os.environ, OMP_NUM_THREADS="1", **(env or {}))
    return subprocess.run(
        cmd + [str(a) for a in args], capture_output=True, text=True, timeout=timeout, env=full_env, cwd=ROOT
    )


def assert_one_line_error(proc, *needles):
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("error: ") and "Traceback" not in proc.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def vec(p, scale=1.0):
    return "[" + ",".join(f"{x * scale:.6f}" for x in p) + "]"


def test_console_script_is_registered():
    assert SCRIPT.exists(), "pip install -e . registers cathsim-aorta"
    proc = run("--help")
    assert proc.returncode == 0 and "cathsim-aorta build" in proc.stdout
    assert_one_line_error(run("frobnicate"), "command 'frobnicate' is not valid", "build", "import")
    assert_one_line_error(run("validate", "no_such_aorta"), "no_such_aorta")


@pytest.fixture(scope="module")
def type1_mm_stl(tmp_path_factory):
    """The generator's own lumen surface (assets/type1/visual.stl), written in millimetres."""
    a = load_asset(ROOT / "assets" / "type1")
    path = tmp_path_factory.mktemp("mesh") / "type1_mm.stl"
    trimesh.Trimesh(a.visual_vertices.astype(np.float64) * 1e3, a.visual_faces, process=False).export(path)
    return path, a


def test_import_round_trip_of_a_generated_lumen(type1_mm_stl, tmp_path):
    stl, src = type1_mm_stl
    out = tmp_path / "rt"
    sites = [f"sites.{k}={vec(p, 1e3)}" for k, p in sorted(src.sites.items())]
    # At the generator's own edge length its triangles suit the wall prisms as they are.
    edge_mm = src.params["edge_length_m"] * 1e3
    proc = run(
        "import",
        f"mesh={stl}",
        f"entry={vec(src.entry_position, 1e3)}",
        *sites,
        f"out={out}",
        "name=roundtrip",
        f"edge_mm={edge_mm}",
        "crop=none",
    )  # crop=auto would remesh what it cuts
    print(proc.stdout, proc.stderr)
    assert proc.returncode == 0, proc.stderr
    assert "assuming millimetres" in proc.stdout
    assert "keeping the" in proc.stdout
    assert "entry direction estimated" in proc.stdout
    asset = load_asset(out)
    assert asset.name == "roundtrip"
    for k, p in src.sites.items():
        np.testing.assert_allclose(asset.sites[k], p, atol=1e-6)
    np.testing.assert_allclose(asset.entry_position, src.entry_position, atol=1e-6)
    assert np.dot(asset.entry_direction, [0, 1, 0]) > 0.999
    report = validate_and_compile(asset)
    print(report.summary())
    assert report.ok, report.problems
    assert report.holes == 0 and report.max_intrusion_m <= 0.2e-3 and report.min_clearance_m >= PROBE_RADIUS_M
    # Same anatomy: centerline lengths within 1% of the generator's, the lumen volume within
    # 2% (measured: centerlines 0.2-0.45% shorter, the volume 1.4% smaller).
    for k in src.sites:
        la = np.linalg.norm(np.diff(asset.centerlines[k].points, axis=0), axis=1).sum()
        lb = np.linalg.norm(np.diff(src.centerlines[k].points, axis=0), axis=1).sum()
        assert abs(la / lb - 1) < 0.01, (k, la, lb)
    vol = lambda a: trimesh.Trimesh(a.visual_vertices.astype(float), a.visual_faces, process=False).volume
    assert abs(vol(asset) / vol(src) - 1) < 0.02, vol(asset) / vol(src)
    # The open end is a flat disc square to the entry direction, a few mm behind the entry.
    oe = asset.meta["open_end"]
    assert 0.002 <= np.dot(asset.entry_position - np.asarray(oe["center"]), asset.entry_direction) <= 0.0051


@pytest.mark.slow
def test_import_remeshes_a_fine_open_mesh(tmp_path):
    """A finely triangulated lumen in metres with its open end left open: closed, remeshed, valid."""
    src = load_asset(ROOT / "assets" / "bovine")
    from cathsim_dmc.anatomy.validate import cap_faces

    cap = cap_faces(src)
    mesh = trimesh.Trimesh(src.visual_vertices.astype(np.float64), src.visual_faces[~cap], process=False).subdivide()
    path = tmp_path / "bovine_fine.obj"
    mesh.export(path)
    sites = [f"sites.{k}={vec(p)}" for k, p in sorted(src.sites.items())]
    proc = run(
        "import", path, f"entry={vec(src.entry_position)}", *sites, f"out={tmp_path / 'out'}", "entry_direction=[0,1,0]"
    )
    print(proc.stdout, proc.stderr)
    assert proc.returncode == 0, proc.stderr
    assert (
        "assuming metres" in proc.stdout
        and "remeshing" in proc.stdout
        and "closed 1 flat open vessel end" in proc.stdout
    )
    asset = load_asset(tmp_path / "out")
    assert 8_000 < asset.hull_count < 20_000
    assert validate_and_compile(asset).ok


@pytest.fixture(scope="module")
def broken_meshes(tmp_path_factory):
    d = tmp_path_factory.mktemp("broken")
    rng = np.random.default_rng(0)
    (d / "garbage.stl").write_bytes(rng.integers(0, 256, 3000, dtype=np.uint8).tobytes())
    box = trimesh.creation.box(extents=(20, 20, 20))
    n = box.face_normals
    # Two adjacent faces removed: an L-shaped hole no safe repair can close.
    keep = ~((n[:, 0] > 0.9) | (n[:, 1] > 0.9))
    trimesh.Trimesh(box.vertices, box.faces[keep], process=False).export(d / "open_cube.stl")
    # A fin: a third triangle on one of the box's edges.
    v = np.vstack([box.vertices, [[30, 30, 30]]])
    e = box.edges_unique[0]
    trimesh.Trimesh(v, np.vstack([box.faces, [[e[0], e[1], len(v) - 1]]]), process=False).export(d / "fin.stl")
    (d / "empty.obj").write_text("# no faces\nv 0 0 0\n")
    return d


@pytest.mark.parametrize(
    "fname, repair, needles",
    [
        ("garbage.stl", "auto", ["garbage.stl", "contains no triangles"]),
        ("open_cube.stl", "surface", ["open_cube.stl", "not watertight", "not a flat vessel end"]),
        # The volume closes gaps up to close_mm; two missing faces of a 20 mm box are wider.
        ("open_cube.stl", "auto", ["open_cube.stl", "the surface is open", "entry=[0.0, 0.0, 0.0] mm", "close_mm"]),
        ("fin.stl", "surface", ["fin.stl", "non-manifold", "shared by more than two triangles"]),
        ("empty.obj", "auto", ["empty.obj", "contains no triangles"]),
        ("missing.stl", "auto", ["missing.stl", "no such file"]),
    ],
)
def test_broken_mesh_is_refused_with_one_line(broken_meshes, tmp_path, fname, repair, needles):
    proc = run(
        "import",
        f"mesh={broken_meshes / fname}",
        "entry=[0,0,0]",
        "sites.bca=[5,5,5]",
        f"out={tmp_path / 'x'}",
        f"repair={repair}",
    )
    print(assert_one_line_error(proc, *needles))
    assert not (tmp_path / "x").exists()


def test_site_outside_the_lumen_is_refused(type1_mm_stl, tmp_path):
    stl, src = type1_mm_stl
    proc = run(
        "import", f"mesh={stl}", f"entry={vec(src.entry_position, 1e3)}", "sites.bca=[0,200,0]", f"out={tmp_path / 'x'}"
    )
    print(assert_one_line_error(proc, "sites.bca=[0.0, 200.0, 0.0] mm is outside the lumen"))
    proc = run("import", f"mesh={stl}", "entry=[0,0,0]", "sites.bca=[0,200,0]", "units=furlongs")
    print(assert_one_line_error(proc, "units='furlongs' is not valid", "mm"))
    proc = run("import", f"mesh={stl}", "sites.bca=[0,200,0]", "sites=frobnicate")
    print(assert_one_line_error(proc, "sites='frobnicate' is not valid", "sites=auto"))


def test_bad_crop_caps_and_frame_values_are_refused_before_any_work(type1_mm_stl, tmp_path):
    stl, src = type1_mm_stl
    base = [
        "import",
        f"mesh={stl}",
        f"entry={vec(src.entry_position, 1e3)}",
        f"sites.bca={vec(src.sites['bca'], 1e3)}",
        f"out={tmp_path / 'x'}",
    ]
    print(assert_one_line_error(run(*base, "crop=some"), "crop='some' is not valid", "'auto', 'none'"))
    print(assert_one_line_error(run(*base, "crop_mm=2"), "crop_mm=2 is not valid", "5 mm or more"))
    print(assert_one_line_error(run(*base, f"caps=[{tmp_path / 'inlet.stl'}]"), "inlet.stl is not a file"))
    print(assert_one_line_error(run(*base, "frame=LSP"), "frame='LSP' is not valid", "['sim', 'LPS', 'RAS']"))
    # Before the mesh is read: a missing file is not reached.
    missing = ["import", f"mesh={tmp_path / 'none.stl'}", *base[2:], "frame=xyz"]
    print(assert_one_line_error(run(*missing), "frame='xyz' is not valid"))
    assert not (tmp_path / "x").exists()


def test_an_oversize_mesh_is_refused_before_any_grid(type1_mm_stl, tmp_path):
    stl, src = type1_mm_stl
    # The millimetre mesh read as metres: 217 m across.
    proc = run(
        "import",
        f"mesh={stl}",
        "units=m",
        f"entry={vec(src.entry_position, 1e3)}",
        f"sites.bca={vec(src.sites['bca'], 1e3)}",
        f"out={tmp_path / 'x'}",
    )
    print(assert_one_line_error(proc, "spans 217 m with units=m", "pass the right units="))
    assert not (tmp_path / "x").exists()


def test_the_grid_memory_is_planned_before_it_is_allocated(type1_mm_stl):
    import re

    from cathsim_dmc.anatomy.importer import MeshImportError
    from cathsim_dmc.anatomy.mesh_grid import check_grid_memory

    _, src = type1_mm_stl
    v, f = src.visual_vertices.astype(np.float64), src.visual_faces.astype(np.int64)
    # The type I arch at 0.5 mm: 14.4 M nodes, measured peak 1.8 GB.
    need = check_grid_memory(v, f, 0.0005, 0.013, "t1.stl", available_bytes=64 * 2**30)
    assert 1.5e9 < need < 2.5e9
    with pytest.raises(MeshImportError, match=r"needs about 1\.\d GiB, 1\.0 GiB available; pass sdf_mm=") as error:
        check_grid_memory(v, f, 0.0005, 0.013, "t1.stl", available_bytes=2**30)
    suggested_mm = float(re.search(r"sdf_mm=([\d.]+) or more", str(error.value)).group(1))
    assert suggested_mm > 0.5
    check_grid_memory(v, f, suggested_mm * 1e-3, 0.013, "t1.stl", available_bytes=2**30)


def _bca_profile(src):
    from cathsim_dmc.anatomy.validate import _lumen_mesh, lumen_profile

    return lumen_profile(src.centerlines["bca"].points, *_lumen_mesh(src))


def _shallow_bca_site(src):
    """A point on the BCA centerline 2 mm past the middle of its opening's flare (the
    BCA's lumen radius there is about 8 mm)."""
    from cathsim_dmc.anatomy.polyline import arclength
    from cathsim_dmc.anatomy.validate import branch_depth

    pts, rad = _bca_profile(src)
    depth, _ = branch_depth(pts, rad)
    s = arclength(pts)
    return pts[np.searchsorted(s, s[-1] - depth + 0.002)]


def test_sites_that_make_no_task_are_refused_before_the_remesh(type1_mm_stl, tmp_path):
    stl, src = type1_mm_stl
    entry = f"entry={vec(src.entry_position, 1e3)}"
    at_entry = src.entry_position + [0, 0.003, 0]
    proc = run("import", f"mesh={stl}", entry, f"sites.bca={vec(at_entry, 1e3)}", f"out={tmp_path / 'x'}")
    print(assert_one_line_error(proc, "sites.bca=", "coincides with the entry"))
    proc = run("import", f"mesh={stl}", entry, f"sites.bca={vec(_shallow_bca_site(src), 1e3)}", f"out={tmp_path / 'x'}")
    print(assert_one_line_error(proc, "sites.bca=", "into its branch", "move it deeper"))
    assert not (tmp_path / "x").exists()


def test_site_placement_checks_on_the_shipped_centerlines():
    from cathsim_dmc.anatomy.validate import _lumen_mesh, lumen_profile, site_placement_problems

    src = load_asset(ROOT / "assets" / "type1")
    lines = {k: lumen_profile(c.points, *_lumen_mesh(src)) for k, c in src.centerlines.items()}
    assert site_placement_problems(lines) == []  # shipped sites sit 36-38 mm past their openings
    pts, rad = lines["bca"]
    shallow = _shallow_bca_site(src)
    cut = int(np.argmin(np.linalg.norm(pts - shallow, axis=1))) + 1
    problems = site_placement_problems({"bca": (pts[:cut], rad[:cut])})
    assert len(problems) == 1 and "site bca is" in problems[0] and "into its branch" in problems[0]
    problems = site_placement_problems({"bca": (pts[:3], rad[:3])})
    assert len(problems) == 1 and "coincides with the entry" in problems[0]


def test_build_a_generated_variant(tmp_path):
    out = tmp_path / "my_arch"
    proc = run(
        "build",
        "name=my_arch",
        "arch_type=3",
        "seed=7",
        f"out={out}",
        "validate=false",
        "edge_length_m=0.005",
        "sdf_spacing_m=0.002",
    )  # coarse: the arch type is the centerlines'
    print(proc.stdout, proc.stderr)
    assert proc.returncode == 0, proc.stderr
    asset = load_asset(out)
    assert asset.name == "my_arch" and asset.meta["arch_type"] == "III"
    assert asset.arch_type_distance_m / asset.cca_diameter_m > 2
    assert "arch type III" in proc.stdout
    # Not over an existing folder without overwrite=true; bad keys and values are named.
    assert_one_line_error(run("build", f"out={out}", "validate=false"), "exists and is not empty")
    assert_one_line_error(run("build", "arch_type=5"), "arch_type=5 is not valid")
    assert_one_line_error(run("build", "arch_widht_m=0.05"), "arch_widht_m", "arch_width_m")
    assert_one_line_error(run("build", "preset=type9"), "preset='type9' is not valid", "type1")


def test_build_into_the_cache(tmp_path):
    args = ("build", "preset=bovine", "edge_length_m=0.005", "sdf_spacing_m=0.002", "validate=false")
    first = run(*args, env={"CATHSIM_DMC_CACHE": str(tmp_path)})
    assert first.returncode == 0, first.stderr
    folder = pathlib.Path(first.stdout.split("cached in ")[1].split()[0])
    assert folder.parent == tmp_path / "aortas" and (folder / "meta.json").is_file()
    stamp = (folder / "collision.npz").stat().st_mtime_ns
    second = run(*args, env={"CATHSIM_DMC_CACHE": str(tmp_path)})
    assert second.returncode == 0 and f"cached in {folder}" in second.stdout
    assert (folder / "collision.npz").stat().st_mtime_ns == stamp
