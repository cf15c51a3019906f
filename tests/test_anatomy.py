"""Checks of the procedural arch generator and every shipped asset under `assets/`.

Geometry checks run on the committed assets (what users load): the full
validation (`cathsim_dmc.anatomy.validate`: lumen open for the wire, sites inside,
no intrusion, continuous wall; `cathsim_dmc.sim.model_check`: MuJoCo compiles) for each, plus the variant
properties (arch type class, tortuosity, aneurysm size, bovine origin). The
determinism check rebuilds a coarse variant twice. Run with `-s` to see the
measured numbers.
"""

import dataclasses
import functools
import importlib.util
import json
import pathlib
import shutil

import numpy as np
import pytest
import trimesh

from cathsim_dmc.anatomy import BRANCHES, PRESETS, ArchParams, arch_type_of, build_arch, build_asset, load_asset
from cathsim_dmc.anatomy.asset import SHIPPED_MESHER_VERSIONS, recorded_mesher_version
from cathsim_dmc.anatomy.lumen import MESHER_VERSION
from cathsim_dmc.anatomy.sdf import signed_distance
from cathsim_dmc.anatomy.triangles import triangle_quality
from cathsim_dmc.anatomy.validate import PROBE_RADIUS_M, HullSet, cap_faces, validate_asset
from cathsim_dmc.core.shipped import available_aortas
from cathsim_dmc.sim.model_check import validate_and_compile

ROOT = pathlib.Path(__file__).resolve().parents[1]
ASSETS = ROOT / "assets"
TYPE1 = ASSETS / "type1"
SHIPPED = list(PRESETS)
MM = 1e-3
# Clinical arch type each shipped variant must have.
EXPECTED_TYPE = {
    "type1": "I",
    "type2": "II",
    "type3": "III",
    "aneurysm": "I",
    "low_tortuosity": "I",
    "bovine": "I",
    "type1_oblique": "I",
    "type2_oblique": "II",
    "type3_oblique": "III",
}


class _Shipped:
    """A shipped asset, its HullSet and its validation report, each computed on first use (once
    per test process): the validation takes seconds, and only its own test reads the report."""

    def __init__(self, name):
        self.asset = load_asset(ASSETS / name)

    @functools.cached_property
    def hulls(self):
        return HullSet(self.asset.hulls)

    @functools.cached_property
    def report(self):
        return validate_and_compile(self.asset, hullset=self.hulls)


_cache = {}


def shipped(name):
    """`shipped(name).asset`, `.hulls`, `.report`: the loaded asset, its HullSet, its validation."""
    if name not in _cache:
        _cache[name] = _Shipped(name)
    return _cache[name]


def trimesh_of(asset):
    return trimesh.Trimesh(asset.visual_vertices.astype(np.float64), asset.visual_faces, process=False)


def inside_depth(asset, points):
    """Signed distance to the lumen surface, positive inside the lumen."""
    return signed_distance(asset.visual_vertices, asset.visual_faces, np.asarray(points, dtype=np.float64))


# ----------------------------------------------------------------------------
# Every shipped asset


def test_every_preset_is_shipped_with_a_config():
    assert set(SHIPPED) == set(available_aortas())
    assert set(EXPECTED_TYPE) == set(SHIPPED)
    for name in SHIPPED:
        conf = ROOT / "conf" / "aorta" / f"{name}.yaml"
        assert conf.is_file(), conf
        assert f"name: {name}" in conf.read_text().splitlines()
        size = sum(f.stat().st_size for f in (ASSETS / name).iterdir())
        assert size < 1.5e6, f"{name}: {size / 1e6:.2f} MB"


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_asset_passes_validation(name):
    report = shipped(name).report
    print("\n" + report.summary())
    assert report.ok, report.problems
    assert report.holes == 0
    assert report.max_intrusion_m <= 0.2 * MM
    assert report.min_clearance_m >= PROBE_RADIUS_M
    assert min(report.site_depth_m.values()) >= 1 * MM
    assert report.ostium_samples > 0 and report.shell_samples > 50_000
    assert set(report.clearance_m) == set(BRANCHES)


