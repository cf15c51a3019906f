"""Parameters of the generated aortic arch (`ArchParams`, SI metres and degrees), the
clinical arch types and the obliquity of the arch. `presets` names shipped parameter sets;
`arch.build_arch` turns parameters into centerlines and radii."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

BRANCHES = ("bca", "lcca", "lsa")  # proximal (ascending side) to distal


def arch_type_of(ratio: float) -> str:
    """Clinical arch type from the BCA-origin distance below the arch top, in CCA diameters."""
    return "I" if ratio < 1.0 else ("II" if ratio <= 2.0 else "III")


# Bounds of the generator's sizes (the validate() size guards). The largest length a human
# aortic model needs is the descending aorta (11 cm here); 25 cm leaves room for unusual
# anatomy. The shipped arches use a 1 mm grid and 7 mm base edges.
MAX_LENGTH_M = 0.25
MIN_SDF_SPACING_M = 0.00025
MIN_EDGE_LENGTH_M = 0.001


# Lengths that may be 0 (every other `*_m` field must be positive).
NON_NEGATIVE_FIELDS = (
    "tortuosity_amplitude_m",
    "aneurysm_diameter_m",
    "bovine_trunk_length_m",
    "bca_lcca_gap_m",
    "lcca_lsa_gap_m",
    "branch_tortuosity_amplitude_m",
)


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
    # Seed for every random choice (the phases of the aortic and branch tortuosity).
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
    # (about 4 mm BCA-LCCA and 6 mm LCCA-LSA in CTA series, design brief); 0: the ostia
    # touch.
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
    # Length over which a branch turns from its take-off direction to its heading.
    branch_bend_length_m: float = 0.020
    # Take-off: the angle, in the arch plane, between a branch's first direction (through
    # the ostium) and the arch's outward normal there; positive leans towards the
    # descending side (patient left), negative towards the ascending side. 0: straight
    # out of the wall. A bovine trunk leaves at the BCA's.
    bca_takeoff_deg: float = 0.0
    lcca_takeoff_deg: float = 0.0
    lsa_takeoff_deg: float = 0.0
    # Origin roll: each ostium turned about the aortic centreline away from the outer
    # curvature, degrees, positive anterior (+z before `arch_rotation_deg`). The ostia of
    # real arches do not all sit on the top of the outer curvature.
    bca_roll_deg: float = 0.0
    lcca_roll_deg: float = 0.0
    lsa_roll_deg: float = 0.0
    # Branch tortuosity: a sideways sinusoid of the branch centerline (perpendicular to its
    # heading, in the frontal plane), rising from zero at the ostium over one wavelength,
    # with a random phase per branch from `seed`. 0: none.
    branch_tortuosity_amplitude_m: float = 0.0
    branch_tortuosity_wavelength_m: float = 0.030
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
        positive = [
            f.name for f in dataclasses.fields(self) if f.name.endswith("_m") and f.name not in NON_NEGATIVE_FIELDS
        ]
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"ArchParams.{name} must be > 0, got {getattr(self, name)!r}.")
        # Size guards: building meshes a level set on a grid over the arch's box, so a length
        # given in millimetres as metres, or a very fine grid, would run for minutes or
        # exhaust memory before failing.
        for name in [f.name for f in dataclasses.fields(self) if f.name.endswith("_m")]:
            if not getattr(self, name) <= MAX_LENGTH_M:
                raise ValueError(
                    f"ArchParams.{name}={getattr(self, name)!r} m is larger than any aortic arch "
                    f"dimension; use at most {MAX_LENGTH_M} m (values are in metres)."
                )
        if self.sdf_spacing_m < MIN_SDF_SPACING_M or self.edge_length_m < MIN_EDGE_LENGTH_M:
            raise ValueError(
                f"ArchParams.sdf_spacing_m={self.sdf_spacing_m!r} and edge_length_m={self.edge_length_m!r} "
                f"must be at least {MIN_SDF_SPACING_M} and {MIN_EDGE_LENGTH_M} m (finer grids and "
                f"meshes take minutes to build and change no contact)."
            )
        if self.site_depth_m >= min(self.branch_length_m(b) for b in BRANCHES):
            raise ValueError("ArchParams.site_depth_m must be shorter than every branch length.")
        # Narrow branches are refined by their fold angle (max_dihedral_deg) and, from mesher
        # version 2 on, where a triangle cuts into them (lumen.MAX_SAG_FRACTION), so the base
        # edge only has to stay below the narrowest branch diameter.
        narrowest = min(self.branch_diameter_m(b) for b in BRANCHES)
        if self.edge_length_m > narrowest:
            raise ValueError(
                f"ArchParams.edge_length_m={self.edge_length_m} is too coarse for a "
                f"{narrowest * 1e3:.1f} mm branch; use at most {narrowest:.4f}."
            )
        if self.refine_levels < 0 or self.relax_iterations < 0:
            raise ValueError("ArchParams.refine_levels and relax_iterations must be >= 0.")
        for name in NON_NEGATIVE_FIELDS:
            if not getattr(self, name) >= 0:
                raise ValueError(f"ArchParams.{name} must be >= 0, got {getattr(self, name)!r}.")
        for name in [f.name for f in dataclasses.fields(self) if f.name.endswith(("_takeoff_deg", "_roll_deg"))]:
            if not -60.0 <= getattr(self, name) <= 60.0:
                raise ValueError(f"ArchParams.{name} must be in [-60, 60] degrees, got {getattr(self, name)!r}.")
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


def with_arch_type(
    params: "ArchParams", arch_type: str, ratio: float | None = None, name: str | None = None
) -> "ArchParams":
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
    return params.replace(
        name=params.name if name is None else name,
        arch_type=arch_type,
        bca_origin_drop_m=ratio * params.lcca_diameter_m,
        arch_height_m=height,
    )


def normalize_arch_type(value) -> str:
    """ "I"/"II"/"III", 1/2/3 or "1"/"2"/"3" -> "I"/"II"/"III"."""
    names = {"1": "I", "2": "II", "3": "III", "I": "I", "II": "II", "III": "III"}
    key = str(value).strip().upper()
    if key not in names:
        raise ValueError(f"arch_type={value!r} is not valid; choose one of 1, 2, 3 (or I, II, III).")
    return names[key]
