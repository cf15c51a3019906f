"""Step 7 of a mesh import: the closed lumen (remeshed or as given) cut square to the entry
direction a few mm behind the entry and capped flat, the cap being the open end where the
wire comes in (see `importer`)."""

from __future__ import annotations

import numpy as np

from cathsim_dmc.anatomy.asset import json_rounded
from cathsim_dmc.anatomy.import_error import MeshImportError
from cathsim_dmc.anatomy.lumen import FoldedSurfaceError, Lumen, check_lumen_surface, lumen_normals, rim_vertices
from cathsim_dmc.anatomy.remesh import level_set_surface, manifold_arrays, refine_creases, relax_on_surface
from cathsim_dmc.anatomy.rim import clean_rim, close_cap
from cathsim_dmc.anatomy.sdf import signed_distance
from cathsim_dmc.anatomy.surface_cleanup import SHORT_EDGE_FRACTION, collapse_short_edges, fix_slivers, repair_folds
from cathsim_dmc.anatomy.triangles import boundary_loops, canonical_order, drop_unused_vertices, triangle_quality


def _frame(direction):
    d = direction / np.linalg.norm(direction)
    helper = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(d, helper)
    u /= np.linalg.norm(u)
    w = np.cross(u, d)
    return np.stack([u, d, w])  # rows: local x, y (= direction), z


def triangle_stats(v, f):
    """(mean edge length in m, smallest corner angle in degrees) of a triangle mesh."""
    q = triangle_quality(v, f)
    return q["edge_mean"], float(q["min_angle"].min())


