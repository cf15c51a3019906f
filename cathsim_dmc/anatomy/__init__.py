"""Procedural aortic-arch anatomy: parametric model -> lumen mesh -> wall prisms -> asset folder.

parameters, presets -> arch (parametric model) -> sdf (signed distance) -> lumen (surface;
remesh, surface_cleanup, rim, triangles) -> wall (prisms) -> asset (folder); importer (a
lumen mesh file: mesh_repair, mesh_grid, centerlines, open_end, volume), validate
(geometric checks), containment, paths; polyline helpers. No module here needs MuJoCo or
dm_control.

    from cathsim_dmc.anatomy import PRESETS, build_asset, load_asset
    report = build_asset(PRESETS["type1"], "assets/type1")
    asset = load_asset("assets/type1")

    from cathsim_dmc.anatomy import generated_asset, sample_arch_params
    folder = generated_asset(sample_arch_params(7))      # built once, then cached

    from cathsim_dmc.anatomy import validate_asset
    print(validate_asset("assets/type2").summary())

    from cathsim_dmc.anatomy import Containment, lumen_field
    inside = Containment(lumen_field(asset), tolerance_m=1e-3).contains(points)   # (N,) bool
"""

from cathsim_dmc.anatomy.arch import ArchModel, Vessel, build_arch, path_to_site
from cathsim_dmc.anatomy.asset import (
    FORMAT_VERSION,
    AortaAsset,
    BuildReport,
    Centerline,
    build_asset,
    load_asset,
    write_asset,
)
from cathsim_dmc.anatomy.containment import Channel, Containment, LumenField, build_lumen_field, lumen_field
from cathsim_dmc.anatomy.generate import (
    CACHE_ENV,
    DISTRIBUTIONS,
    MORPHOMETRY,
    Morphometry,
    arch_params,
    branch_clearance_m,
    cache_root,
    generated_asset,
    params_hash,
    sample_arch_params,
)
from cathsim_dmc.anatomy.lumen import Lumen, build_lumen
from cathsim_dmc.anatomy.parameters import (
    ARCH_OBLIQUITY_DEG,
    ARCH_TYPE_ELONGATION,
    ARCH_TYPE_NOMINAL_RATIO,
    ARCH_TYPE_RATIO_RANGE,
    ARCH_TYPES,
    BRANCHES,
    ArchParams,
    arch_type_of,
    normalize_arch_type,
    ostia_obliquity_deg,
    with_arch_type,
)
from cathsim_dmc.anatomy.presets import PRESETS
from cathsim_dmc.anatomy.sdf import signed_distance
from cathsim_dmc.anatomy.validate import ValidationReport, validate_asset
from cathsim_dmc.anatomy.wall import extrude_prisms

__all__ = [
    "ARCH_OBLIQUITY_DEG",
    "ARCH_TYPE_ELONGATION",
    "ARCH_TYPE_NOMINAL_RATIO",
    "ARCH_TYPE_RATIO_RANGE",
    "ARCH_TYPES",
    "BRANCHES",
    "PRESETS",
    "ArchModel",
    "ArchParams",
    "Vessel",
    "arch_type_of",
    "build_arch",
    "normalize_arch_type",
    "ostia_obliquity_deg",
    "path_to_site",
    "with_arch_type",
    "FORMAT_VERSION",
    "AortaAsset",
    "BuildReport",
    "Centerline",
    "build_asset",
    "load_asset",
    "write_asset",
    "Channel",
    "Containment",
    "LumenField",
    "build_lumen_field",
    "lumen_field",
    "CACHE_ENV",
    "DISTRIBUTIONS",
    "MORPHOMETRY",
    "Morphometry",
    "branch_clearance_m",
    "arch_params",
    "cache_root",
    "generated_asset",
    "params_hash",
    "sample_arch_params",
    "Lumen",
    "build_lumen",
    "extrude_prisms",
    "signed_distance",
    "ValidationReport",
    "validate_asset",
]