@pytest.mark.parametrize("name", SHIPPED)
def test_lumen_watertight_outward_and_clean(name):
    asset = shipped(name).asset
    lumen = trimesh_of(asset)
    cap = cap_faces(asset)
    assert lumen.is_watertight and lumen.is_winding_consistent
    assert lumen.volume > 0, "faces must be oriented outward"
    assert lumen.euler_number == 2, "one closed surface without handles"
    q = triangle_quality(lumen.vertices, lumen.faces[~cap])
    n_thin = int((q["min_angle"] < 10).sum())
    print(
        f"\n{name}: {len(lumen.faces)} triangles, edges {q['edge_min'] / MM:.2f}-{q['edge_max'] / MM:.2f} mm "
        f"(mean {q['edge_mean'] / MM:.2f}), min angle {q['min_angle'].min():.1f} deg, {n_thin} below 10 deg"
    )
    assert 3_000 < len(lumen.faces) < 20_000
    assert n_thin == 0
    # The cap is the flat disc of the open end and nothing else; one prism per other face.
    assert 10 < cap.sum() < 200
    np.testing.assert_allclose(lumen.face_normals[cap], [[0, -1, 0]] * int(cap.sum()), atol=1e-5)
    assert asset.hull_count == int((~cap).sum())


@pytest.mark.parametrize("name", SHIPPED)
def test_hulls_are_nondegenerate_prisms(name):
    asset, hulls = shipped(name).asset, shipped(name).hulls
    cap = cap_faces(asset)
    assert np.all(np.diff(asset.hull_offsets) == 6)
    tri = asset.visual_vertices[asset.visual_faces[~cap]].astype(np.float64)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    # A prism of height t over its triangle has volume ~ area * t.
    ratio = hulls.volumes / (area * asset.wall_thickness_m)
    assert ratio.min() > 0.5, ratio.min()


@pytest.mark.parametrize("name", SHIPPED)
def test_arch_type_class_and_landmarks(name):
    asset = shipped(name).asset
    meta = asset.meta
    ratio = asset.arch_type_distance_m / asset.cca_diameter_m
    print(
        f"\n{name}: arch-type distance {asset.arch_type_distance_m / MM:.1f} mm = {ratio:.2f} CCA diameters "
        f"(type {arch_type_of(ratio)}), tortuosity {meta['tortuosity']}"
    )
    assert arch_type_of(ratio) == EXPECTED_TYPE[name] == meta["arch_type"]
    # ... and not near a class boundary.
    assert min(abs(ratio - 1.0), abs(ratio - 2.0)) > 0.3
    params = ArchParams(**asset.params)
    assert params == PRESETS[name], "the committed asset was built from the current preset"
    s = asset.sites
    assert s["bca"][0] < s["lcca"][0] < s["lsa"][0], "BCA most proximal (patient right), LSA most distal"
    np.testing.assert_allclose(asset.entry_direction, [0, 1, 0])
    assert 0.10 <= -asset.entry_position[1] <= 0.12, "10-12 cm of descending aorta below the arch"
    for b in BRANCHES:
        ostium = np.asarray(meta["ostia"][b])
        # Sites ~3 cm into each branch, measured from the ostium.
        assert 0.025 < np.linalg.norm(s[b] - ostium) <= 0.030 + 1e-6, b
        assert s[b][1] > ostium[1] + 0.015, f"{b} site above its ostium"
        pts, rad = asset.centerlines[b]
        np.testing.assert_allclose(pts[0], asset.entry_position, atol=1e-6)
        np.testing.assert_allclose(pts[-1], s[b], atol=1e-6)
        step = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        assert step.min() > 0.5 * MM and step.max() < 2.0 * MM
        assert 0.17 < step.sum() < 0.27
        assert np.all(rad >= PROBE_RADIUS_M)


