"""Parametric aortic arch: centerlines and lumen-radius profiles.

Frame and units: SI metres, patient frame (+y superior, +x patient left, +z
anterior). The arch lies roughly in the frontal (x-y) plane so that the AP
(`top`) camera, looking along -z, sees it unfolded. The descending aorta is at
x > 0 and its inferior end is open (femoral access, wire travels +y); the
ascending aorta is at x < 0 and ends closed a few centimetres below the arch.

The model is purely geometric: `build_arch(params)` returns an `ArchModel`
holding one `Vessel` (dense centerline + radius per point) for the aorta and one
per branch, plus the landmarks (ostia, sites, entry) that the asset needs.
`sdf.py` and `lumen.py` turn the vessels into a lumen surface.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Dict, Tuple

import numpy as np
from scipy import interpolate

from cathsim_dmc.anatomy.polyline import arclength, polyline_length, resample_polyline

BRANCHES = ("bca", "lcca", "lsa")  # proximal (ascending side) to distal


def arch_type_of(ratio: float) -> str:
    """Clinical arch type from the BCA-origin distance below the arch top, in CCA diameters."""
    return "I" if ratio < 1.0 else ("II" if ratio <= 2.0 else "III")


def _distance_metric(points: np.ndarray) -> float:
    return polyline_length(points) / float(np.linalg.norm(points[-1] - points[0]))


@dataclasses.dataclass(frozen=True)
class ArchParams:
    """Generator parameters. Lengths in metres, angles in degrees.

    The defaults describe a normal adult type I arch. Every anatomical default is
    inside the published range it cites; values without a population source are
    marked as modelling choices.
    """

    name: str = "type1"
    # Arch type label (I/II/III). Geometrically the type is set by
    # `bca_origin_drop_m`; this label is for humans and is checked against the
    # measured drop by the build (see `ArchModel.arch_type_measured`).
    arch_type: str = "I"
    # Seed for every random choice (currently only the tortuosity phases).
    seed: int = 0

    # Aortic lumen diameters, Hager et al. 2002, "Diameters of the thoracic
    # aorta throughout life as measured with helical CT", Z Kardiol 91:674
    # (mean adult values): ascending aorta, proximal arch (at the BCA), distal
    # arch (between LCCA and LSA), isthmus (distal to the LSA), descending aorta.
    ascending_diameter_m: float = 0.0309
    proximal_arch_diameter_m: float = 0.0277
    distal_arch_diameter_m: float = 0.0261
    isthmus_diameter_m: float = 0.0247
    descending_diameter_m: float = 0.0243

    # Arch shape: half-ellipse between the ascending and descending centerlines.
    # Width = centreline distance ascending-descending, height = apex above the
    # ends of the arch. 60 mm / 36 mm (H/W = 0.6) is a representative normal
    # adult arch: the arch height/width ratio of normal controls is about 0.6
    # (Ou et al. 2004, Eur Heart J 25:1853, who use H/W to grade arch shape).
    # Modelling choice, not a fitted population mean.
    arch_width_m: float = 0.060
    arch_height_m: float = 0.036
    # Antero-posterior offset between ascending (anterior, +z) and descending
    # (posterior, -z) ends. Real arches run obliquely (~45 deg); it is kept small
    # so the AP view shows the arch unfolded (modelling choice).
    arch_depth_m: float = 0.010
    # Arch-plane rotation about the vertical axis through the descending aorta,
    # degrees; positive brings the ascending aorta anterior (+z). The entry, its
    # direction and the open end stay where they are (they lie on the axis).
    # With 0 the arch keeps the little obliquity `arch_depth_m` gives it (the BCA-LSA
    # ostia line is 6.2-6.4 deg off the coronal plane in type1-3); real arches
    # run from the anterior ascending to the posterior descending aorta: on CTA of
    # 217 normal arches the BCA-LSA ostia line makes 50.3 +- 13.8 deg with the
    # sagittal plane, i.e. 39.7 deg with the coronal plane (Yan Y, Yan ZY, Deng KX,
    # Shen YH, aortic arch morphology for thoracic endovascular treatment (in Chinese),
    # a retrospective CTA study of 217 normal arches, 2009-2012; abstract at
    # http://m.zgkjsz.com/page/2017/0915/14580039.shtml; `ARCH_OBLIQUITY_DEG`).
    # `ArchModel.obliquity_deg` measures the result.
    arch_rotation_deg: float = 0.0

    # Path lengths. Descending aorta from the entry point up to the start of the
    # arch: 10-12 cm of thoracic descending aorta in view (design brief).
    descending_length_m: float = 0.110
    # Entry point distance inside the open inferior end.
    entry_inset_m: float = 0.010
    # Ascending aorta below the arch down to its closed root end (no heart).
    ascending_length_m: float = 0.040

    # Branch origin lumen diameters (CTA of supra-aortic trunks; normal adult
    # means: BCA 12.5 mm, LCCA 8.3 mm, LSA 10.4 mm, design brief / DESIGN.md).
    bca_diameter_m: float = 0.0125
    lcca_diameter_m: float = 0.0083
    lsa_diameter_m: float = 0.0104
    # Distal/origin diameter ratio over the modelled branch length (gentle
    # taper; modelling choice).
    branch_taper: float = 0.9
    # Wall-to-wall gaps between neighbouring ostia along the outer curvature
    # (about 4 mm BCA-LCCA and 6 mm LCCA-LSA in CTA series, design brief).
    bca_lcca_gap_m: float = 0.004
    lcca_lsa_gap_m: float = 0.006
    # Vertical distance from the top of the outer curvature down to the BCA
    # ostium centre. Arch type (Madhwal et al. 2008, Catheter Cardiovasc Interv
    # 72:38): type I < 1 CCA diameter, type II 1-2, type III > 2 diameters.
    # 3 mm = 0.36 LCCA diameters: type I, with the LCCA near the apex.
    bca_origin_drop_m: float = 0.003
    # Final branch headings in the frontal plane, degrees from +y towards
    # patient left (+x): BCA runs up and to the right, LCCA nearly vertical,
    # LSA up and to the left (modelling choice, typical AP angiogram).
    bca_angle_deg: float = -20.0
    lcca_angle_deg: float = 5.0
    lsa_angle_deg: float = 30.0
    # Length over which a branch turns from the arch normal to its heading.
    branch_bend_length_m: float = 0.020
    # Bovine arch: the BCA and LCCA share one ostium (common origin) and run
    # together along the arch normal for `bovine_trunk_length_m` past it before
    # each turns to its own heading; the LSA stays where it would be in a
    # normal arch (gaps `bca_lcca_gap_m`, `lcca_lsa_gap_m` to a virtual LCCA).
    # The most common variant of arch branching (Layton et al. 2006, AJNR
    # 27:1541, who also explain why "bovine" is a misnomer).
    bovine: bool = False
    bovine_trunk_length_m: float = 0.002
    # Branch length from its ostium to its closed end. The BCA trunk is 4-5 cm
    # (design brief); each branch must hold a site 3 cm in plus ~1.5 cm.
    bca_length_m: float = 0.045
    lcca_length_m: float = 0.045
    lsa_length_m: float = 0.045
    # Depth of the target sites into each branch, from the ostium.
    site_depth_m: float = 0.030

    # Variants (off for type I).
    # Tortuosity: lateral sinusoidal displacement of the descending aorta with
    # a seeded random phase; tapered to zero at both ends of the segment.
    tortuosity_amplitude_m: float = 0.0
    tortuosity_wavelength_m: float = 0.060
    # Aneurysm: Gaussian bulge of the aortic diameter up to this diameter
    # (0 = none), centred at `aneurysm_position` (0 = start of the arch on the
    # descending side, 1 = its end on the ascending side), with this 1-sigma
    # half-length along the centreline.
    aneurysm_diameter_m: float = 0.0
    aneurysm_position: float = 0.5
    aneurysm_length_m: float = 0.015

    # Lumen surface and wall.
    # Smooth-union blend width k at the junctions (quadratic smooth-min; where
    # there is room it rounds a corner with a radius of about 0.85 k). 4 mm made
    # ostia continuous without lips in the wall prototype (DESIGN.md).
    blend_radius_m: float = 0.004
    # Wall (collision prism) thickness (DESIGN.md, Known hard parts).
    wall_thickness_m: float = 0.002
    # Maximum edge length passed to the mesher, refined below where the lumen
    # is narrow. 7 mm: ~5k wall prisms instead of ~11k at 4 mm, which pass
    # validation (no holes, no intrusion) and cut the broadphase cost per physics
    # step and the env build time and memory 2-3x (physics probe). 8 mm folded
    # triangles on five of the six presets, 10 mm on type1 too; where an arch
    # folds one, lumen.build_lumen meshes it again with shorter edges.
    edge_length_m: float = 0.007
    # Local refinement: triangles next to edges folded by more than this
    # (narrow branches, the carinas between ostia) are split, up to
    # `refine_levels` times, then the mesh is relaxed on the surface, so that the
    # wall prisms follow the curvature (modelling choice, see remesh.py). One
    # level takes the worst fold from ~65 to ~33 deg for +3% triangles.
    max_dihedral_deg: float = 25.0
    refine_levels: int = 1
    relax_iterations: int = 10
    # Spacing of the sampled SDF grid the surface is extracted from.
    sdf_spacing_m: float = 0.001

    def replace(self, **changes) -> "ArchParams":
        return dataclasses.replace(self, **changes)

    def branch_diameter_m(self, branch: str) -> float:
        return getattr(self, f"{branch}_diameter_m")

    def branch_length_m(self, branch: str) -> float:
        return getattr(self, f"{branch}_length_m")

    def branch_angle_deg(self, branch: str) -> float:
        return getattr(self, f"{branch}_angle_deg")

    def validate(self) -> None:
        positive = [f.name for f in dataclasses.fields(self)
                    if f.name.endswith("_m") and f.name not in (
                        "tortuosity_amplitude_m", "aneurysm_diameter_m", "bovine_trunk_length_m")]
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"ArchParams.{name} must be > 0, got {getattr(self, name)!r}.")
        if self.site_depth_m >= min(self.branch_length_m(b) for b in BRANCHES):
            raise ValueError("ArchParams.site_depth_m must be shorter than every branch length.")
        # Narrow branches are refined by their fold angle (max_dihedral_deg) and, from mesher
        # version 2 on, where a triangle cuts into them (lumen.MAX_SAG_FRACTION), so the base
        # edge only has to stay below the narrowest branch diameter.
        narrowest = min(self.branch_diameter_m(b) for b in BRANCHES)
        if self.edge_length_m > narrowest:
            raise ValueError(f"ArchParams.edge_length_m={self.edge_length_m} is too coarse for a "
                             f"{narrowest * 1e3:.1f} mm branch; use at most {narrowest:.4f}.")
        if self.refine_levels < 0 or self.relax_iterations < 0:
            raise ValueError("ArchParams.refine_levels and relax_iterations must be >= 0.")
        if self.bovine_trunk_length_m < 0:
            raise ValueError("ArchParams.bovine_trunk_length_m must be >= 0.")
        if not -90.0 <= self.arch_rotation_deg <= 90.0:
            raise ValueError(f"ArchParams.arch_rotation_deg must be in [-90, 90], got {self.arch_rotation_deg!r}.")
        if self.arch_type not in ("I", "II", "III"):
            raise ValueError(f"ArchParams.arch_type must be one of I, II, III, got {self.arch_type!r}.")


# Arch types. Madhwal et al. 2008 grade the arch by the vertical distance from
# the top of the outer curvature down to the BCA origin, in CCA diameters:
# type I < 1, type II 1-2, type III > 2.
ARCH_TYPES = ("I", "II", "III")
# Distance in CCA diameters used when an arch is built "as type X" with no
# distance given (the middle of the class; type I keeps the 0.36 of `type1`).
ARCH_TYPE_NOMINAL_RATIO = {"I": 0.36, "II": 1.5, "III": 2.5}
# Ratio range the sampler draws from, 0.15 inside each class boundary so that
# every draw is unambiguously of its class (type III is capped at 2.85: deeper
# origins put the BCA on the vertical ascending aorta of this model).
ARCH_TYPE_RATIO_RANGE = {"I": (0.15, 0.85), "II": (1.15, 1.85), "III": (2.15, 2.85)}
# Arch height relative to a type I arch. Type II/III arches are elongated: the
# arch rises above great vessels whose origins sit lower on the ascending side
# (the arch elongates and "unfolds" with age, as the arch type rises). The
# factors are a modelling choice.
ARCH_TYPE_ELONGATION = {"I": 1.0, "II": 1.1, "III": 1.25}


# Obliquity of the arch (the BCA-LSA ostia line seen from above, degrees from the
# coronal plane, positive when the LSA lies posterior to the BCA): mean and SD of 217
# normal arches on CTA, 90 deg minus the published 50.30 +- 13.79 deg to the sagittal
# plane (Yan et al., see `ArchParams.arch_rotation_deg`).
ARCH_OBLIQUITY_DEG = (39.7, 13.79)


def ostia_obliquity_deg(ostia) -> float:
    """Angle (degrees) of the BCA-LSA ostia line with the coronal (x-y) plane, measured in
    the transverse (x-z) plane; positive when the LSA ostium is posterior (-z) to the BCA's."""
    d = np.asarray(ostia["lsa"], dtype=float) - np.asarray(ostia["bca"], dtype=float)
    return float(math.degrees(math.atan2(-d[2], d[0])))