def build_open_lumen(
    v, f, grid, entry, direction, *, remesh: bool, edge_length: float, depth: float, path
) -> "tuple[Lumen, dict]":
    """Closed lumen (remeshed or not), cut square to `direction` `depth` behind the entry, capped flat."""
    import manifold3d
    import trimesh

    rot = _frame(direction)
    # Where does the lumen end behind the entry? The cut must stay inside the vessel.
    tm = trimesh.Trimesh(v, f, process=False)
    hits, _, _ = tm.ray.intersects_location([entry], [-direction], multiple_hits=False)
    behind = float(np.linalg.norm(hits[0] - entry)) if len(hits) else 0.0
    if behind < 0.002:
        raise MeshImportError(
            f"{path}: the entry is only {behind * 1e3:.1f} mm from the end of its vessel; put it at least 2 mm inside"
        )
    depth = min(depth, 0.5 * behind)
    p0 = entry - depth * direction
    # Cross-section at the cut: the loop around the entry axis sets the cutting cylinder's radius.
    segs = trimesh.intersections.mesh_plane(tm, plane_normal=direction, plane_origin=p0)
    pts = segs.reshape(-1, 3) - p0
    radial = np.linalg.norm(pts - np.outer(pts @ direction, direction), axis=1)
    wall = float(-grid(p0[None])[0])
    own = radial < 3.0 * max(wall, 1e-4)
    r_loop = float(radial[own].max())
    r_cut = 1.25 * r_loop + 2 * grid.spacing
    if np.any(radial[~own] < r_cut):
        raise MeshImportError(
            f"{path}: another vessel passes within {r_cut * 1e3:.1f} mm of the open end "
            f"behind the entry; choose an entry further inside the vessel"
        )

    if remesh:
        shape = np.array(grid.values.shape)
        man = level_set_surface(grid, grid.origin + grid.spacing, grid.origin + grid.spacing * (shape - 2), edge_length)
    else:
        man = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=v, tri_verts=f.astype(np.uint64)))
    length = float(np.max(np.ptp(v, axis=0))) + 0.1
    cyl = manifold3d.Manifold.cylinder(length, r_cut, r_cut, 128)
    # Cylinder along +z from 0 to length -> along -direction from p0.
    m = np.zeros((3, 4))
    m[:, 0], m[:, 1], m[:, 2] = rot[0], rot[2], -rot[1]
    m[:, 3] = p0
    man = man - cyl.transform(m)
    if man.status() != manifold3d.Error.NoError or man.is_empty():
        raise MeshImportError(f"{path}: cutting the open end failed ({man.status().name})")
    parts = man.decompose()
    if len(parts) > 1:
        # Keep the piece holding the entry (pieces beyond the cut are dropped).
        best = None
        for part in parts:
            pm = part.to_mesh64()
            pv = np.array(pm.vert_properties)[:, :3]
            pf = np.array(pm.tri_verts, dtype=np.int64)
            if signed_distance(pv, pf, entry[None])[0] > 0:
                best = part
        man = best if best is not None else max(parts, key=lambda x: x.volume())
    vv, ff = manifold_arrays(man)
    edge = edge_length if remesh else triangle_stats(vv, ff)[0] * 1.7
    # Local frame: the cut plane is y = 0, the entry axis is the y axis.
    to_local = lambda x: (x - p0) @ rot.T
    to_world = lambda x: x @ rot + p0
    loc = to_local(vv)
    loc[np.abs(loc[:, 1]) < 1e-9, 1] = 0.0
    near_axis = np.hypot(loc[:, 0], loc[:, 2]) < r_cut + 1e-6
    cap = np.all((np.abs(loc[ff][:, :, 1]) < 1e-9) & near_axis[ff], axis=1)
    ff = ff[~cap]
    loc, ff = drop_unused_vertices(loc, ff)
    loops = boundary_loops(ff)
    if loops is None or len(loops) != 1:
        raise MeshImportError(
            f"{path}: the open end behind the entry is not one simple rim "
            f"({0 if loops is None else len(loops)} loops); choose another entry"
        )
    loc, ff = clean_rim(loc, ff, np.zeros(2), 0.0, edge, radius=r_cut + 3 * edge)
    vv = to_world(loc)
    band = lambda x: (
        (to_local(x)[:, 1] < 3 * edge) & (np.hypot(to_local(x)[:, 0], to_local(x)[:, 2]) < r_cut + 3 * edge)
    )
    if remesh:
        vv, ff = collapse_short_edges(vv, ff, grid, SHORT_EDGE_FRACTION * edge, frozen=band(vv))
        vv, ff = refine_creases(vv, ff, grid, 25.0, 1, -np.inf, frozen=band)
        vv = relax_on_surface(vv, ff, grid, frozen=band(vv), iterations=10)
    vv, ff = fix_slivers(vv, ff, grid, frozen=band(vv))
    vv, ff, _ = repair_folds(vv, ff, grid, frozen=band(vv))
    loc = to_local(vv)
    loc[np.abs(loc[:, 1]) < 1e-12, 1] = 0.0
    loc, ff = close_cap(loc, ff, 0.0)
    vv2, ff2 = canonical_order(to_world(loc), ff)
    _, first, count = np.unique(vv2.astype(np.float32), axis=0, return_index=True, return_counts=True)
    if np.any(count > 1):  # two sheets meshed onto one point: a septum thinner than the mesher resolves
        where = vv2[first[np.argmax(count)]]
        raise FoldedSurfaceError(
            f"Lumen surface touches itself at [{', '.join(f'{x * 1e3:.1f}' for x in where)}] mm.", where=where
        )
    loc2 = to_local(vv2)
    cap2 = np.all(
        (np.abs(loc2[ff2][:, :, 1]) < 1e-9) & (np.hypot(loc2[ff2][:, :, 0], loc2[ff2][:, :, 2]) < r_cut + 3 * edge),
        axis=1,
    )
    normals = lumen_normals(vv2, ff2, cap2, direction)
    rim = rim_vertices(ff2, cap2)
    try:
        check_lumen_surface(vv2, ff2, cap2, grid)
    except FoldedSurfaceError:
        raise
    except RuntimeError as exc:
        raise MeshImportError(f"{path}: {exc}") from None
    radius = float(np.max(np.linalg.norm((vv2[rim] - p0) - np.outer((vv2[rim] - p0) @ direction, direction), axis=1)))
    open_end = {"center": json_rounded(p0), "normal": json_rounded(-direction), "radius_m": json_rounded(radius)}
    return Lumen(vertices=vv2, faces=ff2, cap=cap2, normals=normals), open_end


# ----------------------------------------------------------------------------
# The whole import
