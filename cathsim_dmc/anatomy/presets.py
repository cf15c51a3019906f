"""Named arch parameter sets: the shipped presets and their oblique variants."""

from __future__ import annotations

from typing import Dict

from cathsim_dmc.anatomy.parameters import ArchParams, with_arch_type

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
    "aneurysm": _TYPE1.replace(
        name="aneurysm", aneurysm_diameter_m=0.050, aneurysm_position=0.12, aneurysm_length_m=0.012
    ),
    # A flatter, wider arch (H/W 0.44 instead of 0.6) with straight branches:
    # each branch keeps the direction of the arch normal at its origin (the
    # headings below are those normals), so it does not bend at all.
    "low_tortuosity": _TYPE1.replace(
        name="low_tortuosity",
        arch_height_m=0.028,
        arch_width_m=0.064,
        bca_angle_deg=-22.3,
        lcca_angle_deg=-5.5,
        lsa_angle_deg=12.2,
    ),
    # Bovine arch: BCA and LCCA from one common ostium, diverging more widely
    # and bending sooner than in type1, so that the two lumens part about 1.5 cm
    # above the ostium.
    "bovine": _TYPE1.replace(
        name="bovine", bovine=True, bca_angle_deg=-40.0, lcca_angle_deg=20.0, branch_bend_length_m=0.015
    ),
}
# Oblique arches: type I-III turned 33.5 deg about the descending aorta, which takes the
# BCA-LSA ostia line from 6.2-6.4 to 39.7-39.9 deg off the coronal plane, the published
# mean of normal arches (`ARCH_OBLIQUITY_DEG`).
OBLIQUE_ROTATION_DEG = 33.5
for _name in ("type1", "type2", "type3"):
    PRESETS[f"{_name}_oblique"] = PRESETS[_name].replace(
        name=f"{_name}_oblique", arch_rotation_deg=OBLIQUE_ROTATION_DEG
    )
del _name