def with_arch_type(params: "ArchParams", arch_type: str, ratio: float | None = None,
                   name: str | None = None) -> "ArchParams":
    """`params` turned into an arch of `arch_type` ("I"/"II"/"III" or 1/2/3).

    The BCA origin is put `ratio` CCA (= LCCA) diameters below the arch top
    (default: `ARCH_TYPE_NOMINAL_RATIO`) and the arch height is scaled by
    `ARCH_TYPE_ELONGATION` relative to the type of `params`.
    """
    arch_type = normalize_arch_type(arch_type)
    ratio = ARCH_TYPE_NOMINAL_RATIO[arch_type] if ratio is None else float(ratio)
    if arch_type_of(ratio) != arch_type:
        raise ValueError(f"ratio={ratio} CCA diameters is not an arch of type {arch_type}.")
    height = params.arch_height_m * ARCH_TYPE_ELONGATION[arch_type] / ARCH_TYPE_ELONGATION[params.arch_type]
    return params.replace(name=params.name if name is None else name, arch_type=arch_type,
                          bca_origin_drop_m=ratio * params.lcca_diameter_m, arch_height_m=height)


def normalize_arch_type(value) -> str:
    """"I"/"II"/"III", 1/2/3 or "1"/"2"/"3" -> "I"/"II"/"III"."""
    names = {"1": "I", "2": "II", "3": "III", "I": "I", "II": "II", "III": "III"}
    key = str(value).strip().upper()
    if key not in names:
        raise ValueError(f"arch_type={value!r} is not valid; choose one of 1, 2, 3 (or I, II, III).")
    return names[key]


