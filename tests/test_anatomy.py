"""Checks of the procedural arch generator and the shipped `assets/type1`.

Geometry checks run on the committed asset (what users load); the determinism
check rebuilds a coarse variant twice. Run with `-s` to see the measured numbers.
"""

import json
import pathlib
import shutil
import time

import mujoco
import numpy as np
import pytest
import trimesh
from scipy import spatial

from cathsim_dmc.anatomy import (BRANCHES, PRESETS, ArchParams, build_arch, build_asset, load_asset)
from cathsim_dmc.anatomy import mesh as mesh_lib

ROOT = pathlib.Path(__file__).resolve().parents[1]
TYPE1 = ROOT / "assets" / "type1"
WIRE_RADIUS_M = 0.000445          # 0.035 in guidewire
MM = 1e-3


@pytest.fixture(scope="module")
def asset():
    return load_asset(TYPE1)


@pytest.fixture(scope="module")
def lumen(asset):
    return trimesh.Trimesh(asset.visual_vertices.astype(np.float64), asset.visual_faces, process=False)


@pytest.fixture(scope="module")
def model(asset):
    return build_arch(ArchParams(**asset.params))


@pytest.fixture(scope="module")
def cap(asset):
    y_open = asset.meta["open_end"]["center"][1]
    tri_y = asset.visual_vertices[asset.visual_faces][:, :, 1]
    return np.all(np.abs(tri_y - y_open) < 1e-7, axis=1)


class Prisms:
    """Half-space form of every hull, with a KD prefilter, for point-in-hull tests."""

    def __init__(self, asset):
        hulls = [h.astype(np.float64) for h in asset.hulls]
        self.volumes = np.empty(len(hulls))
        eqs = []
        for i, h in enumerate(hulls):
            ch = spatial.ConvexHull(h)
            self.volumes[i] = ch.volume
            eqs.append(ch.equations)
        m = max(len(e) for e in eqs)
        self.eq = np.zeros((len(hulls), m, 4))
        self.eq[:, :, 3] = -1.0                     # padding rows: always satisfied
        for i, e in enumerate(eqs):
            self.eq[i, :len(e)] = e
        self.centroids = np.array([h.mean(axis=0) for h in hulls])
        self.reach = max(np.linalg.norm(h - c, axis=1).max() for h, c in zip(hulls, self.centroids))
        self.tree = spatial.cKDTree(self.centroids)

    def covered(self, points, tol=1e-9, exclude=()):
        """Bool per point: inside (or on) at least one hull not in `exclude`."""
        lists = self.tree.query_ball_point(points, self.reach + 1e-6)
        counts = np.array([len(c) for c in lists])
        pi = np.repeat(np.arange(len(points)), counts)
        hi = np.fromiter((j for c in lists for j in c), dtype=np.int64, count=counts.sum())
        keep = ~np.isin(hi, list(exclude))
        pi, hi = pi[keep], hi[keep]
        out = np.zeros(len(points), dtype=bool)
        for s in range(0, len(pi), 400_000):
            p, h = pi[s:s + 400_000], hi[s:s + 400_000]
            e = self.eq[h]
            val = np.einsum("nfk,nk->nf", e[:, :, :3], points[p]) + e[:, :, 3]
            out[p[np.all(val <= tol, axis=1)]] = True
        return out


@pytest.fixture(scope="module")
def prisms(asset):
    return Prisms(asset)


def inside_depth(lumen, points):
    """Signed distance to the lumen surface, positive inside the lumen."""
    return mesh_lib.signed_distance(lumen.vertices, lumen.faces, np.asarray(points, dtype=np.float64))


# ----------------------------------------------------------------------------


def test_lumen_watertight_outward_and_clean(asset, lumen, cap):
    assert lumen.is_watertight
    assert lumen.is_winding_consistent
    assert lumen.volume > 0, "faces must be oriented outward"
    assert lumen.euler_number == 2, "one closed surface without handles"
    q = mesh_lib.triangle_quality(lumen.vertices, lumen.faces[~cap])
    n_thin = int((q["min_angle"] < 10).sum())
    print(f"\nlumen: {len(lumen.faces)} triangles, edges {q['edge_min'] / MM:.2f}-{q['edge_max'] / MM:.2f} mm "
          f"(mean {q['edge_mean'] / MM:.2f}), min angle {q['min_angle'].min():.1f} deg, {n_thin} below 10 deg")
    assert 6_000 < len(lumen.faces) < 20_000
    assert n_thin == 0
    # The cap is the flat disc of the open end and nothing else.
    assert 10 < cap.sum() < 200
    np.testing.assert_allclose(lumen.face_normals[cap], [[0, -1, 0]] * int(cap.sum()), atol=1e-5)


