"""Geometric validation of an aorta asset folder (generated or imported).

    from cathsim_dmc.anatomy.validate import validate_asset
    report = validate_asset("assets/type2")
    print(report.summary()); assert report.ok, report.problems

Checks, each on the files a user loads (visual lumen + collision pieces + meta):

- **lumen open**: a sphere of radius `probe_radius_m` (the 0.035 in wire's
  0.445 mm radius + 0.5 mm) travels every centerline from the entry to its site
  without touching any collision piece (exact point-to-convex-piece distance
  on the centerline resampled every 0.25 mm);
- **sites**: every site lies inside the lumen, at least `min_site_depth_m` from
  the wall; every centerline runs from the entry to its site;
- **no intrusion**: points sampled in every piece (its vertices, random interior
  points, several per piece around every ostium) lie at most
  `max_intrusion_m` inside the lumen;
- **continuous wall**: points sampled in the wall shell (0.01 mm to 3/4 of the
  wall thickness outside the lumen surface, uniformly by area plus densely
  within `ostium_radius_m` of every ostium) each lie inside some piece or
  inside the lumen; the open end (beyond the plane of ``meta["open_end"]``) is
  the wire's way in and is not wall;
Ostia come from ``meta["ostia"]`` (the generator writes them) or are estimated
from the centerlines (where the lumen radius jumps, and where the centerlines
to different sites part).

No MuJoCo here: `cathsim_dmc.sim.model_check.validate_and_compile` adds the check
that the pieces and the visual mesh compile and step.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Dict, List, Optional

import numpy as np
from scipy import spatial

from cathsim_dmc.anatomy.asset import AortaAsset, load_asset
from cathsim_dmc.anatomy.polyline import arclength, resample_polyline
from cathsim_dmc.anatomy.sdf import signed_distance, unsigned_distance
from cathsim_dmc.anatomy.triangles import face_normals, vertex_normals

WIRE_RADIUS_M = 0.000445  # 0.035 in guidewire
PROBE_RADIUS_M = WIRE_RADIUS_M + 0.0005
MAX_INTRUSION_M = 0.0002
MIN_SITE_DEPTH_M = 0.001


class HullSet:
    """Convex pieces in half-space and facet form, with a KD prefilter on their centroids."""

    def __init__(self, hulls):
        hulls = [np.asarray(h, dtype=np.float64) for h in hulls]
        eqs, facets = [], []
        self.volumes = np.empty(len(hulls))
        for i, h in enumerate(hulls):
            ch = spatial.ConvexHull(h)
            self.volumes[i] = ch.volume
            eqs.append(ch.equations)
            facets.append(h[ch.simplices])
        m = max(len(e) for e in eqs)
        self.eq = np.zeros((len(hulls), m, 4))
        self.eq[:, :, 3] = -1.0  # padding rows: always satisfied
        t = max(len(f) for f in facets)
        self.facets = np.empty((len(hulls), t, 3, 3))
        for i, (e, f) in enumerate(zip(eqs, facets)):
            self.eq[i, : len(e)] = e
            self.facets[i, : len(f)] = f
            self.facets[i, len(f) :] = f[0]  # padding: repeat a real facet
        self.centroids = np.array([h.mean(axis=0) for h in hulls])
        self.reach_each = np.array([np.linalg.norm(h - c, axis=1).max() for h, c in zip(hulls, self.centroids)])
        self.reach = float(self.reach_each.max())
        self.tree = spatial.cKDTree(self.centroids)
        self.vertex_tree = spatial.cKDTree(np.concatenate(hulls))

    def __len__(self):
        return len(self.eq)

    def _pairs(self, points, radius, exclude=()):
        lists = self.tree.query_ball_point(points, radius)
        counts = np.array([len(c) for c in lists], dtype=np.int64)
        pi = np.repeat(np.arange(len(points)), counts)
        hi = np.fromiter((j for c in lists for j in c), dtype=np.int64, count=int(counts.sum()))
        if len(exclude):
            keep = ~np.isin(hi, np.asarray(list(exclude)))
            pi, hi = pi[keep], hi[keep]
        return pi, hi

    def covered(self, points, tol=1e-9, exclude=()) -> np.ndarray:
        """Bool per point: inside (or on) at least one piece not in `exclude`."""
        points = np.asarray(points, dtype=np.float64)
        pi, hi = self._pairs(points, self.reach + 1e-6, exclude)
        out = np.zeros(len(points), dtype=bool)
        for s in range(0, len(pi), 400_000):
            p, h = pi[s : s + 400_000], hi[s : s + 400_000]
            e = self.eq[h]
            val = np.einsum("nfk,nk->nf", e[:, :, :3], points[p]) + e[:, :, 3]
            out[p[np.all(val <= tol, axis=1)]] = True
        return out

    def min_distance(self, points):
        """(distance, index): the smallest distance from any of `points` to any piece (0 inside one).

        Exact, but cheap: a lower bound per point (over the pieces that may be
        nearest, the largest signed distance to a piece's facet planes) and an
        upper bound (the nearest piece vertex) leave exact point-to-facet
        distances to compute only for the points that may hold the minimum.
        """
        import trimesh

        points = np.asarray(points, dtype=np.float64)
        if self.covered(points).any():
            i = int(np.argmax(self.covered(points)))
            return 0.0, i
        upper, _ = self.vertex_tree.query(points)
        pi, hi = self._pairs(points, upper + self.reach + 1e-9)
        near = np.linalg.norm(points[pi] - self.centroids[hi], axis=1) <= self.reach_each[hi] + upper[pi] + 1e-9
        pi, hi = pi[near], hi[near]
        lower = np.empty(len(pi))
        for s in range(0, len(pi), 200_000):
            e = self.eq[hi[s : s + 200_000]]
            lower[s : s + 200_000] = np.max(
                np.einsum("nfk,nk->nf", e[:, :, :3], points[pi[s : s + 200_000]]) + e[:, :, 3], axis=1
            )
        point_lower = np.full(len(points), np.inf)
        np.minimum.at(point_lower, pi, lower)
        best = float(upper.min())
        best_i = int(np.argmin(upper))
        keep = (point_lower[pi] < best) & (lower < upper[pi])
        pi, hi = pi[keep], hi[keep]
        nt = self.facets.shape[1]
        order = np.argsort(lower[keep], kind="stable")
        pi, hi = pi[order], hi[order]
        for s in range(0, len(pi), 20_000):
            p, h = pi[s : s + 20_000], hi[s : s + 20_000]
            tri = self.facets[h].reshape(-1, 3, 3)
            q = np.repeat(points[p], nt, axis=0)
            # In millimetres: trimesh's tolerances are absolute.
            closest = trimesh.triangles.closest_point(tri * 1e3, q * 1e3) * 1e-3
            d = np.linalg.norm(closest - q, axis=1).reshape(-1, nt).min(axis=1)
            j = int(np.argmin(d))
            if d[j] < best:
                best, best_i = float(d[j]), int(p[j])
        return best, best_i


@dataclasses.dataclass
class ValidationReport:
    name: str
    hulls: int
    triangles: int
    probe_radius_m: float
    clearance_m: Dict[str, float]  # min distance from each centerline to any collision piece
    site_depth_m: Dict[str, float]  # depth of each site inside the lumen
    max_intrusion_m: float  # deepest sampled collision point inside the lumen (<= 0: none)
    intrusion_samples: int
    shell_samples: int
    ostium_samples: int
    holes: int
    compile_seconds: Optional[float]  # MuJoCo compile (cathsim_dmc.sim.model_check); None: not run or failed
    seconds: float
    problems: List[str]

    @property
    def ok(self) -> bool:
        return not self.problems

    @property
    def min_clearance_m(self) -> float:
        return float(min(self.clearance_m.values()))

    def summary(self) -> str:
        status = "OK" if self.ok else f"FAILED ({len(self.problems)} problems)"
        clear = ", ".join(f"{k} {v * 1e3:.2f}" for k, v in sorted(self.clearance_m.items()))
        depth = ", ".join(f"{k} {v * 1e3:.1f}" for k, v in sorted(self.site_depth_m.items()))
        comp = "skipped" if self.compile_seconds is None else f"{self.compile_seconds:.2f} s"
        return (
            f"{self.name}: {status}; {self.hulls} pieces; centerline clearance to the wall (mm, probe "
            f"{self.probe_radius_m * 1e3:.3f}): {clear}; site depth (mm): {depth}; max intrusion "
            f"{max(self.max_intrusion_m, 0.0) * 1e3:.3f} mm ({self.intrusion_samples} samples); wall holes "
            f"{self.holes} of {self.shell_samples} shell samples ({self.ostium_samples} near ostia); "
            f"MuJoCo compile {comp}; checked in {self.seconds:.1f} s"
        )


def _lumen_mesh(asset: AortaAsset):
    v = asset.visual_vertices.astype(np.float64)
    f = asset.visual_faces.astype(np.int64)
    return v, f


def open_end_plane(asset: AortaAsset):
    """(centre, outward unit normal, radius) of the open end, or None."""
    oe = asset.meta.get("open_end")
    if not oe:
        return None
    n = np.asarray(oe["normal"], dtype=np.float64)
    return np.asarray(oe["center"], dtype=np.float64), n / np.linalg.norm(n), float(oe["radius_m"])


def cap_faces(asset: AortaAsset, tol: float = 2e-6) -> np.ndarray:
    """Faces of the visual mesh lying in the open-end disc (no collision piece covers them)."""
    v, f = _lumen_mesh(asset)
    plane = open_end_plane(asset)
    if plane is None:
        return np.zeros(len(f), dtype=bool)
    c, n, r = plane
    tri = v[f]
    h = (tri - c) @ n
    rho = np.linalg.norm((tri - c) - h[..., None] * n, axis=2)
    return np.all(np.abs(h) < tol, axis=1) & np.all(rho < r * 1.05 + 1e-4, axis=1)


def estimate_ostia(asset: AortaAsset) -> Dict[str, np.ndarray]:
    """Ostia from ``meta["ostia"]``, else estimated from the centerlines (`ostia_from_centerlines`)."""
    meta = asset.meta.get("ostia")
    if meta:
        return {k: np.asarray(v, dtype=np.float64) for k, v in meta.items()}
    return ostia_from_centerlines({k: (c.points, c.radius) for k, c in asset.centerlines.items()})


BRANCH_WIDENING = 1.4  # a branch opens into its parent where the lumen radius exceeds this x the branch's
MIN_PATH_ENTRY_DIAMETERS = 2.0  # a site closer to the entry than this many entry lumen diameters is no task


def branch_depth(points, radius, parent_window_m: float = 0.060) -> "tuple[Optional[float], float]":
    """(how far the site, the last point, lies past its branch's opening along the
    centerline (m; None if the lumen within `parent_window_m` before the site is never
    BRANCH_WIDENING x wider: no narrower branch), the lumen radius at the site (m)).

    `points` every ~0.5 mm with the lumen `radius` at each (the distance to the wall).
    The opening is the middle of the flare: the last point, walking back from the site,
    where the radius is halfway between the site's and the widest within the window.
    """
    pts, rad = np.asarray(points, dtype=np.float64), np.asarray(radius, dtype=np.float64)
    s = arclength(pts)
    r_site = float(np.median(rad[s >= s[-1] - 0.001]))
    window = s >= s[-1] - parent_window_m
    r_parent = float(rad[window].max())
    if r_parent < BRANCH_WIDENING * r_site:
        return None, r_site
    wide = np.nonzero(window & (rad >= 0.5 * (r_site + r_parent)))[0]
    return float(s[-1] - s[wide[-1]]), r_site


def site_placement_problems(centerlines, label=lambda name: f"site {name}") -> List[str]:
    """Sites that make no navigation task, from entry->site centerlines {name: (points,
    radius)} sampled every ~0.5 mm (`lumen_profile`): a site that (nearly) coincides with
    the entry (its centerline shorter than MIN_PATH_ENTRY_DIAMETERS entry lumen diameters),
    and a site less than its own lumen radius past its branch's opening (`branch_depth`;
    the task would end at the ostium)."""
    problems = []
    for name, (points, radius) in sorted(centerlines.items()):
        pts, rad = np.asarray(points, dtype=np.float64), np.asarray(radius, dtype=np.float64)
        length = float(arclength(pts)[-1])
        shortest = MIN_PATH_ENTRY_DIAMETERS * 2 * float(rad[0])
        if length < shortest:
            problems.append(
                f"{label(name)} is {length * 1e3:.1f} mm along the vessel from the entry (needs >= "
                f"{shortest * 1e3:.0f} mm, {MIN_PATH_ENTRY_DIAMETERS:g} entry diameters): it coincides "
                f"with the entry; move the entry or the site"
            )
            continue
        depth, r_branch = branch_depth(pts, rad)
        if depth is not None and depth < r_branch:
            problems.append(
                f"{label(name)} is {depth * 1e3:.1f} mm into its branch (needs >= {r_branch * 1e3:.1f} "
                f"mm, its lumen radius): move it deeper along the branch (the shipped sites: 35-40 mm)"
            )
    return problems


def lumen_profile(points, v, f, spacing_m: float = 0.0005):
    """(the polyline resampled every `spacing_m`, the lumen radius at each point: its
    distance to the surface v, f)."""
    dense = resample_polyline(np.asarray(points, dtype=np.float64), spacing_m)
    return dense, unsigned_distance(v, f, dense)


def ostia_from_centerlines(centerlines) -> Dict[str, np.ndarray]:
    """Junction points estimated from entry->site centerlines {name: (points, radius)}.

    Per site: walking from the site back towards the entry, the last centerline
    point whose lumen radius exceeds 1.4x the radius near the site (the branch
    opens into its parent), and the point where its centerline parts from the
    centerline of each other site (a bifurcation).
    """
    out = {}
    names = sorted(centerlines)
    for k in names:
        pts, rad = (np.asarray(a, dtype=np.float64) for a in centerlines[k])
        s = arclength(pts)
        tail = s >= s[-1] - 0.010
        r_branch = float(np.median(rad[tail]))
        wide = np.nonzero(rad > BRANCH_WIDENING * r_branch)[0]
        if len(wide):
            out[k] = pts[wide[-1]]
        for j in names:
            if j == k:
                continue
            other = np.asarray(centerlines[j][0], dtype=np.float64)
            d, _ = spatial.cKDTree(other).query(pts)
            apart = np.nonzero(d > 0.5 * np.maximum(rad, 1e-4))[0]
            if len(apart) and apart[0] > 0:
                out[f"{k}/{j}"] = pts[apart[0]]
    return out


def validate_asset(
    asset,
    *,
    shell_samples: int = 40_000,
    ostium_samples: int = 24_000,
    ostium_radius_m: float = 0.015,
    interior_per_piece: int = 1,
    interior_near_ostia: int = 4,
    probe_radius_m: float = PROBE_RADIUS_M,
    max_intrusion_m: float = MAX_INTRUSION_M,
    min_site_depth_m: float = MIN_SITE_DEPTH_M,
    seed: int = 0,
    hullset: Optional[HullSet] = None,
    checks=("sites", "lumen", "intrusion", "wall"),
) -> ValidationReport:
    """Run the checks on `asset` (an `AortaAsset` or a folder); never raises on a failed check.

    `checks` selects among "sites", "lumen" (the probe along the centerlines),
    "intrusion" and "wall". Skipped checks report NaN / 0 samples; `compile_seconds`
    is None (see `cathsim_dmc.sim.model_check`).
    """
    unknown = set(checks) - {"sites", "lumen", "intrusion", "wall"}
    if unknown:
        raise ValueError(f"unknown checks {sorted(unknown)}; choose from sites, lumen, intrusion, wall")
    t0 = time.perf_counter()
    if not isinstance(asset, AortaAsset):
        asset = load_asset(asset)
    rng = np.random.default_rng(seed)
    problems: List[str] = []
    v, f = _lumen_mesh(asset)
    sd = lambda pts: signed_distance(v, f, np.asarray(pts, dtype=np.float64))  # + inside
    hs = HullSet(asset.hulls) if hullset is None else hullset
    thickness = asset.wall_thickness_m
    ostia = estimate_ostia(asset)
    ostium_pts = np.array(list(ostia.values())) if ostia else np.zeros((0, 3))

    # --- pieces must not be degenerate
    if np.any(hs.volumes <= 0):
        problems.append(f"{int(np.sum(hs.volumes <= 0))} collision pieces have zero volume")

    # --- sites and centerlines
    names = sorted(asset.sites)
    depth = sd([asset.sites[k] for k in names]) if "sites" in checks else np.full(len(names), np.nan)
    site_depth = dict(zip(names, depth.tolist()))
    for k, d in site_depth.items():
        if d < min_site_depth_m:
            problems.append(f"site {k} is {d * 1e3:.2f} mm inside the lumen (needs >= {min_site_depth_m * 1e3:.1f} mm)")
    if "sites" in checks:
        problems += site_placement_problems({k: lumen_profile(c.points, v, f) for k, c in asset.centerlines.items()})
    clearance = {}
    for k in names:
        pts = np.asarray(asset.centerlines[k].points, dtype=np.float64)
        if np.linalg.norm(pts[0] - asset.entry_position) > 1e-5:
            problems.append(f"centerline {k} does not start at the entry")
        if np.linalg.norm(pts[-1] - asset.sites[k]) > 1e-5:
            problems.append(f"centerline {k} does not end at its site")
        if "lumen" not in checks:
            clearance[k] = float("nan")
            continue
        dense = resample_polyline(pts, 0.00025)
        clearance[k], i = hs.min_distance(dense)
        if clearance[k] < probe_radius_m:
            problems.append(
                f"centerline {k} passes {clearance[k] * 1e3:.2f} mm from a collision piece at "
                f"{np.round(dense[i] * 1e3, 1).tolist()} mm (a {probe_radius_m * 1e3:.3f} mm probe touches it)"
            )

    # --- intrusion: piece vertices + interior samples (more around the ostia)
    o = asset.hull_offsets
    sizes = np.diff(o)
    hv = asset.hull_vertices.astype(np.float64)
    samples = [np.unique(asset.hull_vertices, axis=0).astype(np.float64)] if "intrusion" in checks else []
    near_o = np.zeros(len(sizes), dtype=bool)
    if len(ostium_pts):
        near_o = np.min(np.linalg.norm(hs.centroids[:, None] - ostium_pts[None], axis=2), axis=1) < ostium_radius_m
    for reps, sel in (
        ((interior_per_piece, np.ones(len(sizes), dtype=bool)), (interior_near_ostia, near_o))
        if "intrusion" in checks
        else ()
    ):
        for _ in range(reps):
            idx = np.nonzero(sel)[0]
            if not len(idx):
                continue
            # Random convex combination of each selected piece's points.
            k = sizes[idx]
            kmax = int(k.max())
            w = rng.dirichlet(np.full(kmax, 0.5), size=len(idx))
            w[np.arange(kmax)[None] >= k[:, None]] = 0.0
            w /= w.sum(axis=1, keepdims=True)
            gather = o[idx][:, None] + np.minimum(np.arange(kmax)[None], k[:, None] - 1)
            samples.append(np.einsum("hk,hkj->hj", w, hv[gather]))
    samples = np.concatenate(samples) if samples else np.zeros((0, 3))
    intr = sd(samples) if len(samples) else np.full(1, np.nan)
    max_intrusion = float(intr.max())
    if max_intrusion > max_intrusion_m:
        i = int(np.argmax(intr))
        problems.append(
            f"a collision piece reaches {max_intrusion * 1e3:.3f} mm into the lumen at "
            f"{np.round(samples[i] * 1e3, 1).tolist()} mm (limit {max_intrusion_m * 1e3:.1f} mm)"
        )

    # --- wall continuity: shell samples
    cap = cap_faces(asset)
    wall_f = f[~cap]
    tri = v[wall_f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if "wall" not in checks:
        shell_samples = ostium_samples = 0
    pick = [rng.choice(len(wall_f), shell_samples, p=area / area.sum())]
    n_near = 0
    if len(ostium_pts) and ostium_samples:
        cen = tri.mean(axis=1)
        near = np.min(np.linalg.norm(cen[:, None] - ostium_pts[None], axis=2), axis=1) < ostium_radius_m
        if near.any():
            pick.append(rng.choice(np.nonzero(near)[0], ostium_samples, p=area[near] / area[near].sum()))
            n_near = ostium_samples
    pick = np.concatenate(pick)
    bary = rng.dirichlet(np.ones(3), size=len(pick))
    base = np.einsum("nk,nkj->nj", bary, tri[pick])
    vn = vertex_normals(v, f, ~cap)
    n_vert = np.einsum("nk,nkj->nj", bary, vn[wall_f[pick]])
    n_vert /= np.maximum(np.linalg.norm(n_vert, axis=1, keepdims=True), 1e-12)
    fn = face_normals(v, wall_f)
    use_face = rng.random(len(pick)) < 0.5
    normal = np.where(use_face[:, None], fn[pick], n_vert)
    dist = rng.uniform(0.00001, 0.75 * thickness, len(pick))
    pts = base + dist[:, None] * normal
    plane = open_end_plane(asset)
    if plane is not None:
        c, nrm, _ = plane
        pts = pts[(pts - c) @ nrm <= 0.0]
    uncovered = ~hs.covered(pts)
    holes = 0
    if uncovered.any():
        in_lumen = sd(pts[uncovered]) > 0
        holes = int(np.sum(~in_lumen))
        if holes:
            where = pts[uncovered][~in_lumen][0]
            problems.append(
                f"{holes} of {len(pts)} wall-shell samples lie in no collision piece "
                f"(first at {np.round(where * 1e3, 1).tolist()} mm)"
            )

    return ValidationReport(
        name=asset.name,
        hulls=asset.hull_count,
        triangles=len(f),
        probe_radius_m=probe_radius_m,
        clearance_m=clearance,
        site_depth_m=site_depth,
        max_intrusion_m=max_intrusion,
        intrusion_samples=len(samples),
        shell_samples=len(pts),
        ostium_samples=n_near,
        holes=holes,
        compile_seconds=None,
        seconds=time.perf_counter() - t0,
        problems=problems,
    )