_TYPE1 = ArchParams()

# Shipped presets: name -> parameters (built into assets/<name> by scripts/build_assets.py).
PRESETS: Dict[str, ArchParams] = {
    "type1": _TYPE1,
    "type2": with_arch_type(_TYPE1, "II", name="type2"),
    # 6.5 mm edges: at 6, 7, 7.5 and 8 mm the mesher folds a triangle of this arch.
    "type3": with_arch_type(_TYPE1, "III", name="type3").replace(edge_length_m=0.0065),
    # Type I with a fusiform aneurysm of the proximal descending aorta just
    # distal to the LSA (the isthmus region, where most thoracic aortic
    # aneurysms of the arch region sit): 50 mm, twice the ~25 mm adjacent aorta
    # (surgical repair is advised from 55-60 mm; modelling choice).
    "aneurysm": _TYPE1.replace(name="aneurysm", aneurysm_diameter_m=0.050, aneurysm_position=0.12,
                               aneurysm_length_m=0.012),
    # A flatter, wider arch (H/W 0.44 instead of 0.6) with straight branches:
    # each branch keeps the direction of the arch normal at its origin (the
    # headings below are those normals), so it does not bend at all.
    "low_tortuosity": _TYPE1.replace(name="low_tortuosity", arch_height_m=0.028, arch_width_m=0.064,
                                     bca_angle_deg=-22.3, lcca_angle_deg=-5.5, lsa_angle_deg=12.2),
    # Bovine arch: BCA and LCCA from one common ostium, diverging more widely
    # and bending sooner than in type1, so that the two lumens part about 1.5 cm
    # above the ostium.
    "bovine": _TYPE1.replace(name="bovine", bovine=True, bca_angle_deg=-40.0, lcca_angle_deg=20.0,
                             branch_bend_length_m=0.015),
}
# Oblique arches: type I-III turned 33.5 deg about the descending aorta, which takes the
# BCA-LSA ostia line from 6.2-6.4 to 39.7-39.9 deg off the coronal plane, the published
# mean of normal arches (`ARCH_OBLIQUITY_DEG`).
OBLIQUE_ROTATION_DEG = 33.5
for _name in ("type1", "type2", "type3"):
    PRESETS[f"{_name}_oblique"] = PRESETS[_name].replace(name=f"{_name}_oblique",
                                                         arch_rotation_deg=OBLIQUE_ROTATION_DEG)
