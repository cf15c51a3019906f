"""Procedural aortic-arch anatomy: parametric model -> lumen mesh -> wall prisms -> asset folder.

    from cathsim_dmc.anatomy import PRESETS, build_asset, load_asset
    report = build_asset(PRESETS["type1"], "assets/type1")
    asset = load_asset("assets/type1")
"""

from cathsim_dmc.anatomy.arch import BRANCHES, PRESETS, ArchModel, ArchParams, Vessel, build_arch, path_to_site
from cathsim_dmc.anatomy.asset import (FORMAT_VERSION, AortaAsset, BuildReport, Centerline, build_asset,
                                       load_asset, write_asset)
from cathsim_dmc.anatomy.mesh import Lumen, build_lumen, extrude_prisms, signed_distance

__all__ = [
    "BRANCHES", "PRESETS", "ArchModel", "ArchParams", "Vessel", "build_arch", "path_to_site",
    "FORMAT_VERSION", "AortaAsset", "BuildReport", "Centerline", "build_asset", "load_asset", "write_asset",
    "Lumen", "build_lumen", "extrude_prisms", "signed_distance",
]