def test_tortuosity_of_low_tortuosity_is_lower_than_type1():
    t1 = shipped("type1").asset.meta["tortuosity"]
    lo = shipped("low_tortuosity").asset.meta["tortuosity"]
    print(f"\ntype1 {t1}\nlow_tortuosity {lo}")
    assert lo["arch"] < t1["arch"] - 0.1
    assert lo["branches"] < t1["branches"]
    for b in BRANCHES:
        assert lo[b] <= t1[b]
    # Measured on the shipped centerlines too: path/chord of each branch's last 3 cm.
    for b in BRANCHES:
        dm = []
        for name in ("type1", "low_tortuosity"):
            pts = np.asarray(shipped(name).asset.centerlines[b].points)
            seg = pts[-20:]
            dm.append(np.linalg.norm(np.diff(seg, axis=0), axis=1).sum() / np.linalg.norm(seg[-1] - seg[0]))
        assert dm[1] <= dm[0] + 1e-6, (b, dm)


def lumen_diameter(asset, point, axis, n_rays=16):
    """Mean lumen width through `point` in the plane normal to `axis` (ray casts both ways)."""
    mesh = trimesh.Trimesh(asset.visual_vertices.astype(np.float64) * 1e3, asset.visual_faces, process=False)
    axis = axis / np.linalg.norm(axis)
    u = np.cross(axis, [0.0, 0.0, 1.0])
    if np.linalg.norm(u) < 0.1:
        u = np.cross(axis, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(axis, u)
    phi = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
    dirs = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * w
    origins = np.repeat(np.asarray(point)[None] * 1e3, n_rays, axis=0)
    loc, idx, _ = mesh.ray.intersects_location(origins, dirs, multiple_hits=False)
    reach = np.linalg.norm(loc - origins[idx], axis=1) * 1e-3
    assert len(reach) == n_rays
    return 2 * reach.mean()


def test_aneurysm_is_at_least_one_and_a_half_times_the_adjacent_aorta():
    asset = shipped("aneurysm").asset
    # Lumen radius (distance to the wall) along the path over the arch to the LSA.
    pts, rad = (np.asarray(a) for a in asset.centerlines["lsa"])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    peak = int(np.argmax(rad))
    below = int(np.argmin(np.abs(s - (s[peak] - 0.060))))
    tangent = lambda i: pts[min(i + 2, len(pts) - 1)] - pts[max(i - 2, 0)]
    d_peak = lumen_diameter(asset, pts[peak], tangent(peak))
    d_adjacent = lumen_diameter(asset, pts[below], tangent(below))
    ratio = d_peak / d_adjacent
    print(
        f"\naneurysm: cross-section diameter {d_peak / MM:.1f} mm at {np.round(pts[peak] / MM, 1)} mm; adjacent "
        f"descending aorta (6 cm below) {d_adjacent / MM:.1f} mm; ratio {ratio:.2f}; inscribed-sphere "
        f"ratio {rad[peak] / rad[below]:.2f}"
    )
    assert ratio >= 1.5 and rad[peak] / rad[below] >= 1.5
    assert 0.045 <= d_peak <= 0.055
    # On the proximal descending aorta / distal arch: patient left, above mid-descending, below the ostia.
    assert pts[peak][0] > 0 and -0.04 < pts[peak][1] < asset.meta["ostia"]["lsa"][1]
    # type1 has no such bulge.
    r1 = np.asarray(shipped("type1").asset.centerlines["lsa"].radius)
    assert r1.max() < 0.0145


def test_bovine_bca_and_lcca_share_one_ostium():
    asset = shipped("bovine").asset
    o = {b: np.asarray(asset.meta["ostia"][b]) for b in BRANCHES}
    assert np.linalg.norm(o["bca"] - o["lcca"]) < 1e-6
    assert np.linalg.norm(o["lsa"] - o["bca"]) > 0.015
    # Both centerlines pass through the common ostium, then part: sites 2 cm apart.
    for b in ("bca", "lcca"):
        pts = np.asarray(asset.centerlines[b].points)
        assert np.linalg.norm(pts - o["bca"], axis=1).min() < 1.5 * MM, b
    assert np.linalg.norm(asset.sites["bca"] - asset.sites["lcca"]) > 0.015
    # In type1 they have separate ostia.
    t1 = shipped("type1").asset.meta["ostia"]
    assert np.linalg.norm(np.subtract(t1["bca"], t1["lcca"])) > 0.012


def test_hole_detector_finds_a_missing_piece():
    """Sanity check of the wall check: drop the pieces around the LCCA ostium and holes are found."""
    asset, hulls = shipped("type1").asset, shipped("type1").hulls
    ostium = np.asarray(asset.meta["ostia"]["lcca"])
    drop = np.argsort(np.linalg.norm(hulls.centroids - ostium, axis=1))[:10]
    keep = np.setdiff1d(np.arange(asset.hull_count), drop)
    pieces = asset.hulls
    broken = _with_hulls(asset, [pieces[i] for i in keep])
    report = validate_asset(broken, shell_samples=5000, ostium_samples=5000, checks=("wall",))
    print("\n" + report.summary())
    assert report.holes > 0 and not report.ok


def test_intrusion_and_blockage_are_found():
    asset, hulls = shipped("type1").asset, shipped("type1").hulls
    pieces = [np.asarray(h) for h in asset.hulls]
    # Push the piece nearest the LCCA site 1 mm into the lumen...
    site = asset.sites["lcca"]
    i = int(np.argmin(np.linalg.norm(hulls.centroids - site, axis=1)))
    inward = site - hulls.centroids[i]
    inward /= np.linalg.norm(inward)
    moved = list(pieces)
    moved[i] = pieces[i] + (1.0 * MM * inward).astype(np.float32)
    report = validate_asset(_with_hulls(asset, moved), checks=("intrusion",))
    assert report.max_intrusion_m > 0.5 * MM and not report.ok
    # ...and a small cube on the BCA centerline blocks the wire.
    c = np.asarray(asset.centerlines["bca"].points)[-30]
    cube = (c + 0.5 * MM * np.array(list(np.ndindex(2, 2, 2))) - 0.25 * MM).astype(np.float32)
    report = validate_asset(_with_hulls(asset, pieces + [cube]), checks=("lumen",))
    print("\n" + "\n".join(report.problems))
    assert report.clearance_m["bca"] < PROBE_RADIUS_M
    assert any("centerline bca" in p for p in report.problems)


def _with_hulls(asset, hulls):
    sizes = [len(h) for h in hulls]
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int32)
    return dataclasses.replace(asset, hull_vertices=np.concatenate(hulls).astype(np.float32), hull_offsets=offsets)