del _name


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
    aorta: Vessel            # from below the open inferior end up, over the arch, to the root
    branches: Dict[str, Vessel]  # each from its origin on the aortic centreline to its closed end
    aorta_open_s: float      # arclength on `aorta` of the open inferior end (cut plane)
    branch_origin_s: Dict[str, float]   # arclength on `aorta` where each branch centreline starts
    ostia: Dict[str, np.ndarray]        # ostium centres (branch centreline meets nominal aortic wall)
    sites: Dict[str, np.ndarray]
    entry_position: np.ndarray
    entry_direction: np.ndarray
    open_end_center: np.ndarray
    open_end_radius: float
    arch_top_y: float        # top of the outer curvature (nominal tube surface)
    arch_s: Tuple[float, float] = (0.0, 0.0)   # arclength on `aorta` of the arch's ends (descending, ascending)

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
        return np.stack([self.a * np.cos(theta), self.b * np.sin(theta),
                         -self.hd * np.cos(theta)], axis=-1)

    def tangent(self, theta):
        theta = np.asarray(theta, dtype=float)
        return _unit(np.stack([-self.a * np.sin(theta), self.b * np.cos(theta),
                               self.hd * np.sin(theta)], axis=-1))

    def normal(self, theta):
        """Outward normal (away from the curvature centre), orthogonal to the tangent."""
        theta = np.asarray(theta, dtype=float)
        n = np.stack([np.cos(theta) / self.a, np.sin(theta) / self.b,
                      np.zeros_like(theta)], axis=-1)
        t = self.tangent(theta)
        n = n - np.sum(n * t, axis=-1, keepdims=True) * t
        return _unit(n)


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


