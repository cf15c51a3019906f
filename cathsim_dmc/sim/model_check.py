"""MuJoCo check of an aorta asset: its wall pieces and visual mesh compile and step.

Outside `cathsim_dmc.anatomy` so that building, importing and validating the
geometry need neither MuJoCo nor dm_control; the tools that hand an asset to
the simulator (`cathsim-aorta`, scripts/build_assets.py) add this check.

    from cathsim_dmc.sim.model_check import validate_and_compile
    report = validate_and_compile("assets/type2")   # validate_asset + the compile
    print(report.summary()); assert report.ok, report.problems
"""

from __future__ import annotations

import dataclasses
import time

from cathsim_dmc.anatomy.asset import AortaAsset, load_asset
from cathsim_dmc.anatomy.validate import ValidationReport, validate_asset


def compile_in_mujoco(asset: AortaAsset) -> float:
    """Compile the pieces and the visual mesh in a bare MuJoCo model, step once; seconds taken."""
    import mujoco

    meshes, geoms = [], []
    for i, h in enumerate(asset.hulls):
        meshes.append(f'<mesh name="w{i}" vertex="{" ".join(f"{x:.9g}" for x in h.ravel())}"/>')
        geoms.append(f'<geom type="mesh" mesh="w{i}"/>')
    vv = " ".join(f"{x:.9g}" for x in asset.visual_vertices.ravel())
    ff = " ".join(str(int(x)) for x in asset.visual_faces.ravel())
    meshes.append(f'<mesh name="lumen" vertex="{vv}" face="{ff}"/>')
    geoms.append('<geom type="mesh" mesh="lumen" contype="0" conaffinity="0" group="1"/>')
    xml = (
        f'<mujoco><asset>{"".join(meshes)}</asset><worldbody><body name="aorta">'
        f"{''.join(geoms)}</body></worldbody></mujoco>"
    )
    t0 = time.perf_counter()
    model = mujoco.MjModel.from_xml_string(xml)
    seconds = time.perf_counter() - t0
    if model.ngeom != asset.hull_count + 1:
        raise RuntimeError(f"MuJoCo compiled {model.ngeom} geoms, expected {asset.hull_count + 1}.")
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data)
    return seconds


def validate_and_compile(asset, **options) -> ValidationReport:
    """`validate_asset(asset, **options)` plus the MuJoCo compile; never raises on a failed check.

    A compile failure is one more problem of the report; `compile_seconds` is the
    compile time, or None when it failed.
    """
    t0 = time.perf_counter()
    if not isinstance(asset, AortaAsset):
        asset = load_asset(asset)
    report = validate_asset(asset, **options)
    problems = list(report.problems)
    compile_seconds = None
    try:
        compile_seconds = compile_in_mujoco(asset)
    except Exception as exc:  # noqa: BLE001 - reported as a problem
        problems.append(f"MuJoCo could not compile the asset: {exc}")
    return dataclasses.replace(
        report, compile_seconds=compile_seconds, problems=problems, seconds=time.perf_counter() - t0
    )
