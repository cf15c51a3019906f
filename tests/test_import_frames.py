"""cathsim-aorta import frame=sim|LPS|RAS: a CT segmentation in patient coordinates (DICOM and
3D Slicer: LPS; some tools: RAS; millimetres, the scanner's origin) turned into the simulator's
frame (x patient left, y superior, z anterior), with the points given in the mesh's frame."""

import json
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from cathsim_dmc import tasks
from cathsim_dmc.anatomy import load_asset
from cathsim_dmc.anatomy.frames import FRAMES, from_sim, sim_axes, to_sim, to_sim_matrix

ROOT = pathlib.Path(__file__).resolve().parents[1]
OFFSET_LPS_MM = np.array([-123.4, 56.7, -890.1])  # a scanner's origin far from the anatomy
OFFSET_SIM_MM = to_sim(OFFSET_LPS_MM, "LPS")


def run(*args):
    script = pathlib.Path(sys.executable).with_name("cathsim-aorta")
    env = dict(os.environ, OMP_NUM_THREADS="1")
    proc = subprocess.run(
        [str(script), *map(str, args)], capture_output=True, text=True, timeout=900, cwd=ROOT, env=env
    )
    print(proc.stdout, proc.stderr)
    return proc


def vec(p):
    return "[" + ",".join(f"{x:.6f}" for x in p) + "]"  # 1 nm in millimetres


def test_frames_are_rotations_of_the_patient_axes():
    # The patient's left, superior and anterior directions written in each frame.
    patient = {
        "sim": ([1, 0, 0], [0, 1, 0], [0, 0, 1]),
        "LPS": ([1, 0, 0], [0, 0, 1], [0, -1, 0]),
        "RAS": ([-1, 0, 0], [0, 0, 1], [0, 1, 0]),
    }
    assert set(FRAMES) == set(patient)
    for frame, m in FRAMES.items():
        assert np.linalg.det(m) == pytest.approx(1.0) and np.allclose(m @ m.T, np.eye(3)), frame
        np.testing.assert_array_equal(to_sim(patient[frame], frame), np.eye(3))
        np.testing.assert_array_equal(from_sim(np.eye(3), frame), patient[frame])
        homogeneous = to_sim_matrix(frame, 1e-3) @ np.append([10.0, -20.0, 30.0], 1.0)
        np.testing.assert_allclose(homogeneous[:3], to_sim([10.0, -20.0, 30.0], frame) * 1e-3, rtol=0, atol=1e-15)
    assert (sim_axes("sim"), sim_axes("LPS"), sim_axes("RAS")) == ("[x, y, z]", "[x, z, -y]", "[-x, z, y]")
    # The type I arch's entry and sites as a scanner gives them: in LPS the BCA (on the patient's
    # right) has the smallest x, and every site lies far superior of the entry (z) and a few mm
    # anterior of it (smaller y); RAS reverses x and y.
    src = load_asset(ROOT / "assets" / "type1")
    entry = src.entry_position * 1e3 + OFFSET_SIM_MM
    sites = {k: p * 1e3 + OFFSET_SIM_MM for k, p in src.sites.items()}
    lps = {k: from_sim(p, "LPS") for k, p in sites.items()}
    ras = {k: from_sim(p, "RAS") for k, p in sites.items()}
    e_lps, e_ras = from_sim(entry, "LPS"), from_sim(entry, "RAS")
    np.testing.assert_allclose(e_lps, [-93.4, 61.7, -1000.1], atol=1e-9)
    np.testing.assert_allclose(e_ras, [93.4, -61.7, -1000.1], atol=1e-9)
    assert lps["bca"][0] < lps["lcca"][0] < lps["lsa"][0] and ras["bca"][0] > ras["lcca"][0] > ras["lsa"][0]
    for k in sites:
        assert lps[k][2] - e_lps[2] > 150 and ras[k][2] - e_ras[2] > 150, k  # superior
        assert lps[k][1] < e_lps[1] and ras[k][1] > e_ras[1], k  # anterior
        np.testing.assert_allclose(to_sim(lps[k], "LPS"), sites[k], atol=1e-9)
        np.testing.assert_allclose(to_sim(ras[k], "RAS"), sites[k], atol=1e-9)


