"""Parametric aortic arch: centerlines and lumen-radius profiles.

Frame and units: SI metres, patient frame (+y superior, +x patient left, +z
anterior). The arch lies roughly in the frontal (x-y) plane so that the AP
(`top`) camera, looking along -z, sees it unfolded. The descending aorta is at
x > 0 and its inferior end is open (femoral access, wire travels +y); the
ascending aorta is at x < 0 and ends closed a few centimetres below the arch.

The model is purely geometric: `build_arch(params)` (`parameters.ArchParams`) returns an
`ArchModel` holding one `Vessel` (dense centerline + radius per point) for the aorta and
one per branch, plus the landmarks (ostia, sites, entry) that the asset needs.
`sdf.py` and `lumen.py` turn the vessels into a lumen surface.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Dict, Tuple

import numpy as np
from scipy import interpolate

from cathsim_dmc.anatomy.parameters import BRANCHES, ArchParams, arch_type_of, ostia_obliquity_deg
from cathsim_dmc.anatomy.polyline import arclength, polyline_length, resample_polyline


def _distance_metric(points: np.ndarray) -> float:
    return polyline_length(points) / float(np.linalg.norm(points[-1] - points[0]))


@dataclasses.dataclass(frozen=True)
class Vessel:
    """A tube: dense centreline (N, 3) with a lumen radius per point."""

    name: str
    points: np.ndarray
    radius: np.ndarray

    @property
    def arclength(self) -> np.ndarray:
        return arclength(self.points)


@dataclasses.dataclass(frozen=True)
class ArchModel:
    """Centrelines, radii and landmarks of one generated arch."""

    params: ArchParams
    aorta: Vessel  # from below the open inferior end up, over the arch, to the root
    branches: Dict[str, Vessel]  # each from its origin on the aortic centreline to its closed end
    aorta_open_s: float  # arclength on `aorta` of the open inferior end (cut plane)
    branch_origin_s: Dict[str, float]  # arclength on `aorta` where each branch centreline starts
    ostia: Dict[str, np.ndarray]  # ostium centres (branch centreline meets nominal aortic wall)
    sites: Dict[str, np.ndarray]
    entry_position: np.ndarray
    entry_direction: np.ndarray
    open_end_center: np.ndarray
    open_end_radius: float
    arch_top_y: float  # top of the outer curvature (nominal tube surface)
    arch_s: Tuple[float, float] = (0.0, 0.0)  # arclength on `aorta` of the arch's ends (descending, ascending)
    # Arclength on the centreline of each branch that leaves at a slant (a take-off angle)
    # of its ostium, where it leaves the aortic wall; for the others it is the aortic radius
    # at the origin.
    branch_wall_u: Dict[str, float] = dataclasses.field(default_factory=dict)

    @property
    def vessels(self) -> Tuple[Vessel, ...]:
        return (self.aorta,) + tuple(self.branches[b] for b in BRANCHES)

    @property
    def cca_diameter_m(self) -> float:
        return self.params.lcca_diameter_m

    @property
    def arch_type_distance_m(self) -> float:
        """Vertical distance from the top of the outer curvature to the BCA ostium centre."""
        return float(self.arch_top_y - self.ostia["bca"][1])

    @property
    def obliquity_deg(self) -> float:
        """Angle of the BCA-LSA ostia line with the coronal plane (`ostia_obliquity_deg`)."""
        return ostia_obliquity_deg(self.ostia)

    @property
    def arch_type_measured(self) -> str:
        return arch_type_of(self.arch_type_distance_m / self.cca_diameter_m)

    def tortuosity(self) -> Dict[str, float]:
        """Distance metric (path length / chord, 1 = straight) of the vessel segments the wire travels.

        ``arch``: the aortic centreline over the arch, from its descending end to
        its ascending end (where the half-ellipse meets the straight tubes);
        ``<branch>``: the branch centreline from its ostium to its site;
        ``branches``: the mean of the three. Path/chord is the classic vessel
        tortuosity "distance metric" (Bullitt et al. 2003, IEEE TMI 22:1163).
        """
        s = self.aorta.arclength
        keep = (s >= self.arch_s[0]) & (s <= self.arch_s[1])
        out = {"arch": _distance_metric(self.aorta.points[keep])}
        for b in BRANCHES:
            br = self.branches[b]
            u = br.arclength
            u0 = float(np.linalg.norm(self.ostia[b] - br.points[0]))
            seg = br.points[(u >= u0) & (u <= u0 + self.params.site_depth_m)]
            out[b] = _distance_metric(seg)
        out["branches"] = float(np.mean([out[b] for b in BRANCHES]))
        return out


# ----------------------------------------------------------------------------
# Geometry helpers


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


class _ArchCurve:
    """Half-ellipse arch: theta = 0 at the descending end, pi at the ascending end."""

    def __init__(self, p: ArchParams):
        self.a = p.arch_width_m / 2.0
        self.b = p.arch_height_m
        self.hd = p.arch_depth_m / 2.0

    def point(self, theta):
        theta = np.asarray(theta, dtype=float)
        return np.stack([self.a * np.cos(theta), self.b * np.sin(theta), -self.hd * np.cos(theta)], axis=-1)

    def tangent(self, theta):
        theta = np.asarray(theta, dtype=float)
        return _unit(np.stack([-self.a * np.sin(theta), self.b * np.cos(theta), self.hd * np.sin(theta)], axis=-1))

    def normal(self, theta):
        """Outward normal (away from the curvature centre), orthogonal to the tangent."""
        theta = np.asarray(theta, dtype=float)
        n = np.stack([np.cos(theta) / self.a, np.sin(theta) / self.b, np.zeros_like(theta)], axis=-1)
        t = self.tangent(theta)
        n = n - np.sum(n * t, axis=-1, keepdims=True) * t
        return _unit(n)

    def takeoff_direction(self, theta, roll_deg: float, takeoff_deg: float):
        """(direction, stretch): a branch's first direction from the centreline at `theta`,
        `rolled_normal` leaned by `takeoff_deg` in the arch plane (positive towards the
        descending side, against the tangent), and 1 / cos(take-off), by which the path
        from the centreline to the wall grows."""
        n = self.rolled_normal(theta, roll_deg)
        if takeoff_deg == 0.0:
            return n, 1.0
        a = math.radians(takeoff_deg)
        return _unit(math.cos(a) * n - math.sin(a) * self.tangent(theta)), 1.0 / math.cos(a)

    def rolled_normal(self, theta, roll_deg: float):
        """`normal` turned by `roll_deg` about the tangent, positive towards +z (anterior)."""
        n = self.normal(theta)
        if roll_deg == 0.0:
            return n
        binormal = np.cross(n, self.tangent(theta))  # +z where the arch lies in the x-y plane
        r = math.radians(roll_deg)
        return _unit(math.cos(r) * n + math.sin(r) * binormal)


def _bisect(f, lo, hi, iters=80):
    flo = f(lo)
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        fm = f(mid)
        if (fm > 0) == (flo > 0):
            lo, flo = mid, fm
        else:
            hi = mid
    return 0.5 * (lo + hi)


# ----------------------------------------------------------------------------
# Model construction


_SAMPLE_M = 0.0005  # centreline sample spacing of the model
_CUT_MARGIN_M = 0.012  # the aorta tube continues this far below the open end (trimmed away)


def build_arch(params: ArchParams) -> ArchModel:
    """Build centrelines, radius profiles and landmarks from `params`."""
    p = params
    p.validate()
    arch = _ArchCurve(p)
    r_branch = {b: p.branch_diameter_m(b) / 2.0 for b in BRANCHES}
    # A bovine trunk (BCA and LCCA from one ostium) leaves where, and as, the BCA does.
    trunk_of = lambda b: "bca" if p.bovine and b == "lcca" else b
    roll_of = lambda b: getattr(p, f"{trunk_of(b)}_roll_deg")
    takeoff_of = lambda b: getattr(p, f"{trunk_of(b)}_takeoff_deg")

    # --- aortic centreline: from below the open end up the descending aorta,
    # over the arch, down the ascending aorta to the root. Arclength s = 0 is
    # the lower end of the part that is trimmed away by the open-end cut.
    y_open = -(p.descending_length_m + p.entry_inset_m)
    desc = np.stack([np.full(2, arch.a), [y_open - _CUT_MARGIN_M, 0.0], np.full(2, -arch.hd)], axis=1)
    desc = resample_polyline(desc, _SAMPLE_M)
    th_dense = np.linspace(0.0, math.pi, 6001)
    asc = np.stack([np.full(2, -arch.a), [0.0, -p.ascending_length_m], np.full(2, arch.hd)], axis=1)
    raw = np.concatenate([desc, arch.point(th_dense)[1:], resample_polyline(asc, _SAMPLE_M)[1:]])
    s_raw = arclength(raw)
    s_theta = s_raw[len(desc) - 1 : len(desc) - 1 + len(th_dense)]
    s_of_theta = lambda t: float(np.interp(t, th_dense, s_theta))
    points = resample_polyline(raw, _SAMPLE_M)
    s = arclength(points)
    s_open = _CUT_MARGIN_M
    s_arch0, s_arch1 = s_of_theta(0.0), s_of_theta(math.pi)

    def place_branches(r_of_theta):
        """Origin angles on the arch: BCA from the drop, then LCCA/LSA from the gaps."""
        th = np.linspace(0.0, math.pi, 4001)
        tan = arch.tangent(th)
        outer_y = arch.point(th)[:, 1] + r_of_theta(th) * np.sqrt(np.clip(1 - tan[:, 1] ** 2, 0, 1))
        top_y, theta_top = float(outer_y.max()), float(th[np.argmax(outer_y)])

        def ostium(t, b):
            direction, stretch = arch.takeoff_direction(t, roll_of(b), takeoff_of(b))
            return arch.point(t) + r_of_theta(t) * stretch * direction

        drop = lambda t: top_y - ostium(t, "bca")[1] - p.bca_origin_drop_m
        if drop(math.pi * 0.98) < 0:
            raise ValueError("ArchParams.bca_origin_drop_m is larger than the arch allows.")
        theta = {"bca": _bisect(drop, theta_top, math.pi * 0.98)}
        # LCCA then LSA, each spaced from its neighbour by the given wall-to-wall gap.
        for prev, nxt, gap in (("bca", "lcca", p.bca_lcca_gap_m), ("lcca", "lsa", p.lcca_lsa_gap_m)):
            want = r_branch[prev] + gap + r_branch[nxt]
            o_prev = ostium(theta[prev], prev)
            f = lambda t: np.linalg.norm(ostium(t, nxt) - o_prev) - want
            if f(0.05) < 0:
                raise ValueError(f"No room on the arch for the {nxt.upper()} with the given gaps.")
            theta[nxt] = _bisect(f, 0.05, theta[prev])
        if p.bovine:
            # The LCCA's origin moves onto the BCA's; the LSA stays where it
            # would be in a normal arch.
            theta["lcca"] = theta["bca"]
        return theta

    def radius_profile(theta):
        """Monotone cubic through the Hager levels (+ optional aneurysm bulge)."""
        s_br = {b: s_of_theta(theta[b]) for b in BRANCHES}
        knots = [
            (s_br["lsa"] - r_branch["lsa"] - 0.045, p.descending_diameter_m / 2),
            (s_br["lsa"] - r_branch["lsa"] - 0.008, p.isthmus_diameter_m / 2),
            (0.5 * (s_br["lsa"] + s_br["lcca"]), p.distal_arch_diameter_m / 2),
            (s_br["bca"], p.proximal_arch_diameter_m / 2),
            (s_arch1 + 0.010, p.ascending_diameter_m / 2),
        ]
        ks, kr = map(np.array, zip(*knots))
        if np.any(np.diff(ks) <= 0):
            raise ValueError("Aortic radius knots are out of order; the branches are too far apart for the arch.")
        r = interpolate.PchipInterpolator(ks, kr)(np.clip(s, ks[0], ks[-1]))
        if p.aneurysm_diameter_m > 0:
            s_c = s_arch0 + p.aneurysm_position * (s_arch1 - s_arch0)
            bump = np.exp(-0.5 * ((s - s_c) / p.aneurysm_length_m) ** 2)
            r = r + np.clip(p.aneurysm_diameter_m / 2 - r, 0, None) * bump
        return r

    # The ostia sit on the aortic wall, whose radius depends on where they are:
    # start from the Hager arch radii, then iterate (converges in 2-3 rounds).
    r_of_theta = lambda t: np.interp(
        t,
        [0.0, math.pi / 2, math.pi],
        [p.isthmus_diameter_m / 2, p.distal_arch_diameter_m / 2, p.proximal_arch_diameter_m / 2],
    )
    for _ in range(4):
        theta = place_branches(r_of_theta)
        radius = radius_profile(theta)
        r_of_theta = lambda t, r=radius: np.interp(np.vectorize(s_of_theta)(t), s, r)
    s_br = {b: s_of_theta(theta[b]) for b in BRANCHES}

    # Tortuosity of the descending aorta (lateral, in the frontal plane). The
    # arclength is recomputed afterwards and landmarks are carried over by index.
    if p.tortuosity_amplitude_m > 0:
        rng = np.random.default_rng(p.seed)
        phase = rng.uniform(0.0, 2 * math.pi)
        seg_lo, seg_hi = s_open + 0.02, s_arch0 - 0.02
        u = (s - seg_lo) / max(seg_hi - seg_lo, 1e-9)
        window = np.sin(math.pi * np.clip(u, 0, 1)) ** 2
        points = points.copy()
        points[:, 0] += (
            p.tortuosity_amplitude_m * window * np.sin(2 * math.pi * (s - seg_lo) / p.tortuosity_wavelength_m + phase)
        )
        s_new = arclength(points)
        s_br = {b: float(np.interp(v, s, s_new)) for b, v in s_br.items()}
        s_arch0, s_arch1 = (float(np.interp(v, s, s_new)) for v in (s_arch0, s_arch1))
        s = s_new
    aorta = Vessel("aorta", points, radius)

    def aorta_at(s_query):
        P = np.array([np.interp(s_query, s, points[:, k]) for k in range(3)])
        return P, float(np.interp(s_query, s, radius))

    # --- branches: straight out through the aortic wall along the arch normal (turned by
    # the take-off angle), then turning to their heading over `branch_bend_length_m`.
    branches, ostia, sites, wall_u = {}, {}, {}, {}
    phases = _branch_phases(p)
    for b in BRANCHES:
        A, R_a = aorta_at(s_br[b])
        takeoff = takeoff_of(b)
        n0, stretch = arch.takeoff_direction(theta[b], roll_of(b), takeoff)
        u_wall = R_a * stretch
        ang = math.radians(p.branch_angle_deg(b))
        d1 = np.array([math.sin(ang), math.cos(ang), 0.0])
        total = u_wall + p.branch_length_m(b)
        u = np.arange(0.0, total + 1e-12, _SAMPLE_M / 2)
        bend_start = u_wall + (p.bovine_trunk_length_m if p.bovine and b in ("bca", "lcca") else 0.0)
        w = _smoothstep((u - bend_start) / p.branch_bend_length_m)[:, None]
        dirs = _unit((1 - w) * n0 + w * d1)
        steps = np.diff(u)[:, None] * 0.5 * (dirs[1:] + dirs[:-1])
        bpts = A + np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
        bpts = resample_polyline(bpts, _SAMPLE_M)
        if p.branch_tortuosity_amplitude_m > 0:
            amplitude, wavelength = p.branch_tortuosity_amplitude_m, p.branch_tortuosity_wavelength_m
            bpts = _wiggle(bpts, u_wall, d1, amplitude, wavelength, phases[b])
        ub = arclength(bpts)
        taper = np.clip((ub - u_wall) / p.branch_length_m(b), 0, 1)
        branches[b] = Vessel(b, bpts, r_branch[b] * (1 - (1 - p.branch_taper) * taper))
        ostia[b] = A + u_wall * n0
        sites[b] = np.array([np.interp(u_wall + p.site_depth_m, ub, bpts[:, k]) for k in range(3)])
        if takeoff != 0.0:
            wall_u[b] = float(u_wall)

    # Top of the outer curvature of the final tube (highest point of its wall).
    tan_all = _unit(np.gradient(points, s, axis=0))
    top_y = float(np.max(points[:, 1] + radius * np.sqrt(np.clip(1 - tan_all[:, 1] ** 2, 0, 1))))

    open_c, r_open = aorta_at(s_open)
    entry, _ = aorta_at(s_open + p.entry_inset_m)
    if p.arch_rotation_deg != 0.0:
        # Rigid turn about the vertical line through the (straight) descending aorta, on
        # which the open end and the entry lie: they and the insertion direction stay put.
        turn = _turn_about_descending(p.arch_rotation_deg, arch)
        points = turn(points)
        aorta = Vessel("aorta", points, radius)
        branches = {b: Vessel(b, turn(v.points), v.radius) for b, v in branches.items()}
        ostia = {b: turn(v) for b, v in ostia.items()}
        sites = {b: turn(v) for b, v in sites.items()}
        open_c, entry = turn(open_c), turn(entry)
    return ArchModel(
        params=p,
        aorta=aorta,
        branches=branches,
        aorta_open_s=s_open,
        branch_origin_s=s_br,
        ostia=ostia,
        sites=sites,
        entry_position=entry,
        entry_direction=np.array([0.0, 1.0, 0.0]),
        open_end_center=open_c,
        open_end_radius=r_open,
        arch_top_y=top_y,
        arch_s=(float(s_arch0), float(s_arch1)),
        branch_wall_u=wall_u,
    )


def _branch_phases(p: ArchParams) -> Dict[str, float]:
    """The branch tortuosity's phase per branch, from `seed` (a stream of its own, so the
    aortic tortuosity's phase stays what it was)."""
    rng = np.random.default_rng([p.seed, 1])
    return {b: float(rng.uniform(0.0, 2 * math.pi)) for b in BRANCHES}