def test_signed_distance_matches_ray_casting(asset, lumen):
    """The pseudo-normal signed distance used below agrees with trimesh's ray tests."""
    rng = np.random.default_rng(3)
    pts = np.concatenate([rng.uniform(asset.bounds[0], asset.bounds[1], (1500, 3)),
                          lumen.vertices[rng.choice(len(lumen.vertices), 500)] + rng.normal(0, 0.3 * MM, (500, 3))])
    sd = inside_depth(lumen, pts)
    far = np.abs(sd) > 1e-6
    assert np.array_equal(sd[far] > 0, lumen.contains(pts[far]))
    # Brute force distance to every triangle.
    tri = lumen.triangles
    some = np.arange(0, len(pts), 10)          # far and near-surface points
    brute = np.array([np.linalg.norm(trimesh.triangles.closest_point(tri * 1e3, np.repeat(p[None] * 1e3, len(tri), 0))
                                     - p * 1e3, axis=1).min() * 1e-3 for p in pts[some]])
    np.testing.assert_allclose(np.abs(sd[some]), brute, atol=1e-9)


def test_sites_inside_lumen(asset, lumen):
    names = sorted(asset.sites)
    assert names == sorted(BRANCHES)
    depth = inside_depth(lumen, [asset.sites[b] for b in names])
    print("\nsite depth inside lumen (mm):", dict(zip(names, np.round(depth / MM, 2))))
    assert np.all(depth >= 1 * MM)


def test_centerlines_clear_for_the_wire(asset, lumen):
    for b in BRANCHES:
        pts, rad = asset.centerlines[b]
        np.testing.assert_allclose(pts[0], asset.entry_position, atol=1e-6)
        np.testing.assert_allclose(pts[-1], asset.sites[b], atol=1e-6)
        step = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        assert step.min() > 0.5 * MM and step.max() < 2.0 * MM
        depth = inside_depth(lumen, pts)
        print(f"\n{b}: {len(pts)} points, {step.sum() * 100:.1f} cm, min clearance {depth.min() / MM:.2f} mm")
        assert depth.min() >= WIRE_RADIUS_M + 0.5 * MM
        # radius_m is the distance to the wall: never more than the clearance
        # from the closed mesh except near the open end (whose cap is not wall).
        assert np.all(rad >= depth - 1e-6)
        assert np.all(rad >= WIRE_RADIUS_M + 0.5 * MM)


def test_anatomy_landmarks(asset, model):
    p = PRESETS["type1"]
    s = asset.sites
    # BCA most proximal (patient right), LSA most distal (patient left), all above the arch.
    assert s["bca"][0] < s["lcca"][0] < s["lsa"][0]
    for b in BRANCHES:
        assert s[b][1] > model.arch_top_y
    assert model.aorta.points[:, 0].max() > 0 > model.aorta.points[:, 0].min()
    # Type I: BCA origin less than one CCA diameter below the top of the arch.
    assert asset.arch_type_distance_m < asset.cca_diameter_m
    assert asset.cca_diameter_m == pytest.approx(p.lcca_diameter_m)
    np.testing.assert_allclose(asset.entry_direction, [0, 1, 0])
    lengths = {b: np.linalg.norm(np.diff(asset.centerlines[b][0], axis=0), axis=1).sum() for b in BRANCHES}
    assert 0.20 <= lengths["bca"] <= 0.25
    assert lengths["bca"] > lengths["lcca"] > lengths["lsa"]
    # Descending aorta from the entry to the arch: 10-12 cm.
    assert 0.10 <= -asset.entry_position[1] <= 0.12
    # Sites ~3 cm into each branch: the distance from the ostium along the branch.
    for b in BRANCHES:
        assert 0.025 < np.linalg.norm(s[b] - model.ostia[b]) <= 0.030 + 1e-6
    # Parameters round-trip.
    assert ArchParams(**asset.params) == p