def test_an_lps_segmentation_at_a_scanner_origin_imports_and_simulates(tmp_path):
    """The type I lumen as a Slicer export would hold it (LPS millimetres, far from the origin): the
    asset is the arch in the simulator's frame, at the scanner's offset, and the robot finds its entry."""
    src = load_asset(ROOT / "assets" / "type1")
    lps = from_sim(src.visual_vertices.astype(np.float64) * 1e3, "LPS") + OFFSET_LPS_MM
    mesh = tmp_path / "lumen_lps.stl"
    trimesh.Trimesh(lps, src.visual_faces, process=False).export(mesh)
    given = {k: from_sim(p * 1e3, "LPS") + OFFSET_LPS_MM for k, p in src.sites.items()}
    entry = from_sim(src.entry_position * 1e3, "LPS") + OFFSET_LPS_MM
    out = tmp_path / "patient"
    # The generator's own edge length and no crop keep the triangles as they are (fast, and comparable).
    proc = run(
        "import",
        f"mesh={mesh}",
        "units=mm",
        "frame=LPS",
        f"entry={vec(entry)}",
        *[f"sites.{k}={vec(p)}" for k, p in sorted(given.items())],
        f"out={out}",
        f"edge_mm={src.params['edge_length_m'] * 1e3}",
        "crop=none",
    )
    assert proc.returncode == 0, proc.stderr
    assert "frame=LPS: the mesh and the points given turned into the simulator's frame" in proc.stdout
    assert "keeping the" in proc.stdout
    asset = load_asset(out)
    offset_m = OFFSET_SIM_MM * 1e-3
    for k, p in src.sites.items():
        np.testing.assert_allclose(asset.sites[k], p + offset_m, rtol=0, atol=1e-8)  # meta.json keeps 10 nm
    np.testing.assert_allclose(asset.entry_position, src.entry_position + offset_m, rtol=0, atol=1e-8)
    assert np.dot(asset.entry_direction, [0, 1, 0]) > 0.999  # up the descending aorta: superior
    # The lumen is the shipped one moved by the offset (its open end is cut again a few mm behind the entry).
    np.testing.assert_allclose(asset.bounds[1], src.bounds[1] + offset_m, rtol=0, atol=1e-6)
    low = asset.bounds[0] - (src.bounds[0] + offset_m)
    assert np.all(np.abs(low) <= [1e-4, 6e-3, 1e-4]), low
    assert abs(asset.hull_count / src.hull_count - 1) < 0.01
    for k in src.sites:
        length = lambda a: np.linalg.norm(np.diff(a.centerlines[k].points, axis=0), axis=1).sum()  # noqa: E731
        assert abs(length(asset) / length(src) - 1) < 0.01, k
    # The card says what was done and maps the asset's points back to the ones given.
    meta = json.loads((out / "meta.json").read_text())
    card = meta["source_frame"]
    assert card["frame"] == "LPS" and card["units"] == "mm" and meta["params"]["frame"] == "LPS"
    back = np.asarray(card["from_sim"])
    np.testing.assert_allclose(back @ np.asarray(card["to_sim"]), np.eye(4), atol=1e-12)
    for k, p in given.items():  # meta.json keeps 10 nm
        np.testing.assert_allclose(back @ np.append(asset.sites[k], 1.0), np.append(p, 1.0), rtol=0, atol=1e-4)
    assert "LPS" in meta["description"]
    # It simulates there: the robot at the entry pushes the wire up the aorta, inside the lumen.
    env = tasks.load(task="bca", aorta=str(out), obs="pixels", seed=0)
    env.reset()
    task, physics = env.task, env.physics
    tip0 = task.tip_position_m(physics)
    assert np.linalg.norm(tip0 - asset.entry_position) < 0.03
    for _ in range(20):
        env.step(np.array([1.0, 0.0]))
    assert (task.tip_position_m(physics) - tip0) @ asset.entry_direction > 0.05
    assert task.containment.contains(task.wire_points_m(physics)).all()
    assert env.physics.data.time > 0