def _wiggle(points, u_start, heading, amplitude, wavelength, phase):
    """`points` (a branch centreline) displaced sideways, perpendicular to `heading` in the
    frontal plane, by a sinusoid that rises from zero at arclength `u_start` over one
    wavelength."""
    u = arclength(points)
    side = np.array([heading[1], -heading[0], 0.0])
    x = (u - u_start) / wavelength
    envelope = _smoothstep(x)
    offset = amplitude * envelope * (np.sin(2 * math.pi * x + phase) - math.sin(phase))
    return resample_polyline(points + offset[:, None] * side, _SAMPLE_M)


def _turn_about_descending(angle_deg: float, arch: _ArchCurve):
    """Rotation by `angle_deg` about world +y through the descending centreline
    (x = a, z = -depth/2): positive turns the ascending aorta (x < 0) anterior (+z)."""
    c, s_ = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    rot = np.array([[c, 0.0, s_], [0.0, 1.0, 0.0], [-s_, 0.0, c]])
    axis = np.array([arch.a, 0.0, -arch.hd])

    def turn(v):
        v = np.asarray(v, dtype=float)
        return (v - axis) @ rot.T + axis

    return turn


def path_to_site(model: ArchModel, branch: str, spacing: float = 0.0015, fillet_m: float = 0.010) -> np.ndarray:
    """Polyline from the entry along the aorta and into `branch`, ending at its site.

    The corner where the branch centreline leaves the aortic centreline is
    replaced by a cubic Bezier (tangent-continuous) that starts `fillet_m` before
    the origin on the aorta and ends in the branch just past its ostium, so the
    path is smooth and stays deep inside the lumen.
    """
    p = model.params
    s = model.aorta.arclength
    s_entry = model.aorta_open_s + p.entry_inset_m
    s_origin = model.branch_origin_s[branch]
    s_fillet = s_origin - fillet_m
    keep = (s >= s_entry) & (s <= s_fillet)
    at = lambda sq: np.array([np.interp(sq, s, model.aorta.points[:, k]) for k in range(3)])
    head = np.concatenate([[at(s_entry)], model.aorta.points[keep], [at(s_fillet)]])
    tangent_a = _unit(at(s_fillet + 1e-4) - at(s_fillet - 1e-4))

    br = model.branches[branch]
    ub = br.arclength
    u_wall = model.branch_wall_u.get(branch, float(np.interp(s_origin, s, model.aorta.radius)))
    u_join = u_wall + 0.25 * p.site_depth_m  # a little past the ostium, in the branch
    u_site = u_wall + p.site_depth_m
    bat = lambda uq: np.array([np.interp(uq, ub, br.points[:, k]) for k in range(3)])
    tangent_b = _unit(bat(u_join + 1e-4) - bat(u_join - 1e-4))
    P0, P3 = at(s_fillet), bat(u_join)
    h = 0.5 * np.linalg.norm(P3 - P0)
    P1, P2 = P0 + h * tangent_a, P3 - h * tangent_b
    t = np.linspace(0, 1, 200)[:, None]
    bez = ((1 - t) ** 3) * P0 + 3 * ((1 - t) ** 2) * t * P1 + 3 * (1 - t) * t * t * P2 + t**3 * P3
    keep_b = (ub > u_join) & (ub < u_site)
    tail = np.concatenate([br.points[keep_b], [bat(u_site)]])
    path = np.concatenate([head, bez[1:], tail])
    # Drop duplicate points before resampling.
    d = np.linalg.norm(np.diff(path, axis=0), axis=1)
    path = np.concatenate([path[:1], path[1:][d > 1e-9]])
    return resample_polyline(path, spacing)