_SAMPLE_M = 0.0005       # centreline sample spacing of the model
_CUT_MARGIN_M = 0.012    # the aorta tube continues this far below the open end (trimmed away)


def build_arch(params: ArchParams) -> ArchModel:
    """Build centrelines, radius profiles and landmarks from `params`."""
    p = params
    p.validate()
    arch = _ArchCurve(p)
    r_branch = {b: p.branch_diameter_m(b) / 2.0 for b in BRANCHES}

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
    s_theta = s_raw[len(desc) - 1:len(desc) - 1 + len(th_dense)]
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
        ostium = lambda t: arch.point(t) + r_of_theta(t) * arch.normal(t)
        drop = lambda t: top_y - ostium(t)[1] - p.bca_origin_drop_m
        if drop(math.pi * 0.98) < 0:
            raise ValueError("ArchParams.bca_origin_drop_m is larger than the arch allows.")
        theta = {"bca": _bisect(drop, theta_top, math.pi * 0.98)}
        # LCCA then LSA, each spaced from its neighbour by the given wall-to-wall gap.
        for prev, nxt, gap in (("bca", "lcca", p.bca_lcca_gap_m), ("lcca", "lsa", p.lcca_lsa_gap_m)):
            want = r_branch[prev] + gap + r_branch[nxt]
            o_prev = ostium(theta[prev])
            f = lambda t: np.linalg.norm(ostium(t) - o_prev) - want
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
    r_of_theta = lambda t: np.interp(t, [0.0, math.pi / 2, math.pi],
                                     [p.isthmus_diameter_m / 2, p.distal_arch_diameter_m / 2,
                                      p.proximal_arch_diameter_m / 2])
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
        points[:, 0] += p.tortuosity_amplitude_m * window * np.sin(
            2 * math.pi * (s - seg_lo) / p.tortuosity_wavelength_m + phase)
        s_new = arclength(points)
        s_br = {b: float(np.interp(v, s, s_new)) for b, v in s_br.items()}
        s_arch0, s_arch1 = (float(np.interp(v, s, s_new)) for v in (s_arch0, s_arch1))
        s = s_new
    aorta = Vessel("aorta", points, radius)

    def aorta_at(s_query):
        P = np.array([np.interp(s_query, s, points[:, k]) for k in range(3)])
        return P, float(np.interp(s_query, s, radius))

    # --- branches: straight out along the arch normal through the aortic wall,
    # then turning to their heading over `branch_bend_length_m`.
    branches, ostia, sites = {}, {}, {}
    for b in BRANCHES:
        A, R_a = aorta_at(s_br[b])
        n0 = arch.normal(theta[b])
        ang = math.radians(p.branch_angle_deg(b))
        d1 = np.array([math.sin(ang), math.cos(ang), 0.0])
        total = R_a + p.branch_length_m(b)
        u = np.arange(0.0, total + 1e-12, _SAMPLE_M / 2)
        bend_start = R_a + (p.bovine_trunk_length_m if p.bovine and b in ("bca", "lcca") else 0.0)
        w = _smoothstep((u - bend_start) / p.branch_bend_length_m)[:, None]
        dirs = _unit((1 - w) * n0 + w * d1)
        steps = np.diff(u)[:, None] * 0.5 * (dirs[1:] + dirs[:-1])
        bpts = A + np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
        bpts = resample_polyline(bpts, _SAMPLE_M)
        ub = arclength(bpts)
        taper = np.clip((ub - R_a) / p.branch_length_m(b), 0, 1)
        branches[b] = Vessel(b, bpts, r_branch[b] * (1 - (1 - p.branch_taper) * taper))
        ostia[b] = A + R_a * n0
        sites[b] = np.array([np.interp(R_a + p.site_depth_m, ub, bpts[:, k]) for k in range(3)])

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
        params=p, aorta=aorta, branches=branches, aorta_open_s=s_open,
        branch_origin_s=s_br, ostia=ostia, sites=sites,
        entry_position=entry, entry_direction=np.array([0.0, 1.0, 0.0]),
        open_end_center=open_c, open_end_radius=r_open, arch_top_y=top_y,
        arch_s=(float(s_arch0), float(s_arch1)))


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