def test_entry_is_open():
    """The wire's way in along +y from below the open end meets no wall piece."""
    for name in SHIPPED:
        asset, hulls = shipped(name).asset, shipped(name).hulls
        oe = asset.meta["open_end"]
        c, r = np.array(oe["center"]), oe["radius_m"]
        rng = np.random.default_rng(2)
        rho = (r - 1.0 * MM) * np.sqrt(rng.random(4000))
        phi = rng.uniform(0, 2 * np.pi, 4000)
        y = c[1] + rng.uniform(-0.01, asset.entry_position[1] - c[1], 4000)
        pts = np.stack([c[0] + rho * np.cos(phi), y, c[2] + rho * np.sin(phi)], axis=1)
        assert not hulls.covered(pts).any(), name
        # ...while the side wall around it is covered.
        ring = np.stack(
            [c[0] + (r + 1 * MM) * np.cos(phi), c[1] + 0.005 + 0 * phi, c[2] + (r + 1 * MM) * np.sin(phi)], axis=1
        )
        assert hulls.covered(ring).all(), name


# ----------------------------------------------------------------------------
# Generator internals (type1)


def test_signed_distance_matches_ray_casting():
    """The pseudo-normal signed distance used by the validation agrees with trimesh's ray tests."""
    asset = shipped("type1").asset
    lumen = trimesh_of(asset)
    rng = np.random.default_rng(3)
    pts = np.concatenate(
        [
            rng.uniform(asset.bounds[0], asset.bounds[1], (1500, 3)),
            lumen.vertices[rng.choice(len(lumen.vertices), 500)] + rng.normal(0, 0.3 * MM, (500, 3)),
        ]
    )
    sd = inside_depth(asset, pts)
    far = np.abs(sd) > 1e-6
    assert np.array_equal(sd[far] > 0, lumen.contains(pts[far]))
    tri = lumen.triangles
    some = np.arange(0, len(pts), 20)  # far and near-surface points
    brute = np.array(
        [
            np.linalg.norm(
                trimesh.triangles.closest_point(tri * 1e3, np.repeat(p[None] * 1e3, len(tri), 0)) - p * 1e3, axis=1
            ).min()
            * 1e-3
            for p in pts[some]
        ]
    )
    np.testing.assert_allclose(np.abs(sd[some]), brute, atol=1e-9)