def test_hulls_convex_and_nondegenerate(asset, prisms, cap):
    sizes = np.diff(asset.hull_offsets)
    print(f"\nhulls: {asset.hull_count}, volume {prisms.volumes.min():.2e}-{prisms.volumes.max():.2e} m^3")
    assert asset.hull_count == int((~cap).sum())
    assert np.all(sizes == 6)
    tri = asset.visual_vertices[asset.visual_faces[~cap]].astype(np.float64)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    # A prism of height t over its triangle has volume ~ area * t.
    ratio = prisms.volumes / (area * asset.wall_thickness_m)
    assert ratio.min() > 0.5, ratio.min()
    for h in asset.hulls[:: max(1, asset.hull_count // 500)]:
        assert len(spatial.ConvexHull(h.astype(np.float64)).vertices) == 6


def test_no_piece_intrudes_into_lumen(asset, lumen):
    hv = asset.hull_vertices.astype(np.float64)
    rng = np.random.default_rng(0)
    hulls = hv.reshape(-1, 6, 3)
    w = rng.dirichlet(np.full(6, 0.5), size=(len(hulls), 2))
    interior = np.einsum("hsk,hkj->hsj", w, hulls).reshape(-1, 3)
    depth_v = inside_depth(lumen, hv)
    depth_i = inside_depth(lumen, interior)
    worst = max(depth_v.max(), depth_i.max())
    print(f"\nmax intrusion into the lumen: {max(worst, 0) / MM:.4f} mm (deepest signed depth {worst / MM:+.2e} mm; "
          f"{len(hv)} hull vertices, {len(interior)} interior samples)")
    assert worst <= 0.2 * MM


def _shell_samples(asset, lumen, cap, model, rng, n_uniform=40_000, n_ostia=24_000):
    v = lumen.vertices
    f = lumen.faces[~cap]
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    cen = tri.mean(axis=1)
    near = np.zeros(len(f), dtype=bool)
    for b in BRANCHES:
        near |= np.linalg.norm(cen - model.ostia[b], axis=1) < 0.015
    pick = np.concatenate([rng.choice(len(f), n_uniform, p=area / area.sum()),
                           rng.choice(np.nonzero(near)[0], n_ostia, p=area[near] / area[near].sum())])
    bary = rng.dirichlet(np.ones(3), size=len(pick))
    base = np.einsum("nk,nkj->nj", bary, tri[pick])
    vn = mesh_lib.vertex_normals(v, lumen.faces, ~cap)
    n_vert = np.einsum("nk,nkj->nj", bary, vn[f[pick]])
    n_vert /= np.linalg.norm(n_vert, axis=1, keepdims=True)
    n_face = lumen.face_normals[~cap][pick]
    use_face = rng.random(len(pick)) < 0.5
    normal = np.where(use_face[:, None], n_face, n_vert)
    dist = rng.uniform(0.01, 1.5, len(pick)) * MM
    pts = base + dist[:, None] * normal
    # Below the open end's plane is outside the vessel (the wire's way in), not wall.
    return pts[pts[:, 1] >= asset.meta["open_end"]["center"][1]], near.sum()


def test_wall_has_no_holes(asset, lumen, cap, model, prisms):
    rng = np.random.default_rng(1)
    pts, n_near = _shell_samples(asset, lumen, cap, model, rng)
    in_lumen = inside_depth(lumen, pts) > 0
    covered = prisms.covered(pts)
    holes = int(np.sum(~covered & ~in_lumen))
    print(f"\nwall shell: {len(pts)} samples (~24000 within 15 mm of the ostia, {n_near} triangles there), "
          f"{holes} holes, {int(in_lumen.sum())} fell inside the lumen")
    assert holes == 0


def test_hole_detector_finds_a_missing_piece(asset, lumen, cap, prisms):
    """Sanity check of the check above: drop a few prisms and their holes are found."""
    rng = np.random.default_rng(4)
    drop = rng.choice(asset.hull_count, 5, replace=False)
    tri = lumen.vertices[lumen.faces[~cap][drop]]
    normal = lumen.face_normals[~cap][drop]
    pts = tri.mean(axis=1) + 0.75 * MM * normal
    assert prisms.covered(pts).all()
    assert not prisms.covered(pts, exclude=drop).any()


def test_entry_is_open(asset, prisms):
    """The wire's way in along +y from below the open end meets no wall piece."""
    oe = asset.meta["open_end"]
    c, r = np.array(oe["center"]), oe["radius_m"]
    rng = np.random.default_rng(2)
    rho = (r - 1.0 * MM) * np.sqrt(rng.random(4000))
    phi = rng.uniform(0, 2 * np.pi, 4000)
    y = c[1] + rng.uniform(-0.01, asset.entry_position[1] - c[1], 4000)
    pts = np.stack([c[0] + rho * np.cos(phi), y, c[2] + rho * np.sin(phi)], axis=1)
    assert not prisms.covered(pts).any()
    # ...while the side wall around it is covered.
    ring = np.stack([c[0] + (r + 1 * MM) * np.cos(phi), c[1] + 0.005 + 0 * phi,
                     c[2] + (r + 1 * MM) * np.sin(phi)], axis=1)
    assert prisms.covered(ring).all()


def test_build_is_deterministic(tmp_path):
    params = ArchParams(name="coarse", edge_length_m=0.005, sdf_spacing_m=0.002)
    build_asset(params, tmp_path / "a")
    build_asset(params, tmp_path / "b")
    for fname in ("meta.json", "visual.stl", "collision.npz"):
        assert (tmp_path / "a" / fname).read_bytes() == (tmp_path / "b" / fname).read_bytes(), fname
    assert load_asset(tmp_path / "a").name == "coarse"


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


def test_asset_compiles_in_mujoco(asset):
    meshes, geoms = [], []
    for i, h in enumerate(asset.hulls):
        meshes.append(f'<mesh name="w{i}" vertex="{" ".join(f"{x:.7g}" for x in h.ravel())}"/>')
        geoms.append(f'<geom type="mesh" mesh="w{i}"/>')
    xml = (f"<mujoco><asset>{''.join(meshes)}</asset><worldbody><body name=\"aorta\">"
           f"{''.join(geoms)}</body></worldbody></mujoco>")
    t0 = time.perf_counter()
    model = mujoco.MjModel.from_xml_string(xml)
    seconds = time.perf_counter() - t0
    print(f"\nMuJoCo compile: {asset.hull_count} hull geoms in {seconds:.2f} s")
    assert model.ngeom == asset.hull_count and model.nmesh == asset.hull_count
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data)