def _write_in_frame(tmp_path, world_mm, faces, frame):
    path = tmp_path / f"lumen_{frame}.stl"
    trimesh.Trimesh(from_sim(world_mm, frame), faces, process=False).export(path)
    return path


def _ap_images(folder):
    """The top camera's (AP) pixels after a seeded reset and after a few steps."""
    env = tasks.load(task="bca", aorta=str(folder), obs="pixels", seed=3)
    images = [env.reset().observation["pixels"]]
    for _ in range(5):
        images.append(env.step(np.array([1.0, 0.3])).observation["pixels"])
    return np.stack(images)


@pytest.mark.slow
def test_the_same_segmentation_in_three_frames_gives_the_same_asset(tmp_path):
    """The decimated corpus mesh at a scanner's origin, written in the simulator's axes, in LPS and in
    RAS (the same float32 numbers, permuted and negated), with its entry and sites written the same
    way, imported with the defaults: one asset, three times, bit for bit; and the same AP images.

    The offset is in all three files: the importer keeps the scanner's origin, and its voxel grids
    lie on a lattice fixed in space, so a mesh moved by an arbitrary offset voxelises a little
    differently (this mesh gives 10398 wall pieces at the generator's origin, 10716 at this offset)."""
    from cathsim_dmc.anatomy.corpus import make_variant

    path, entry, sites = make_variant("decimated", tmp_path / "corpus")
    mesh = trimesh.load(path, process=False)
    world = (np.asarray(mesh.vertices) + OFFSET_SIM_MM).astype(np.float32).astype(np.float64)
    points = {"entry": entry, **{f"sites.{k}": sites[k] for k in ("bca", "lcca")}}
    assets, images = {}, {}
    for frame in FRAMES:
        stl = _write_in_frame(tmp_path, world, mesh.faces, frame)
        given = [f"{k}={vec(from_sim(p + OFFSET_SIM_MM, frame))}" for k, p in points.items()]
        proc = run("import", f"mesh={stl}", f"frame={frame}", *given, f"out={tmp_path / frame}")
        assert proc.returncode == 0, proc.stderr
        assets[frame] = load_asset(tmp_path / frame)
        images[frame] = _ap_images(tmp_path / frame)
    ref = assets["sim"]
    for k in ("bca", "lcca"):
        np.testing.assert_allclose(ref.sites[k], (sites[k] + OFFSET_SIM_MM) * 1e-3, rtol=0, atol=1e-8)
    assert ref.entry_direction[1] > 0.99
    for frame in ("LPS", "RAS"):
        a = assets[frame]
        assert a.hull_count == ref.hull_count
        np.testing.assert_array_equal(a.visual_vertices, ref.visual_vertices)
        np.testing.assert_array_equal(a.visual_faces, ref.visual_faces)
        np.testing.assert_array_equal(a.hull_vertices, ref.hull_vertices)
        np.testing.assert_allclose(a.entry_position, ref.entry_position, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.entry_direction, ref.entry_direction, rtol=0, atol=1e-12)
        for k in ref.sites:
            np.testing.assert_allclose(a.sites[k], ref.sites[k], rtol=0, atol=1e-12)
            np.testing.assert_allclose(a.centerlines[k].points, ref.centerlines[k].points, rtol=0, atol=1e-12)
            np.testing.assert_allclose(a.centerlines[k].radius, ref.centerlines[k].radius, rtol=0, atol=1e-12)
        assert a.meta["source_frame"]["frame"] == frame
        np.testing.assert_array_equal(images[frame], images["sim"])
    assert "source_frame" not in ref.meta and "frame" not in ref.params  # sim: recorded as before
    print("wall pieces", ref.hull_count)
    assert images["sim"].std() > 5  # the AP view shows something