def test_type1_landmarks_match_the_model():
    asset = shipped("type1").asset
    model = build_arch(ArchParams(**asset.params))
    s = asset.sites
    for b in BRANCHES:
        assert s[b][1] > model.arch_top_y
        np.testing.assert_allclose(asset.meta["ostia"][b], model.ostia[b], atol=1e-7)
    assert model.aorta.points[:, 0].max() > 0 > model.aorta.points[:, 0].min()
    assert asset.cca_diameter_m == pytest.approx(PRESETS["type1"].lcca_diameter_m)
    lengths = {b: np.linalg.norm(np.diff(asset.centerlines[b][0], axis=0), axis=1).sum() for b in BRANCHES}
    assert 0.20 <= lengths["bca"] <= 0.25
    assert lengths["bca"] > lengths["lcca"] > lengths["lsa"]
    assert asset.meta["tortuosity"]["arch"] == pytest.approx(model.tortuosity()["arch"], abs=1e-6)


def test_build_is_deterministic(tmp_path):
    params = PRESETS["bovine"].replace(name="coarse", edge_length_m=0.005, sdf_spacing_m=0.002)
    build_asset(params, tmp_path / "a")
    build_asset(params, tmp_path / "b")
    for fname in ("meta.json", "visual.stl", "collision.npz"):
        assert (tmp_path / "a" / fname).read_bytes() == (tmp_path / "b" / fname).read_bytes(), fname
    assert load_asset(tmp_path / "a").name == "coarse"


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_asset_records_its_pinned_mesher_version(name):
    """What scripts/build_assets.py builds a preset at is what its committed meta.json says
    it was built at (no key: version 1), so a rebuild at the current mesher goes with
    dropping the pin (and re-running the tables measured on it)."""
    meta = json.loads((ASSETS / name / "meta.json").read_text())
    assert recorded_mesher_version(meta) == SHIPPED_MESHER_VERSIONS.get(name, MESHER_VERSION)


@pytest.mark.slow
@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_asset_rebuilds_as_shipped(name, tmp_path):
    """Byte for byte, or (as `scripts/build_assets.py --check` accepts) with coordinates
    apart only in their last float32 bits, which vary between machines."""
    spec = importlib.util.spec_from_file_location("build_assets", ASSETS.parent / "scripts" / "build_assets.py")
    build_assets = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(build_assets)
    build_asset(PRESETS[name], tmp_path / name, mesher_version=SHIPPED_MESHER_VERSIONS.get(name))
    same, largest_m = build_assets.compare(ASSETS / name, tmp_path / name)
    assert same, f"{name}: rebuilt asset differs (largest coordinate difference {largest_m} m)"


def test_label_must_match_the_measured_arch_type(tmp_path):
    with pytest.raises(ValueError, match="labelled arch type II.*type I"):
        build_asset(ArchParams(name="x", arch_type="II", edge_length_m=0.005, sdf_spacing_m=0.002), tmp_path / "x")


def test_load_errors_are_clear(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_asset(tmp_path / "nope")
    bad = tmp_path / "bad"
    shutil.copytree(TYPE1, bad)
    (bad / "collision.npz").unlink()
    with pytest.raises(FileNotFoundError, match="missing collision.npz"):
        load_asset(bad)
    shutil.copy(TYPE1 / "collision.npz", bad / "collision.npz")
    meta = json.loads((bad / "meta.json").read_text())
    meta["format_version"] = 99
    (bad / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"format_version 99.*format_version 1"):
        load_asset(bad)
    (bad / "meta.json").write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_asset(bad)
