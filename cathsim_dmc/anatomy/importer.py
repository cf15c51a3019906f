"""Import a vessel LUMEN surface (STL/OBJ, e.g. from a CT segmentation) as an aorta asset folder.

    from cathsim_dmc.anatomy.importer import import_mesh
    report = import_mesh("lumen.stl", "assets_local/patient7", units="mm",
                         entry=[30, -110, -5], sites={"bca": [-27, 74, 2], "lcca": [-1, 79, 0]})
    report = import_mesh("slicer_lumen.stl", "assets_local/patient8", units="mm", frame="LPS",
                         entry=[...], sites={"bca": [...]})   # points in the mesh's frame and units

The pipeline, each step with one clear error (`MeshImportError`) when it cannot
go on:

1. **read** the mesh with trimesh and turn it from its ``frame`` into the
   simulator's (`frames`: ``"sim"``, the default, is +x patient left, +y superior,
   +z anterior; ``"LPS"`` is DICOM's and 3D Slicer's, ``"RAS"`` some tools'), the
   entry, sites and entry direction with it; the scanner's origin is kept. The asset
   records the frame and the transform (meta.json ``source_frame``);
2. **repair** what is safe to repair: merge duplicate vertices, drop degenerate
   and duplicate triangles, drop loose pieces, fill 3-4 edge holes (trimesh),
   close open vessel ends (holes whose rim is a flat loop), fix the triangle
   winding and an inside-out surface. Non-manifold edges, holes that are not
   flat vessel ends or a surface that stays open are refused;
3. **units**: ``units="mm"`` or ``"m"``, or ``"auto"``: a mesh more than 2
   units across is taken to be in millimetres (a note says so). Sites and the
   entry are given in the mesh's units (and frame);
4. **signed distance grid** of the lumen (exact within a narrow band around the
   surface, flood fill + distance transform elsewhere);
5. **centerlines**: shortest paths on the lumen voxels at least the wire probe
   (0.945 mm) away from the wall, weighted by 1/clearance^2 so they run near
   the medial axis, from the entry to each site; Gaussian-smoothed where that
   keeps the clearance; radius = distance to the final wall;
6. **entry direction**: given, or the principal axis of the lumen within a few
   radii of the entry, pointing towards the sites;
7. **crop** (`crop="auto"`, `crop.crop_to_paths`): the lumen is kept within
   `crop_margin_m` (20 mm, through the lumen) of the entry-to-site paths, past each site
   too; the rest (the aortic root, distal branches, stumps) is cut off and capped, so
   a rough region no path needs cannot stop the import. `crop="none"` keeps it all;
8. **lumen**: kept as given if its triangles suit the wall prisms (mean edge
   0.8-3.2 mm at the default 4 mm target, no angle below 10 deg, at most 40k
   triangles) and nothing was cropped, else **remeshed** like the generator (level
   set of the SDF grid, curvature refinement, relaxation). The vessel is then cut
   square to the entry direction a few mm behind the entry (locally: a cylinder
   around the entry axis is subtracted) and capped flat; the cap is the open end
   where the wire comes in and gets no wall. A fold that local repair leaves gets
   the remedies in order: remeshing (a kept surface), shorter edges, the surface
   path's volume rebuild (`repair="auto"`), a septum or ridge crest thinner than 1 mm
   (or 3 grid nodes) near the fold thickened to that (`crop.thicken_septa`: the septum
   between close ostia, the carina of two branches, which the mesher pinches or folds),
   the volume smoothed around the fold (twice, coarser), and, when the fold lies beyond
   what the paths need, a tighter crop that cuts it away. A surface that touches itself
   (two sheets meshed onto one point) counts as a fold. When none works, the import
   stops with one final message;
9. **wall**: one prism per lumen triangle extruded outward (as generated
   arches), except where the vertex normal meets another lumen within the wall's
   thickness (a septum thinner than the wall): there the prism ends halfway across
   (`wall.thin_at_septa`), and a note says where and how thin;
10. **validate** (`validator`: `cathsim_dmc.anatomy.validate.validate_asset`; the
   CLI passes `cathsim_dmc.sim.model_check.validate_and_compile`, which adds the
   MuJoCo compile) and only then move the folder into place.

The import answers within `import_clock.IMPORT_BUDGET_S` (240 s; each meshing attempt
`REMEDY_BUDGET_S`, 100 s): a step that spends its budget stops it with one line naming the
step (`time_budget_s`, `remedy_budget_s`).

This module runs the pipeline; the steps live in `mesh_repair` (1-3), `mesh_grid` (4),
`centerlines` (5-6), `crop` (7 and the fold remedies), `open_end` (8) and `volume`
(repair=volume); `MeshImportError` is defined in `import_error`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import pathlib
import shutil
import tempfile
import time
from typing import Callable, Dict, List, Mapping, Optional, Sequence

import numpy as np

from cathsim_dmc.anatomy.asset import json_rounded, write_asset
from cathsim_dmc.anatomy.branches import FIND_SPACING_M, ArchError, find_arch, swap_message, swapped_site
from cathsim_dmc.anatomy.centerlines import estimate_entry_direction, lumen_centerlines
from cathsim_dmc.anatomy.crop import crop_to_paths, distance_to_paths_m, smooth_around, thicken_septa
from cathsim_dmc.anatomy.frames import SIM_FRAME, frame_rotation, from_sim, sim_axes, to_sim, to_sim_matrix
from cathsim_dmc.anatomy.import_clock import IMPORT_BUDGET_S, REMEDY_BUDGET_S, ImportClock, import_budget
from cathsim_dmc.anatomy.import_error import MeshImportError, format_point
from cathsim_dmc.anatomy.isosurface import zero_surface
from cathsim_dmc.anatomy.lumen import FoldedSurfaceError
from cathsim_dmc.anatomy.mesh_grid import check_grid_memory, mesh_sdf_grid
from cathsim_dmc.anatomy.mesh_repair import check_encloses_volume, detect_units, read_lumen, repair_lumen
from cathsim_dmc.anatomy.open_end import build_open_lumen, triangle_stats
from cathsim_dmc.anatomy.polyline import polyline_length, resample_polyline
from cathsim_dmc.anatomy.sdf import signed_distance, unsigned_distance
from cathsim_dmc.anatomy.validate import (
    PROBE_RADIUS_M,
    ValidationReport,
    ostia_from_centerlines,
    site_placement_problems,
    validate_asset,
)
from cathsim_dmc.anatomy.volume import VolumeError, trim_side_branches, volume_sdf_grid
from cathsim_dmc.anatomy.wall import extrude_prisms, prism_offsets, thin_at_septa
from cathsim_dmc.core.run_files import check_writable_folder

MIN_SITE_DEPTH_M = 0.001
DEFAULT_EDGE_M = 0.004  # level-set edge of the generator: mean edges come out ~2.3 mm
MAX_KEPT_TRIANGLES = 40_000
REPAIR_MODES = ("auto", "surface", "volume")
AUTO_SURFACE_MAX_TRIANGLES = 100_000  # repair=auto rebuilds larger surfaces through the volume
VOLUME_GRID_NODES = 10_000_000  # the voxel volume's default spacing aims at this many nodes
FOLD_RETRY_EDGE_FACTOR = 0.85
CROP_MODES = ("auto", "none")
DEFAULT_CROP_MARGIN_M = 0.02  # kept around the paths and past each site, through the lumen
# The fold remedies, in order, after a remesh at shorter edges: the volume smoothed around the
# fold over these sigmas (m, at least these many grid nodes) within these radii (m).
FOLD_SMOOTHING = ((0.001, 2, 0.012), (0.002, 4, 0.016))
# A fold or pinch with a septum or ridge crest thinner than FOLD_SEPTUM_M within FOLD_SEPTUM_RADIUS_M
# (the septum between close ostia, the carina of two branches) gets that septum thickened to
# FOLD_SEPTUM_M, or FOLD_SEPTUM_NODES grid nodes, before the smoothing (which would thin it more).
FOLD_SEPTUM_M = 0.001
FOLD_SEPTUM_NODES = 3
FOLD_SEPTUM_RADIUS_M = 0.006
FOLD_CROP_CLEARANCE_M = 0.004  # a fold this far beyond a tighter crop's margin is cut away
MAX_EXTENT_M = 1.5  # larger than any aorta (an arch spans 0.1-0.6 m): a unit slip


@dataclasses.dataclass
class ImportReport:
    path: pathlib.Path
    name: str
    units: str
    triangles: int
    hulls: int
    remeshed: bool
    repairs: List[str]
    notes: List[str]
    entry_direction: np.ndarray
    path_length_m: Dict[str, float]
    seconds: float
    validation: Optional[ValidationReport] = None


TERRACE_FOLD_DEG = 60.0  # an edge folding this much is a step of a voxel staircase...
TERRACE_SHARE = 0.10  # ...when this share of all edges fold that much


def terrace_step_m(v: np.ndarray, f: np.ndarray) -> Optional[float]:
    """The step length (m) of a voxel staircase surface, or None for a surface that is not one: a
    smooth lumen folds by a few degrees between neighbouring triangles, a staircase by 90."""
    import trimesh

    mesh = trimesh.Trimesh(v, f, process=False)
    angles = np.degrees(mesh.face_adjacency_angles)
    sharp = angles >= TERRACE_FOLD_DEG
    if len(angles) == 0 or sharp.mean() < TERRACE_SHARE:
        return None
    edges = mesh.face_adjacency_edges[sharp]
    return float(np.median(np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1)))


def source_frame_record(frame: str, units: str, scale: float) -> dict:
    """meta.json's ``source_frame``: the mesh's frame and units, and the 4x4 transforms between them
    and the asset's coordinates (the simulator's frame, metres)."""
    back = np.eye(4)
    back[:3, :3] = frame_rotation(frame).T / scale
    return {
        "frame": frame,
        "units": units,
        "to_sim": json_rounded(to_sim_matrix(frame, scale)),
        "from_sim": json_rounded(back),
        "use": "asset point (m) = to_sim @ [x, y, z, 1] of a mesh point; from_sim maps asset points back",
    }


def septum_note(vertices, thin, width, offsets, wall_m, frame, units) -> str:
    """The import note on a wall thinned at a septum: where, over how much, how thin."""
    i = int(np.argmin(np.where(thin, width, np.inf)))
    spread = float(np.max(np.linalg.norm(vertices[thin] - vertices[i], axis=1)))
    scale, digits = (1e-3, 1) if units == "mm" else (1.0, 4)
    where = format_point(from_sim(vertices[i], frame), scale, digits)
    return (
        f"wall thinned at a septum: {int(thin.sum())} lumen vertices within {spread * 1e3:.0f} mm of {where} "
        f"{units} meet another lumen {width[thin].min() * 1e3:.2f}-{width[thin].max() * 1e3:.2f} mm out, "
        f"within their wall ({wall_m * 1e3:g} mm, longer where the surface curves): it ends halfway across "
        f"({offsets[thin].min() * 1e3:.2f}-{offsets[thin].max() * 1e3:.2f} mm thick)"
    )


def _vec(value, what) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{what}={value!r} must be three numbers [x, y, z]")
    return a


def import_mesh(
    mesh_path,
    out,
    *,
    sites: Optional[Mapping[str, Sequence[float]]] = None,
    entry: Optional[Sequence[float]] = None,
    entry_direction: Optional[Sequence[float]] = None,
    units: str = "auto",
    frame: str = SIM_FRAME,
    name: Optional[str] = None,
    wall_thickness_m: float = 0.002,
    edge_length_m: Optional[float] = None,
    remesh="auto",
    sdf_spacing_m: Optional[float] = None,
    open_end_depth_m: float = 0.005,
    validate: bool = True,
    validator: Callable[[pathlib.Path], ValidationReport] = validate_asset,
    overwrite: bool = False,
    repair: str = "auto",
    smooth_m: Optional[float] = None,
    close_gap_m: float = 0.002,
    trim_branches_m: float = 0.003,
    crop: str = "auto",
    crop_margin_m: float = DEFAULT_CROP_MARGIN_M,
    caps: Sequence = (),
    log: Callable[[str], None] = print,
    time_budget_s: float = IMPORT_BUDGET_S,
    remedy_budget_s: float = REMEDY_BUDGET_S,
    _started: Optional[float] = None,
    _clock: Optional[ImportClock] = None,
) -> ImportReport:
    """Turn a lumen surface file into an asset folder at `out` (see the module docstring).

    It answers within `import_clock.IMPORT_BUDGET_S`: a step that spends its budget stops the
    import with one line naming it (`MeshImportError`)."""
    if _clock is None:
        args = dict(locals())
        if not all(np.isfinite(b) and b > 0 for b in (time_budget_s, remedy_budget_s)):
            raise ValueError(
                f"time_budget_s={time_budget_s!r} and remedy_budget_s={remedy_budget_s!r} must be seconds (> 0)"
            )
        clock = ImportClock(pathlib.Path(mesh_path), budget_s=time_budget_s, started=_started)
        with import_budget(clock):
            return import_mesh(**{**args, "_clock": clock})
    clock = _clock
    t0 = clock.t0
    path = pathlib.Path(mesh_path)
    out = pathlib.Path(out)
    name = name or path.stem
    frame_rotation(frame)  # ValueError naming the frames
    auto = entry is None or not sites  # found from the lumen's centerline tree (`branches`)
    entry_in = None if entry is None else _vec(entry, "entry")
    sites_in = {str(k): _vec(p, f"sites.{k}") for k, p in (sites or {}).items()}
    dir_in = None if entry_direction is None else _vec(entry_direction, "entry_direction")
    if dir_in is not None and np.linalg.norm(dir_in) == 0:
        raise ValueError("entry_direction must not be [0, 0, 0]")
    if repair not in REPAIR_MODES:
        raise ValueError(f"repair={repair!r} is not valid; choose one of {list(REPAIR_MODES)}")
    for key, value in (("smooth_m", smooth_m), ("close_gap_m", close_gap_m), ("trim_branches_m", trim_branches_m)):
        if value is not None and not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{key}={value!r} is not valid; give metres (0 or more)")
    if crop not in CROP_MODES:
        raise ValueError(f"crop={crop!r} is not valid; choose one of {list(CROP_MODES)}")
    if not (np.isfinite(crop_margin_m) and crop_margin_m >= 0.005):
        raise ValueError(f"crop margin {crop_margin_m * 1e3:g} mm is not valid; give 5 mm or more")
    if remesh not in ("auto", True, False):
        raise ValueError(f"remesh={remesh!r} is not valid; choose one of ['auto', true, false]")
    if not 0.0002 <= wall_thickness_m <= 0.01:
        raise ValueError(f"wall thickness {wall_thickness_m * 1e3:g} mm is not valid; use 0.2-10 mm")
    check_writable_folder("out", out)
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise ValueError(f"out={str(out)!r} exists and is not empty; pass overwrite=true or another out")

    v, f = read_lumen(path)
    for cap in caps:  # an open (CFD) wall's separate cap surfaces: more triangles of the same surface
        cv, cf = read_lumen(cap)
        v, f = np.concatenate([v, cv]), np.concatenate([f, cf + len(v)])
    v = to_sim(v, frame)
    shown = (lambda p: from_sim(p, frame)) if frame != SIM_FRAME else np.asarray  # messages: the mesh's frame
    check_encloses_volume(v, f, path)
    scale, units_used, note = detect_units(v, units, path)
    notes = [note] if note else []
    if frame != SIM_FRAME:
        notes.append(
            f"frame={frame}: the mesh and the points given turned into the simulator's frame (x left, y superior, "
            f"z anterior) as {sim_axes(frame)}, the scanner's origin kept"
        )
    if caps:
        notes.append(f"{len(caps)} cap surface{'s' * (len(caps) > 1)} added to the wall")
    for n_ in notes:
        log(f"note: {n_}")
    extent_m = float(np.max(np.ptp(v, axis=0))) * scale
    if extent_m > MAX_EXTENT_M:
        raise MeshImportError(
            f"{path}: spans {extent_m:.3g} m with units={units_used}, more than any aorta "
            f"({MAX_EXTENT_M:g} m at most); pass the right units= or rescale the mesh"
        )
    entry_m = None if entry_in is None else to_sim(entry_in, frame) * scale
    sites_m = {k: to_sim(p, frame) * scale for k, p in sites_in.items()}

    def check_depths(depth):
        for lab, d, p in zip(labels, depth, given):
            need = PROBE_RADIUS_M if lab == "entry" else MIN_SITE_DEPTH_M
            if d < need:
                where = "outside the lumen" if d <= 0 else "inside the lumen but too close to the wall"
                raise MeshImportError(
                    f"{path}: {lab}={format_point(p, digits=4 if units_used == 'm' else 1)} "
                    f"{units_used} is {where} ({d * 1e3:+.2f} mm from the wall; needs >= "
                    f"{need * 1e3:.2f} mm inside)"
                )

    clock.begin("repairing the surface")
    use_volume = repair == "volume"
    repairs: List[str] = []
    closed = None  # the repaired closed surface (mesh units), for finding the sites
    tree = None

    def check_given_sites(grid):
        """Given sites named bca/lcca/lsa must lie in the branches of those names (when all three are
        found: two could be any two of them)."""
        if not sites:
            return
        try:
            found = tree or find_arch(grid)
        except (ArchError, ValueError, IndexError):
            return  # nothing to check against: the given sites win
        if len(found.branches) < 3:
            return
        bad = swapped_site(found, {k: p for k, p in sites_m.items() if k in sites_in})
        if bad:
            given_at = format_point(sites_in[bad[0]], digits=4 if units_used == "m" else 1)
            raise MeshImportError(f"{path}: {swap_message(bad[0], bad[1], found, given_at)}")
        if found.trunk and found.notes()[-1] not in notes:
            notes.append(found.notes()[-1])
            log(f"note: {notes[-1]}")

    def crop_lumen(grid, centerlines):
        if crop != "auto":
            return grid
        grid, cnotes = crop_to_paths(grid, list(centerlines.values()), entry_m, crop_margin_m)
        for n_ in cnotes:
            repairs.append(n_)
            log(f"repair: {path}: {n_}")
        return grid

    if not use_volume:
        try:
            v_closed, f_closed, repairs = repair_lumen(v, f, path, units_used, shown=shown)
        except MeshImportError as exc:
            if repair == "surface":
                raise
            reason = str(exc).split(": ", 1)[-1]
            notes.append(
                f"the surface repair cannot fix it ({reason}); rebuilding it from a voxel volume (repair=volume)"
            )
            log(f"note: {notes[-1]}")
            use_volume = True
        else:
            closed = (v_closed, f_closed)
            if repair == "auto" and len(f_closed) > AUTO_SURFACE_MAX_TRIANGLES:
                # A segmentation export: exact distances to every triangle cost minutes, and its
                # noise folds the remeshed surface; the volume smooths it.
                notes.append(
                    f"{len(f_closed)} triangles: rebuilding the lumen from a voxel volume "
                    f"(repair=surface keeps to the surface as given)"
                )
                log(f"note: {notes[-1]}")
                use_volume = True
                repairs = []  # made to the surface, which the volume does not use
            else:
                v, f = v_closed, f_closed
    if auto:
        clock.begin("finding the entry and the sites")
        try:
            if closed is not None:
                find_grid = mesh_sdf_grid(closed[0] * scale, closed[1], FIND_SPACING_M, pad=0.004)
            else:  # the voxel volume's largest enclosed piece
                find_grid, _ = volume_sdf_grid(
                    v * scale, f, FIND_SPACING_M, 0.004, None, {}, max_gap_m=close_gap_m, shown=shown
                )
            tree = find_arch(find_grid)
        except (ArchError, VolumeError) as exc:
            raise MeshImportError(f"{path}: {exc}") from None
        if entry_m is None:
            entry_m = tree.entry
            entry_in = from_sim(entry_m / scale, frame)
        if not sites_m:
            sites_m = tree.sites()
            sites_in = {k: from_sim(p / scale, frame) for k, p in sites_m.items()}
        digits = 4 if units_used == "m" else 1
        where = ", ".join(
            [f"entry={format_point(entry_in, digits=digits)}"]
            + [f"sites.{k}={format_point(p, digits=digits)}" for k, p in sites_in.items()]
        )
        notes.extend([f"{tree.found}: {where} {units_used}"] + tree.notes()[1:])
        for n_ in notes[-len(tree.notes()) :]:
            log(f"note: {n_}")
    labels = ["entry"] + [f"sites.{k}" for k in sites_m]
    given = [entry_in] + list(sites_in.values())
    points = np.concatenate([[entry_m], list(sites_m.values())])
    if use_volume:
        import trimesh

        mesh = trimesh.Trimesh(v * scale, f, process=False)
        mesh.merge_vertices()
        mesh.update_faces(mesh.nondegenerate_faces())
        v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
        edge = float(edge_length_m) if edge_length_m else DEFAULT_EDGE_M
        box = np.ptp(v, axis=0) + 2 * (3 * edge)
        h = (
            float(sdf_spacing_m)
            if sdf_spacing_m
            else float(np.clip(np.cbrt(np.prod(box) / VOLUME_GRID_NODES), 0.0004, 0.001))
        )
        pad = 3 * edge + 2 * h
        check_grid_memory(v, f, h, pad, path)
        clock.begin(f"the voxel volume on a {h * 1e3:.2f} mm grid")
        smooth = h if smooth_m is None else float(smooth_m)
        try:
            grid, vnotes = volume_sdf_grid(
                v, f, h, pad, entry_m, sites_m, max_gap_m=close_gap_m, smooth_m=smooth, shown=shown
            )
        except VolumeError as exc:
            raise MeshImportError(f"{path}: {exc}") from None
        check_given_sites(grid)
        for n_ in vnotes:
            repairs.append(n_)
            log(f"repair: {path}: {n_}")
        depth = -grid(points)
        check_depths(depth)
        if not edge_length_m:
            edge = min(DEFAULT_EDGE_M, 0.75 * 2 * float(depth[1:].min()))
        clock.begin(f"the centerlines on the {h * 1e3:.2f} mm grid")
        centerlines = lumen_centerlines(grid, None, None, entry_m, sites_m, depth=lambda q: -grid(q))
        grid, tnotes = trim_side_branches(grid, list(centerlines.values()), entry_m, trim_branches_m)
        for n_ in tnotes:
            repairs.append(n_)
            log(f"repair: {path}: {n_}")
        grid = crop_lumen(grid, centerlines)
        # A surface to measure against (radii, the open end): the zero set at about 1 mm.
        step = max(1, int(round(0.001 / h)))
        v, f = zero_surface(grid.values[::step, ::step, ::step], grid.origin, h * step)
    else:
        for r in repairs:
            log(f"repair: {path}: {r}")
        v = v * scale
        depth = signed_distance(v, f, points)
        check_depths(depth)
        edge = float(edge_length_m) if edge_length_m else min(DEFAULT_EDGE_M, 0.75 * 2 * float(depth[1:].min()))
        h = float(sdf_spacing_m) if sdf_spacing_m else float(np.clip(0.25 * float(depth.min()), 0.0004, 0.001))
        check_grid_memory(v, f, h, 3 * edge + 2 * h, path)
        clock.begin(f"the distance grid at {h * 1e3:.2f} mm")
        grid = mesh_sdf_grid(v, f, h, pad=3 * edge + 2 * h)
        check_given_sites(grid)
        centerlines = lumen_centerlines(grid, v, f, entry_m, sites_m)
        grid = crop_lumen(grid, centerlines)
    # Checked before the (slow) remesh, with the radii of the lumen as given (from the grid: exact near
    # the wall, within half a node further in; the closest-point query on a 300k-triangle mesh took 30 s).
    profiles = {}
    for k, p in centerlines.items():
        dense = resample_polyline(p, 0.0005)
        profiles[k] = (dense, np.maximum(-grid(dense), 0.0))
    placement = site_placement_problems(profiles, label=lambda k: f"sites.{k}={format_point(sites_in[k])} {units_used}")
    if placement:
        raise MeshImportError(f"{path}: {placement[0]}")
    if dir_in is None:
        direction = estimate_entry_direction(grid, entry_m, centerlines)
        in_frame = "" if frame == SIM_FRAME else f" ({frame})"
        notes.append(
            "entry direction estimated from the lumen near the entry: "
            f"{format_point(from_sim(direction, frame), digits=3)}{in_frame}"
        )
        log(f"note: {notes[-1]}")
    else:
        direction = to_sim(dir_in, frame) / np.linalg.norm(dir_in)

    mean_edge, min_angle = triangle_stats(v, f)
    cropped = any(r.startswith("cropped ") for r in repairs)
    if use_volume:
        do_remesh = True
    elif remesh == "auto":
        reasons = []
        if not 0.2 * edge <= mean_edge <= 0.8 * edge:
            reasons.append(f"mean edge {mean_edge * 1e3:.2f} mm outside {0.2 * edge * 1e3:.1f}-{0.8 * edge * 1e3:.1f}")
        if min_angle < 10.0:
            reasons.append(f"triangles with angles down to {min_angle:.1f} deg")
        if len(f) > MAX_KEPT_TRIANGLES:
            reasons.append(f"{len(f)} triangles > {MAX_KEPT_TRIANGLES}")
        step = terrace_step_m(v, f)
        if step is not None:
            reasons.append(f"a terraced surface, voxel steps of about {step * 1e3:.1f} mm")
        if cropped:
            reasons.append("cropped")
        do_remesh = bool(reasons)
        msg = (
            ("remeshing (" + "; ".join(reasons) + ")")
            if reasons
            else f"keeping the {len(f)} triangles (mean edge {mean_edge * 1e3:.2f} mm, min angle {min_angle:.1f} deg)"
        )
        notes.append(msg)
        log(f"note: {msg}")
    else:
        do_remesh = bool(remesh) or cropped  # the surface as given still holds what the crop cut away
    # A fold the local repair leaves: the remedies, in order, until one works or none is left.
    tried: List[str] = []
    smoothing = list(FOLD_SMOOTHING)
    shortened = False
    thickened = False
    while True:
        meshing = f"remeshed at {edge * 1e3:.2f} mm edges" if do_remesh else "as given"
        after = f", after: {tried[-1]}" if tried else ""
        clock.begin(f"meshing the lumen ({meshing} on the {grid.spacing * 1e3:.2f} mm grid{after})", remedy_budget_s)
        try:
            lumen, open_end = build_open_lumen(
                v, f, grid, entry_m, direction, remesh=do_remesh, edge_length=edge, depth=open_end_depth_m, path=path
            )
            break
        except FoldedSurfaceError as exc:
            where = format_point(
                from_sim(exc.where, frame), 1e-3 if units_used == "mm" else 1.0, 1 if units_used == "mm" else 4
            )
            away = distance_to_paths_m(list(centerlines.values()), exc.where)
            width = max(FOLD_SEPTUM_NODES * grid.spacing, FOLD_SEPTUM_M)
            remedy = None
            if not do_remesh:
                do_remesh, remedy = True, "remeshed the surface"
            elif not shortened:
                shortened = True
                edge *= FOLD_RETRY_EDGE_FACTOR
                remedy = f"remeshed at {edge * 1e3:.2f} mm edges"
            elif not use_volume and repair == "auto":
                log(
                    f"note: the remeshed surface folds over at {where} {units_used}; rebuilding the lumen from a "
                    f"voxel volume (repair=volume)"
                )
                return import_mesh(
                    mesh_path,
                    out,
                    sites=sites_in,  # found ones too: the volume has no closed surface to find them on
                    entry=entry_in,
                    entry_direction=entry_direction,
                    units=units,
                    frame=frame,
                    name=name,
                    wall_thickness_m=wall_thickness_m,
                    edge_length_m=edge_length_m,
                    remesh=remesh,
                    sdf_spacing_m=sdf_spacing_m,
                    open_end_depth_m=open_end_depth_m,
                    validate=validate,
                    validator=validator,
                    overwrite=overwrite,
                    repair="volume",
                    smooth_m=smooth_m,
                    close_gap_m=close_gap_m,
                    trim_branches_m=trim_branches_m,
                    crop=crop,
                    crop_margin_m=crop_margin_m,
                    caps=caps,
                    log=log,
                    time_budget_s=time_budget_s,
                    remedy_budget_s=remedy_budget_s,
                    _clock=clock,
                )
            elif not thickened and (thick := thicken_septa(grid, exc.where, FOLD_SEPTUM_RADIUS_M, width))[1] < np.inf:
                thickened = True
                grid, thinnest = thick
                remedy = (
                    f"a septum or ridge crest down to {thinnest * 1e3:.2f} mm thick within "
                    f"{FOLD_SEPTUM_RADIUS_M * 1e3:.0f} mm of it thickened to {width * 1e3:.2f} mm"
                )
            elif smoothing:
                sigma, nodes, radius = smoothing.pop(0)
                sigma = max(sigma, nodes * grid.spacing)
                grid = smooth_around(grid, exc.where, radius, sigma)
                remedy = f"smoothed the volume within {radius * 1e3:.0f} mm of it over {sigma * 1e3:.1f} mm"
            elif crop == "auto" and away - FOLD_CROP_CLEARANCE_M >= 0.005:
                margin = away - FOLD_CROP_CLEARANCE_M
                grid, cnotes = crop_to_paths(grid, list(centerlines.values()), entry_m, margin)
                if cnotes:
                    remedy = cnotes[0].replace("cropped", "cut away", 1)
            if remedy is None:
                done = f" (tried: {'; '.join(tried)})" if tried else ""
                raise MeshImportError(
                    f"{path}: the lumen surface folds over at {where} {units_used}, "
                    f"{away * 1e3:.0f} mm from the nearest entry-to-site path, and no remedy undid "
                    f"it{done}; the mesh needs repair there (docs/anatomy.md#your-own-vessel)"
                ) from None
            tried.append(remedy)
            notes.append(f"a fold at {where} {units_used} survived local repair: {remedy}")
            log(f"note: {notes[-1]}")
    clock.begin("the wall")
    offsets = prism_offsets(lumen, wall_thickness_m)
    thinned, width = thin_at_septa(lumen, offsets)
    thin = thinned < offsets
    if thin.any():
        notes.append(septum_note(lumen.vertices, thin, width, thinned, wall_thickness_m, frame, units_used))
        log(f"note: {notes[-1]}")
    prisms = extrude_prisms(lumen, wall_thickness_m, offsets=thinned if thin.any() else None)
    wall = lumen.faces[~lumen.cap]
    cl = {k: (p, unsigned_distance(lumen.vertices, wall, p)) for k, p in centerlines.items()}
    lengths = {k: polyline_length(p) for k, p in centerlines.items()}
    ostia = ostia_from_centerlines(cl)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    params = {
        "source": path.name,
        "source_sha256": digest,
        "units": units_used,
        **({} if frame == SIM_FRAME else {"frame": frame}),
        "entry": json_rounded(entry_in),
        "entry_direction": None if dir_in is None else json_rounded(dir_in),
        "sites": {k: json_rounded(p) for k, p in sorted(sites_in.items())},
        **({"sites_found": "auto"} if auto else {}),
        "wall_thickness_m": wall_thickness_m,
        "edge_length_m": edge,
        "sdf_spacing_m": h,
        "remesh": do_remesh,
        "open_end_depth_m": open_end_depth_m,
        "crop": crop,
        "crop_margin_m": crop_margin_m,
        "repair": "volume" if use_volume else "surface",
    }
    description = (
        f"Imported lumen surface {path.name} ({units_used}{'' if frame == SIM_FRAME else ', ' + frame}); "
        f"{'remeshed' if do_remesh else 'triangles kept'}; wall: one "
        f"{wall_thickness_m * 1e3:g} mm prism per lumen triangle; repairs: "
        f"{'; '.join(repairs) if repairs else 'none'}."
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = pathlib.Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        write_asset(
            tmp,
            name=name,
            description=description,
            vertices=lumen.vertices,
            faces=lumen.faces,
            hulls=prisms,
            sites=sites_m,
            entry_position=entry_m,
            entry_direction=direction,
            centerlines=cl,
            wall_thickness_m=wall_thickness_m,
            params=params,
            extra={
                "open_end": open_end,
                "counts": {"triangles": int(len(lumen.faces)), "hulls": int(len(prisms))},
                "ostia": {k: json_rounded(p) for k, p in sorted(ostia.items())},
                "import": {"repairs": repairs, "notes": notes},
                **({} if frame == SIM_FRAME else {"source_frame": source_frame_record(frame, units_used, scale)}),
            },
        )
        clock.begin(f"validating the {len(prisms)} wall pieces")
        report = validator(tmp) if validate else None
        if report is not None and not report.ok:
            raise MeshImportError(
                f"{path}: the imported asset fails validation: {report.problems[0]}"
                f"{f' (and {len(report.problems) - 1} more)' if len(report.problems) > 1 else ''}"
            )
        if out.exists():
            shutil.rmtree(out)
        tmp.chmod(0o755)
        tmp.rename(out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return ImportReport(
        path=out,
        name=name,
        units=units_used,
        triangles=int(len(lumen.faces)),
        hulls=int(len(prisms)),
        remeshed=do_remesh,
        repairs=repairs,
        notes=notes,
        entry_direction=direction,
        path_length_m=lengths,
        seconds=time.perf_counter() - t0,
        validation=report,
    )
