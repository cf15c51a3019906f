"""cathsim-aorta import without entry= and sites.*= (sites=auto): the entry and the supra-aortic
branches found from the lumen's centerline tree, named from the patient's right (BCA, LCCA, LSA);
given sites checked against them (a BCA and LCCA given the wrong way round are refused)."""

import json
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from cathsim_dmc.anatomy import load_asset
from cathsim_dmc.anatomy.branches import ArchError, find_arch, swap_message, swapped_site
from cathsim_dmc.anatomy.mesh_grid import mesh_sdf_grid

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPT = pathlib.Path(sys.executable).with_name("cathsim-aorta")


def run(*args):
    env = dict(os.environ, OMP_NUM_THREADS="1")
    proc = subprocess.run(
        [str(SCRIPT), *map(str, args)], capture_output=True, text=True, timeout=900, cwd=ROOT, env=env
    )
    print(proc.stdout, proc.stderr)
    return proc


def vec(p):
    return "[" + ",".join(f"{x:.6f}" for x in p) + "]"


def lumen_mm(asset, tmp_path):
    a = load_asset(ROOT / "assets" / asset)
    path = tmp_path / f"{asset}_mm.stl"
    trimesh.Trimesh(a.visual_vertices.astype(np.float64) * 1e3, a.visual_faces, process=False).export(path)
    return path, a


def nearest_target(point, asset):
    """The shipped target whose centerline passes nearest `point` (beyond the shared aorta)."""
    d = {}
    for k, (pts, _) in asset.centerlines.items():
        pts = np.asarray(pts)
        d[k] = float(np.min(np.linalg.norm(pts - point, axis=1)))
    return min(d, key=d.get), d


@pytest.fixture(scope="module")
def trees():
    out = {}
    for name in ("type1", "bovine"):
        a = load_asset(ROOT / "assets" / name)
        grid = mesh_sdf_grid(a.visual_vertices.astype(np.float64), a.visual_faces, 0.001, 0.004)
        out[name] = (find_arch(grid), a, grid)
    return out


def test_the_arch_tree_names_the_branches_and_finds_the_bovine_trunk(trees):
    for name, (tree, a, _) in trees.items():
        assert tree.order == ["bca", "lcca", "lsa"], name
        assert np.linalg.norm(tree.entry - a.entry_position) < 0.003, (name, tree.entry)
        for k, p in tree.sites().items():
            # 3 cm past the opening, like the shipped sites: within 1 cm of them, on the right branch
            assert nearest_target(p, a)[0] == k, (name, k, nearest_target(p, a))
            assert np.linalg.norm(p - a.sites[k]) < 0.011, (name, k, p, a.sites[k])
            assert tree.branch_of(p) == k and tree.branch_of(a.sites[k]) == k, (name, k)
        assert tree.branch_of(a.entry_position) is None  # the aorta is no branch
    assert trees["bovine"][0].trunk and not trees["type1"][0].trunk
    assert "common trunk (bovine arch)" in trees["bovine"][0].notes()[-1]
    tree, a, _ = trees["type1"]
    swapped = {"bca": a.sites["lcca"], "lcca": a.sites["bca"]}
    assert swapped_site(tree, swapped) == ("bca", "lcca")
    assert swapped_site(tree, a.sites) is None
    assert swap_message("bca", "lcca", tree, "[1, 2, 3]") == (
        "sites.bca=[1, 2, 3] lies in the second branch from the patient's right (the LCCA); "
        "give the sites the other way round or check frame="
    )


def test_a_tree_with_one_branch_is_ambiguous(trees):
    """A lumen cut below the arch's top (two branches' tips cut away) cannot name its sites."""
    grid = trees["type1"][2]
    y = grid.origin[1] + grid.spacing * np.arange(grid.values.shape[1])
    cut = grid.values.copy()
    cut[:, y > 0.04, :] = 0.01  # everything above the arch's top is outside
    grid = type(grid)(grid.origin, grid.spacing, cut)
    with pytest.raises(ArchError, match=r"not 2-3 supra-aortic branches; give them: entry=\[x,y,z\] sites.bca="):
        find_arch(grid)


def test_import_without_sites_finds_them(tmp_path):
    mesh, a = lumen_mm("type1", tmp_path)
    out = tmp_path / "found"
    proc = run("import", f"mesh={mesh}", "units=mm", f"out={out}")
    assert proc.returncode == 0, proc.stderr
    assert "found BCA, LCCA, LSA (from the patient's right)" in proc.stdout
    meta = json.loads((out / "meta.json").read_text())
    assert meta["params"]["sites_found"] == "auto"
    assert sorted(meta["sites"]) == ["bca", "lcca", "lsa"]
    assert np.linalg.norm(np.array(meta["entry"]["position"]) - a.entry_position) < 0.003
    for k, p in meta["sites"].items():
        assert nearest_target(np.array(p), a)[0] == k, (k, p)
        assert np.linalg.norm(np.array(p) - a.sites[k]) < 0.011, (k, p)
    assert not any("trunk" in n for n in meta["import"]["notes"])


def test_swapped_sites_are_refused_in_one_line(tmp_path):
    mesh, a = lumen_mm("type1", tmp_path)
    proc = run(
        "import",
        f"mesh={mesh}",
        "units=mm",
        f"entry={vec(a.entry_position * 1e3)}",
        f"sites.bca={vec(a.sites['lcca'] * 1e3)}",
        f"sites.lcca={vec(a.sites['bca'] * 1e3)}",
        f"out={tmp_path / 'swapped'}",
    )
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "sites.bca=[-1.3, 79.2, 0.3] lies in the second branch from the patient's right (the LCCA)" in lines[0]
    assert "give the sites the other way round or check frame=" in lines[0]
    assert not (tmp_path / "swapped").exists()


@pytest.mark.slow
def test_a_bovine_import_reports_the_common_trunk(tmp_path):
    mesh, a = lumen_mm("bovine", tmp_path)
    out = tmp_path / "bovine"
    proc = run("import", f"mesh={mesh}", "units=mm", f"out={out}")
    assert proc.returncode == 0, proc.stderr
    meta = json.loads((out / "meta.json").read_text())
    assert any("common trunk (bovine arch)" in n for n in meta["import"]["notes"]), meta["import"]["notes"]
    for k, p in meta["sites"].items():
        assert nearest_target(np.array(p), a)[0] == k, (k, p)