def path_to_site(model: ArchModel, branch: str, spacing: float = 0.0015,
                 fillet_m: float = 0.010) -> np.ndarray:
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
    R_a = float(np.interp(s_origin, s, model.aorta.radius))
    u_join = R_a + 0.25 * p.site_depth_m   # a little past the ostium, in the branch
    u_site = R_a + p.site_depth_m
    bat = lambda uq: np.array([np.interp(uq, ub, br.points[:, k]) for k in range(3)])
    tangent_b = _unit(bat(u_join + 1e-4) - bat(u_join - 1e-4))
    P0, P3 = at(s_fillet), bat(u_join)
    h = 0.5 * np.linalg.norm(P3 - P0)
    P1, P2 = P0 + h * tangent_a, P3 - h * tangent_b
    t = np.linspace(0, 1, 200)[:, None]
    bez = ((1 - t) ** 3) * P0 + 3 * ((1 - t) ** 2) * t * P1 + 3 * (1 - t) * t * t * P2 + t ** 3 * P3
    keep_b = (ub > u_join) & (ub < u_site)
    tail = np.concatenate([br.points[keep_b], [bat(u_site)]])
    path = np.concatenate([head, bez[1:], tail])
    # Drop duplicate points before resampling.
    d = np.linalg.norm(np.diff(path, axis=0), axis=1)
    path = np.concatenate([path[:1], path[1:][d > 1e-9]])
    return resample_polyline(path, spacing)
