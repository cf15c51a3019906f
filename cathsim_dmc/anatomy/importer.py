"""Import a vessel LUMEN surface (STL/OBJ, e.g. from a CT segmentation) as an aorta asset folder.

    from cathsim_dmc.anatomy.importer import import_mesh
    report = import_mesh("lumen.stl", "assets_local/patient7", units="mm",
                         entry=[30, -110, -5], sites={"bca": [-27, 74, 2], "lcca": [-1, 79, 0]})

The pipeline, each step with one clear error (`MeshImportError`) when it cannot
go on:

1. **read** the mesh with trimesh;
2. **repair** what is safe to repair: merge duplicate vertices, drop degenerate
   and duplicate triangles, drop loose pieces, fill 3-4 edge holes (trimesh),
   close open vessel ends (holes whose rim is a flat loop), fix the triangle
   winding and an inside-out surface. Non-manifold edges, holes that are not
   flat vessel ends or a surface that stays open are refused;
3. **units**: ``units="mm"`` or ``"m"``, or ``"auto"``: a mesh more than 2
   units across is taken to be in millimetres (a note says so). Sites and the
   entry are given in the mesh's units;
4. **signed distance grid** of the lumen (exact within a narrow band around the
   surface, flood fill + distance transform elsewhere);
5. **centerlines**: shortest paths on the lumen voxels at least the wire probe
   (0.945 mm) away from the wall, weighted by 1/clearance^2 so they run near
   the medial axis, from the entry to each site; Gaussian-smoothed where that
   keeps the clearance; radius = distance to the final wall;
6. **entry direction**: given, or the principal axis of the lumen within a few
   radii of the entry, pointing towards the sites;
7. **lumen**: kept as given if its triangles suit the wall prisms (mean edge
   0.8-3.2 mm at the default 4 mm target, no angle below 10 deg, at most 40k
   triangles), else **remeshed** like the generator (level set of the SDF grid,
   curvature refinement, relaxation). The vessel is then cut square to the
   entry direction a few mm behind the entry (locally: a cylinder around the
   entry axis is subtracted) and capped flat; the cap is the open end where
   the wire comes in and gets no wall;
8. **wall**: one prism per lumen triangle extruded outward (as generated
   arches);
9. **validate** (`validator`: `cathsim_dmc.anatomy.validate.validate_asset`; the
   CLI passes `cathsim_dmc.model_check.validate_and_compile`, which adds the
   MuJoCo compile) and only then move the folder into place.
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
from scipy import ndimage, sparse, spatial
from scipy.sparse import csgraph

from cathsim_dmc.anatomy.asset import json_rounded, write_asset
from cathsim_dmc.anatomy.isosurface import zero_surface
from cathsim_dmc.anatomy.lumen import FoldedSurfaceError, Lumen, check_lumen_surface, lumen_normals, rim_vertices
from cathsim_dmc.anatomy.polyline import arclength, polyline_length, resample_polyline
from cathsim_dmc.anatomy.remesh import level_set_surface, manifold_arrays, refine_creases, relax_on_surface
from cathsim_dmc.anatomy.rim import clean_rim, close_cap
from cathsim_dmc.anatomy.sdf import SDFGrid, signed_distance, unsigned_distance
from cathsim_dmc.anatomy.surface_cleanup import SHORT_EDGE_FRACTION, collapse_short_edges, fix_slivers, repair_folds
from cathsim_dmc.anatomy.triangles import (boundary_loops, canonical_order, drop_unused_vertices, fan_triangles,
                                           triangle_quality)
from cathsim_dmc.anatomy.validate import (PROBE_RADIUS_M, ValidationReport, ostia_from_centerlines,
                                          lumen_profile, site_placement_problems, validate_asset)
from cathsim_dmc.anatomy.volume import VolumeError, trim_side_branches, volume_sdf_grid
from cathsim_dmc.anatomy.wall import extrude_prisms

MIN_SITE_DEPTH_M = 0.001
DEFAULT_EDGE_M = 0.004            # level-set edge of the generator: mean edges come out ~2.3 mm
MAX_KEPT_TRIANGLES = 40_000
REPAIR_MODES = ("auto", "surface", "volume")
AUTO_SURFACE_MAX_TRIANGLES = 100_000   # repair=auto rebuilds larger surfaces through the volume
VOLUME_GRID_NODES = 10_000_000     # the voxel volume's default spacing aims at this many nodes
FOLD_RETRY_EDGE_FACTOR = 0.85
MAX_GRID_NODES = 30_000_000
MAX_EXTENT_M = 1.5                 # larger than any aorta (an arch spans 0.1-0.6 m): a unit slip
# Peak memory of the grid stages, per grid node and per node inside the lumen (the
# centerline graph): the type I arch at sdf_mm=0.5 (14.4 M nodes, 1.3 M in the lumen)
# peaked at 1.8 GB.
GRID_BYTES_PER_NODE = 100
GRID_BYTES_PER_LUMEN_NODE = 300
MEMORY_FRACTION = 0.7              # of MemAvailable the import may plan to use


class MeshImportError(ValueError):
    """A mesh that cannot be imported; the message is one line naming the file and the problem."""


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


def _fmt(p, scale=1.0, digits=1):
    return "[" + ", ".join(f"{x / scale:.{digits}f}" for x in np.asarray(p, dtype=float)) + "]"


# ----------------------------------------------------------------------------
# 1-2: read and repair


def read_lumen(path) -> "tuple[np.ndarray, np.ndarray]":
    """Vertices and faces of a mesh file, or MeshImportError."""
    import trimesh

    path = pathlib.Path(path)
    if not path.is_file():
        raise MeshImportError(f"{path}: no such file")
    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # noqa: BLE001 - any reader failure is a bad file
        detail = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise MeshImportError(f"{path}: cannot be read as a mesh ({detail})") from None
    faces = getattr(loaded, "faces", None)
    if not isinstance(loaded, trimesh.Trimesh) or faces is None or len(faces) == 0:
        raise MeshImportError(f"{path}: contains no triangles (is it an STL or OBJ surface mesh?)")
    v = np.asarray(loaded.vertices, dtype=np.float64)
    f = np.asarray(loaded.faces, dtype=np.int64)
    if not np.all(np.isfinite(v)):
        raise MeshImportError(f"{path}: has non-finite vertex coordinates")
    return v, f


def repair_lumen(v, f, path, units_label="units") -> "tuple[np.ndarray, np.ndarray, List[str]]":
    """Safe repairs; MeshImportError when the surface cannot be made a closed 2-manifold."""
    import trimesh

    repairs = []
    mesh = trimesh.Trimesh(v, f, process=False)
    n_v = len(mesh.vertices)
    mesh.merge_vertices()
    bad = ~mesh.nondegenerate_faces()
    if bad.any():
        mesh.update_faces(~bad)
        repairs.append(f"dropped {int(bad.sum())} degenerate triangles")
    uniq = mesh.unique_faces()
    if len(uniq) < len(mesh.faces):
        keep = np.zeros(len(mesh.faces), dtype=bool)
        keep[uniq] = True
        repairs.append(f"dropped {int((~keep).sum())} duplicate triangles")
        mesh.update_faces(keep)
    mesh.remove_unreferenced_vertices()
    merged = n_v - len(mesh.vertices)
    if merged and path.suffix.lower() != ".stl":      # STL always repeats shared vertices
        repairs.append(f"merged {merged} duplicate vertices")
    if len(mesh.faces) < 4:
        raise MeshImportError(f"{path}: has fewer than 4 usable triangles")
    # Non-manifold edges (three or more triangles on one edge): not safely repairable.
    edges = np.sort(mesh.edges, axis=1)
    uniq_e, counts = np.unique(edges, axis=0, return_counts=True)
    if np.any(counts > 2):
        where = mesh.vertices[uniq_e[counts > 2][0, 0]]
        raise MeshImportError(
            f"{path}: non-manifold surface: {int(np.sum(counts > 2))} edges are shared by more than two "
            f"triangles (first at {_fmt(where, digits=3)} {units_label}); a lumen must be one closed surface")
    # Loose pieces: keep the largest (by area).
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))
    if labels.max() > 0:
        area = np.bincount(labels, weights=mesh.area_faces)
        keep = labels == int(np.argmax(area))
        repairs.append(f"dropped {int(labels.max())} loose pieces ({100 * (1 - area.max() / area.sum()):.1f}% of "
                       f"the area)")
        mesh.update_faces(keep)
        mesh.remove_unreferenced_vertices()
    # Holes: trimesh fills 3-4 edge holes; flat loops (vessel ends) get a fan cap.
    if not mesh.is_watertight:
        before = len(mesh.faces)
        trimesh.repair.fill_holes(mesh)
        if len(mesh.faces) > before:
            repairs.append(f"filled small holes with {len(mesh.faces) - before} triangles")
    if not mesh.is_watertight:
        vv, ff = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        loops = boundary_loops(ff)
        if loops is None:
            raise MeshImportError(f"{path}: not watertight, and its holes touch each other; cannot close them safely")
        caps, added = [], []
        for loop in loops:
            p = vv[loop]
            c = p.mean(axis=0)
            _, sv, vt = np.linalg.svd(p - c)
            normal = vt[2]
            size = float(np.max(np.linalg.norm(p - c, axis=1)))
            off = float(np.max(np.abs((p - c) @ normal)))
            # A flat loop whose points all see its centroid: a vessel end cut by the segmentation.
            if len(loop) < 5 or off > 0.05 * size:
                raise MeshImportError(
                    f"{path}: not watertight: a hole of {len(loop)} edges around {_fmt(c, digits=3)} {units_label} "
                    f"is not a flat vessel end ({off / max(size, 1e-12) * 100:.0f}% out of plane); cannot close "
                    f"it safely")
            ci = len(vv) + len(added)
            added.append(c)
            caps.append(fan_triangles(loop, ci))
        mesh = trimesh.Trimesh(np.concatenate([vv, np.array(added)]), np.concatenate([ff] + caps),
                               process=False)
        repairs.append(f"closed {len(loops)} flat open vessel end{'s' * (len(loops) > 1)}")
    if not mesh.is_winding_consistent:
        trimesh.repair.fix_winding(mesh)
        if not mesh.is_winding_consistent:
            raise MeshImportError(f"{path}: triangle orientations are inconsistent and cannot be fixed "
                                  f"(a one-sided or self-overlapping surface?)")
        repairs.append("made the triangle winding consistent")
    if not mesh.is_watertight:
        raise MeshImportError(f"{path}: not watertight after repair")
    if mesh.volume < 0:
        mesh.invert()
        repairs.append("turned the inside-out surface the right way round")
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    import manifold3d

    status = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=v, tri_verts=f.astype(np.uint64))).status()
    if status != manifold3d.Error.NoError:
        raise MeshImportError(f"{path}: not a valid closed 2-manifold ({status.name})")
    return v, f, repairs


def detect_units(v, units: str, path) -> "tuple[float, str, Optional[str]]":
    """(scale to metres, units used, note) for `units` in auto|mm|m."""
    extent = float(np.max(np.ptp(v, axis=0)))
    if units == "auto":
        if extent > 2.0:
            return 1e-3, "mm", (f"{path}: spans {extent:.1f} units, assuming millimetres "
                                f"(pass units=m if it is in metres)")
        return 1.0, "m", f"{path}: spans {extent:.3f} units, assuming metres (pass units=mm if it is in millimetres)"
    if units not in ("mm", "m"):
        raise ValueError(f"units={units!r} is not valid; choose one of ['auto', 'mm', 'm']")
    scale = 1e-3 if units == "mm" else 1.0
    note = None
    if not 0.005 < extent * scale < 2.0:
        note = f"{path}: spans {extent * scale:.3g} m in units={units}; is that the right unit?"
    return scale, units, note


# ----------------------------------------------------------------------------
# 4: signed distance grid


def grid_shape(v, spacing: float, pad: float) -> "tuple[np.ndarray, np.ndarray]":
    """(origin, nodes per axis) of the SDF grid around vertices `v`."""
    lo = np.floor((v.min(axis=0) - pad) / spacing) * spacing
    return lo, np.ceil((v.max(axis=0) + pad - lo) / spacing).astype(int) + 1


def check_grid_memory(v, f, spacing: float, pad: float, path, available_bytes: Optional[int] = None) -> int:
    """The planned peak memory of the grid stages (bytes), or MeshImportError (one line,
    naming sdf_mm) if it exceeds MEMORY_FRACTION of the available memory: refused before
    anything large is allocated."""
    from cathsim_dmc.checks import available_memory_bytes

    _, n = grid_shape(v, spacing, pad)
    nodes = float(np.prod(n.astype(float)))
    tri = v[f]
    volume = abs(float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()) / 6.0)
    need = GRID_BYTES_PER_NODE * nodes + GRID_BYTES_PER_LUMEN_NODE * volume / spacing ** 3
    have = available_memory_bytes() if available_bytes is None else int(available_bytes)
    if need > MEMORY_FRACTION * have:
        enough = spacing * (need / (MEMORY_FRACTION * have)) ** (1 / 3)
        raise MeshImportError(f"{path}: a {n[0]}x{n[1]}x{n[2]} grid at sdf_mm={spacing * 1e3:.2f} needs about "
                              f"{need / 2**30:.1f} GiB, {have / 2**30:.1f} GiB available; pass sdf_mm="
                              f"{np.ceil(enough * 1e4) / 10:.1f} or more")
    return int(need)


def mesh_sdf_grid(v, f, spacing: float, pad: float) -> SDFGrid:
    """SDF grid (positive OUTSIDE) of a closed mesh: exact within ~1 node of the surface.

    Nodes next to the surface (every node within one node of a dense surface
    sample) get the exact signed distance; the rest are classified by a flood
    fill from the grid border and get a distance-transform distance.
    """
    import trimesh

    h = float(spacing)
    lo, n = grid_shape(v, h, pad)
    if int(np.prod(n)) > MAX_GRID_NODES:
        raise MeshImportError(f"the mesh needs a {n[0]}x{n[1]}x{n[2]} grid at {h * 1e3:.2f} mm; "
                              f"pass a larger sdf_mm")
    sv, _ = trimesh.remesh.subdivide_to_size(v, f, max_edge=0.5 * h)
    idx = np.clip(np.rint((sv - lo) / h).astype(int), 0, n - 1)
    band = np.zeros(tuple(n), dtype=bool)
    band[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    band = ndimage.binary_dilation(band, structure=np.ones((3, 3, 3), dtype=bool))
    nodes = np.argwhere(band)
    sd_band = signed_distance(v, f, lo + h * nodes)           # + inside
    labels, _ = ndimage.label(~band)
    border = np.unique(np.concatenate([labels[0].ravel(), labels[-1].ravel(), labels[:, 0].ravel(),
                                       labels[:, -1].ravel(), labels[:, :, 0].ravel(), labels[:, :, -1].ravel()]))
    outside = np.isin(labels, border[border > 0])
    inside = ~band & ~outside
    inside[tuple(nodes[sd_band > 0].T)] = True
    d_in = ndimage.distance_transform_edt(inside) * h
    d_out = ndimage.distance_transform_edt(~inside) * h
    values = np.where(inside, -np.maximum(d_in - 0.5 * h, 0.0), np.maximum(d_out - 0.5 * h, 0.0))
    values[tuple(nodes.T)] = -sd_band
    return SDFGrid(origin=lo, spacing=h, values=values)


# ----------------------------------------------------------------------------
# 5: centerlines


_OFFSETS = np.array([o for o in np.ndindex(3, 3, 3) if o != (1, 1, 1)]) - 1
_OFFSETS = _OFFSETS[[tuple(o) > (0, 0, 0) for o in _OFFSETS]]          # 13 of the 26 neighbours


def _grid_graph(grid: SDFGrid, clearance: float):
    """Sparse graph over grid nodes at least `clearance` inside the lumen; weights length / depth^2."""
    depth = -grid.values
    ok = depth >= clearance
    ids = -np.ones(depth.shape, dtype=np.int64)
    where = np.argwhere(ok)
    ids[tuple(where.T)] = np.arange(len(where))
    rows, cols, w = [], [], []
    shape = np.array(depth.shape)
    for o in _OFFSETS:
        nb = where + o
        inside = np.all((nb >= 0) & (nb < shape), axis=1)
        a = np.nonzero(inside)[0]
        b = ids[tuple(nb[inside].T)]
        good = b >= 0
        a, b = a[good], b[good]
        dm = 0.5 * (depth[tuple(where[a].T)] + depth[tuple(where[b].T)])
        length = grid.spacing * float(np.linalg.norm(o))
        rows.append(a)
        cols.append(b)
        w.append(length * (grid.spacing / dm) ** 2)
    rows, cols, w = (np.concatenate(x) for x in (rows, cols, w))
    graph = sparse.coo_matrix((w, (rows, cols)), shape=(len(where), len(where))).tocsr()
    return graph, grid.origin + grid.spacing * where


def _smooth_path(raw, depth, clearance, spacing=0.0015):
    """Gaussian-smoothed polyline (ends kept) with the largest sigma that keeps `clearance` from the wall
    (`depth`: points -> distance inside the lumen)."""
    fine = resample_polyline(raw, 0.0005)
    s = arclength(fine)
    depth_raw = depth(fine)
    want = min(float(depth_raw.min()), clearance)
    for sigma_m in (0.004, 0.0025, 0.0015, 0.0008, 0.0):
        if sigma_m > 0:
            sm = ndimage.gaussian_filter1d(fine, sigma_m / 0.0005, axis=0, mode="nearest")
            ramp = np.clip(np.minimum(s, s[-1] - s) / (3 * sigma_m), 0.0, 1.0)[:, None]
            cand = fine + ramp * (sm - fine)
        else:
            cand = fine
        out = resample_polyline(cand, spacing)
        if sigma_m == 0.0 or depth(resample_polyline(cand, 0.0005)).min() >= want:
            return out
    return resample_polyline(fine, spacing)


def lumen_centerlines(grid, v, f, entry, sites: Mapping[str, np.ndarray], probe=PROBE_RADIUS_M, depth=None):
    """Entry -> site polylines through the lumen (see the module docstring); MeshImportError if blocked.

    `depth` (points -> distance inside the lumen) defaults to the signed distance to the mesh v, f."""
    if depth is None:
        depth = lambda p: signed_distance(v, f, p)
    graph, coords = _grid_graph(grid, probe)
    if len(coords) == 0:
        raise MeshImportError(f"no part of the lumen is {2 * probe * 1e3:.1f} mm wide (wire probe)")
    tree = spatial.cKDTree(coords)

    def node_near(p, what):
        d, i = tree.query(p)
        if d > 3 * grid.spacing:
            raise MeshImportError(f"{what} lies where the lumen is narrower than the {2 * probe * 1e3:.1f} mm "
                                  f"wire probe")
        return int(i)

    src = node_near(entry, "entry")
    dist, pred = csgraph.dijkstra(graph, directed=False, indices=src, return_predecessors=True)
    out = {}
    for k, site in sites.items():
        dst = node_near(site, f"site {k}")
        if not np.isfinite(dist[dst]):
            raise MeshImportError(f"site {k} cannot be reached from the entry through lumen at least "
                                  f"{2 * probe * 1e3:.1f} mm wide")
        chain = [dst]
        while chain[-1] != src:
            chain.append(int(pred[chain[-1]]))
        raw = np.concatenate([[entry], coords[chain[::-1]], [site]])
        out[k] = _smooth_path(raw, depth, probe + 0.3e-3)
    return out


def estimate_entry_direction(grid, entry, centerlines) -> np.ndarray:
    """Principal axis of the lumen nodes near the entry, pointing along the centerlines."""
    depth_entry = float(-grid(np.asarray(entry)[None])[0])
    radius = max(2.5 * depth_entry, 0.008)
    h = grid.spacing
    lo = np.maximum(np.floor((entry - radius - grid.origin) / h).astype(int), 0)
    hi = np.minimum(np.ceil((entry + radius - grid.origin) / h).astype(int) + 1, np.array(grid.values.shape))
    sub = grid.values[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
    idx = np.argwhere(sub < 0) + lo
    pts = grid.origin + h * idx
    pts = pts[np.linalg.norm(pts - entry, axis=1) < radius]
    c = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - c, full_matrices=False)
    axis = vt[0]
    ahead = []
    for pts_c in centerlines.values():
        s = arclength(pts_c)
        ahead.append(pts_c[int(np.searchsorted(s, min(radius, s[-1])))])
    if np.dot(np.mean(ahead, axis=0) - entry, axis) < 0:
        axis = -axis
    return axis / np.linalg.norm(axis)


# ----------------------------------------------------------------------------
# 7: the lumen with its open end


def _frame(direction):
    d = direction / np.linalg.norm(direction)
    helper = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(d, helper)
    u /= np.linalg.norm(u)
    w = np.cross(u, d)
    return np.stack([u, d, w])        # rows: local x, y (= direction), z


def _triangle_stats(v, f):
    q = triangle_quality(v, f)
    return q["edge_mean"], float(q["min_angle"].min())


def build_open_lumen(v, f, grid, entry, direction, *, remesh: bool, edge_length: float, depth: float,
                     path) -> "tuple[Lumen, dict]":
    """Closed lumen (remeshed or not), cut square to `direction` `depth` behind the entry, capped flat."""
    import manifold3d
    import trimesh

    rot = _frame(direction)
    # Where does the lumen end behind the entry? The cut must stay inside the vessel.
    tm = trimesh.Trimesh(v, f, process=False)
    hits, _, _ = tm.ray.intersects_location([entry], [-direction], multiple_hits=False)
    behind = float(np.linalg.norm(hits[0] - entry)) if len(hits) else 0.0
    if behind < 0.002:
        raise MeshImportError(f"{path}: the entry is only {behind * 1e3:.1f} mm from the end of its vessel; "
                              f"put it at least 2 mm inside")
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
        raise MeshImportError(f"{path}: another vessel passes within {r_cut * 1e3:.1f} mm of the open end "
                              f"behind the entry; choose an entry further inside the vessel")

    if remesh:
        shape = np.array(grid.values.shape)
        man = level_set_surface(grid, grid.origin + grid.spacing, grid.origin + grid.spacing * (shape - 2),
                                edge_length)
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
    edge = edge_length if remesh else _triangle_stats(vv, ff)[0] * 1.7
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
        raise MeshImportError(f"{path}: the open end behind the entry is not one simple rim "
                              f"({0 if loops is None else len(loops)} loops); choose another entry")
    loc, ff = clean_rim(loc, ff, np.zeros(2), 0.0, edge, radius=r_cut + 3 * edge)
    vv = to_world(loc)
    band = lambda x: (to_local(x)[:, 1] < 3 * edge) & (np.hypot(to_local(x)[:, 0], to_local(x)[:, 2]) < r_cut + 3 * edge)
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
    loc2 = to_local(vv2)
    cap2 = np.all((np.abs(loc2[ff2][:, :, 1]) < 1e-9)
                  & (np.hypot(loc2[ff2][:, :, 0], loc2[ff2][:, :, 2]) < r_cut + 3 * edge), axis=1)
    normals = lumen_normals(vv2, ff2, cap2, direction)
    rim = rim_vertices(ff2, cap2)
    try:
        check_lumen_surface(vv2, ff2, cap2, grid)
    except FoldedSurfaceError:
        raise
    except RuntimeError as exc:
        raise MeshImportError(f"{path}: {exc}") from None
    radius = float(np.max(np.linalg.norm((vv2[rim] - p0) - np.outer((vv2[rim] - p0) @ direction, direction),
                                         axis=1)))
    open_end = {"center": json_rounded(p0), "normal": json_rounded(-direction), "radius_m": json_rounded(radius)}
    return Lumen(vertices=vv2, faces=ff2, cap=cap2, normals=normals), open_end


# ----------------------------------------------------------------------------
# The whole import


def _vec(value, what) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{what}={value!r} must be three numbers [x, y, z]")
    return a


def import_mesh(mesh_path, out, *, sites: Mapping[str, Sequence[float]], entry: Sequence[float],
                entry_direction: Optional[Sequence[float]] = None, units: str = "auto", name: Optional[str] = None,
                wall_thickness_m: float = 0.002, edge_length_m: Optional[float] = None, remesh="auto",
                sdf_spacing_m: Optional[float] = None, open_end_depth_m: float = 0.005, validate: bool = True,
                validator: Callable[[pathlib.Path], ValidationReport] = validate_asset,
                overwrite: bool = False, repair: str = "auto", smooth_m: Optional[float] = None,
                close_gap_m: float = 0.002, trim_branches_m: float = 0.003,
                log: Callable[[str], None] = print) -> ImportReport:
    """Turn a lumen surface file into an asset folder at `out` (see the module docstring)."""
    t0 = time.perf_counter()
    path = pathlib.Path(mesh_path)
    out = pathlib.Path(out)
    name = name or path.stem
    if not sites:
        raise ValueError("give at least one site, e.g. sites.bca=[x,y,z]")
    entry_in = _vec(entry, "entry")
    sites_in = {str(k): _vec(p, f"sites.{k}") for k, p in sites.items()}
    dir_in = None if entry_direction is None else _vec(entry_direction, "entry_direction")
    if dir_in is not None and np.linalg.norm(dir_in) == 0:
        raise ValueError("entry_direction must not be [0, 0, 0]")
    if repair not in REPAIR_MODES:
        raise ValueError(f"repair={repair!r} is not valid; choose one of {list(REPAIR_MODES)}")
    for key, value in (("smooth_m", smooth_m), ("close_gap_m", close_gap_m), ("trim_branches_m", trim_branches_m)):
        if value is not None and not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{key}={value!r} is not valid; give metres (0 or more)")
    if remesh not in ("auto", True, False):
        raise ValueError(f"remesh={remesh!r} is not valid; choose one of ['auto', true, false]")
    if not 0.0002 <= wall_thickness_m <= 0.01:
        raise ValueError(f"wall thickness {wall_thickness_m * 1e3:g} mm is not valid; use 0.2-10 mm")
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise ValueError(f"out={str(out)!r} exists and is not empty; pass overwrite=true or another out")

    v, f = read_lumen(path)
    scale, units_used, note = detect_units(v, units, path)
    notes = [note] if note else []
    for n_ in notes:
        log(f"note: {n_}")
    extent_m = float(np.max(np.ptp(v, axis=0))) * scale
    if extent_m > MAX_EXTENT_M:
        raise MeshImportError(f"{path}: spans {extent_m:.3g} m with units={units_used}, more than any aorta "
                              f"({MAX_EXTENT_M:g} m at most); pass the right units= or rescale the mesh")
    entry_m = entry_in * scale
    sites_m = {k: p * scale for k, p in sites_in.items()}
    labels = ["entry"] + [f"sites.{k}" for k in sites_m]
    given = [entry_in] + list(sites_in.values())

    def check_depths(depth):
        for lab, d, p in zip(labels, depth, given):
            need = PROBE_RADIUS_M if lab == "entry" else MIN_SITE_DEPTH_M
            if d < need:
                where = "outside the lumen" if d <= 0 else "inside the lumen but too close to the wall"
                raise MeshImportError(f"{path}: {lab}={_fmt(p, digits=4 if units_used == 'm' else 1)} {units_used} "
                                      f"is {where} ({d * 1e3:+.2f} mm from the wall; needs >= {need * 1e3:.2f} mm "
                                      f"inside)")

    use_volume = repair == "volume"
    repairs: List[str] = []
    if not use_volume:
        try:
            v_closed, f_closed, repairs = repair_lumen(v, f, path, units_used)
        except MeshImportError as exc:
            if repair == "surface":
                raise
            reason = str(exc).split(": ", 1)[-1]
            notes.append(f"the surface repair cannot fix it ({reason}); rebuilding it from a voxel volume "
                         f"(repair=volume)")
            log(f"note: {notes[-1]}")
            use_volume = True
        else:
            if repair == "auto" and len(f_closed) > AUTO_SURFACE_MAX_TRIANGLES:
                # A segmentation export: exact distances to every triangle cost minutes, and its
                # noise folds the remeshed surface; the volume smooths it.
                notes.append(f"{len(f_closed)} triangles: rebuilding the lumen from a voxel volume "
                             f"(repair=surface keeps to the surface as given)")
                log(f"note: {notes[-1]}")
                use_volume = True
                repairs = []          # made to the surface, which the volume does not use
            else:
                v, f = v_closed, f_closed
    points = np.concatenate([[entry_m], list(sites_m.values())])
    if use_volume:
        import trimesh

        mesh = trimesh.Trimesh(v * scale, f, process=False)
        mesh.merge_vertices()
        mesh.update_faces(mesh.nondegenerate_faces())
        v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
        edge = float(edge_length_m) if edge_length_m else DEFAULT_EDGE_M
        box = np.ptp(v, axis=0) + 2 * (3 * edge)
        h = float(sdf_spacing_m) if sdf_spacing_m else float(np.clip(np.cbrt(np.prod(box) / VOLUME_GRID_NODES),
                                                                     0.0004, 0.001))
        pad = 3 * edge + 2 * h
        check_grid_memory(v, f, h, pad, path)
        smooth = h if smooth_m is None else float(smooth_m)
        try:
            grid, vnotes = volume_sdf_grid(v, f, h, pad, entry_m, sites_m, max_gap_m=close_gap_m, smooth_m=smooth)
        except VolumeError as exc:
            raise MeshImportError(f"{path}: {exc}") from None
        for n_ in vnotes:
            repairs.append(n_)
            log(f"repair: {path}: {n_}")
        depth = -grid(points)
        check_depths(depth)
        if not edge_length_m:
            edge = min(DEFAULT_EDGE_M, 0.75 * 2 * float(depth[1:].min()))
        centerlines = lumen_centerlines(grid, None, None, entry_m, sites_m, depth=lambda q: -grid(q))
        grid, tnotes = trim_side_branches(grid, list(centerlines.values()), entry_m, trim_branches_m)
        for n_ in tnotes:
            repairs.append(n_)
            log(f"repair: {path}: {n_}")
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
        grid = mesh_sdf_grid(v, f, h, pad=3 * edge + 2 * h)
        centerlines = lumen_centerlines(grid, v, f, entry_m, sites_m)
    # Checked before the (slow) remesh, with the radii of the lumen as given (from the grid: exact near
    # the wall, within half a node further in; the closest-point query on a 300k-triangle mesh took 30 s).
    profiles = {}
    for k, p in centerlines.items():
        dense = resample_polyline(p, 0.0005)
        profiles[k] = (dense, np.maximum(-grid(dense), 0.0))
    placement = site_placement_problems(profiles,
                                        label=lambda k: f"sites.{k}={_fmt(sites_in[k])} {units_used}")
    if placement:
        raise MeshImportError(f"{path}: {placement[0]}")
    if dir_in is None:
        direction = estimate_entry_direction(grid, entry_m, centerlines)
        notes.append(f"entry direction estimated from the lumen near the entry: {_fmt(direction, digits=3)}")
        log(f"note: {notes[-1]}")
    else:
        direction = dir_in / np.linalg.norm(dir_in)

    mean_edge, min_angle = _triangle_stats(v, f)
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
        do_remesh = bool(reasons)
        msg = ("remeshing (" + "; ".join(reasons) + ")") if reasons else \
            f"keeping the {len(f)} triangles (mean edge {mean_edge * 1e3:.2f} mm, min angle {min_angle:.1f} deg)"
        notes.append(msg)
        log(f"note: {msg}")
    else:
        do_remesh = bool(remesh)
    # A fold the local repair leaves is retried once with shorter edges (as the generator does).
    for attempt in range(2):
        try:
            lumen, open_end = build_open_lumen(v, f, grid, entry_m, direction, remesh=do_remesh, edge_length=edge,
                                               depth=open_end_depth_m, path=path)
            break
        except FoldedSurfaceError as exc:
            where = _fmt(exc.where, 1e-3 if units_used == "mm" else 1.0, 1 if units_used == "mm" else 4)
            if attempt == 0 and do_remesh:
                edge *= FOLD_RETRY_EDGE_FACTOR
                notes.append(f"a fold at {where} {units_used} survived local repair; remeshing at "
                             f"{edge * 1e3:.2f} mm edges")
                log(f"note: {notes[-1]}")
                continue
            if repair == "auto" and not use_volume:
                log(f"note: the remeshed surface folds over at {where} {units_used}; rebuilding the lumen from a "
                    f"voxel volume (repair=volume)")
                return import_mesh(mesh_path, out, sites=sites, entry=entry, entry_direction=entry_direction,
                                   units=units, name=name, wall_thickness_m=wall_thickness_m,
                                   edge_length_m=edge_length_m, remesh=remesh, sdf_spacing_m=sdf_spacing_m,
                                   open_end_depth_m=open_end_depth_m, validate=validate, validator=validator,
                                   overwrite=overwrite, repair="volume", smooth_m=smooth_m,
                                   close_gap_m=close_gap_m, trim_branches_m=trim_branches_m, log=log)
            hint = (f"edge_mm={0.8 * edge * 1e3:.1f}" if do_remesh else "remesh=true") + \
                   ("" if use_volume else " or repair=volume")
            raise MeshImportError(f"{path}: the lumen surface folds over at {where} {units_used} and local repair "
                                  f"cannot undo it; pass {hint}") from None
    prisms = extrude_prisms(lumen, wall_thickness_m)
    wall = lumen.faces[~lumen.cap]
    cl = {k: (p, unsigned_distance(lumen.vertices, wall, p)) for k, p in centerlines.items()}
    lengths = {k: polyline_length(p) for k, p in centerlines.items()}
    ostia = ostia_from_centerlines(cl)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    params = {"source": path.name, "source_sha256": digest, "units": units_used,
              "entry": json_rounded(entry_in), "entry_direction": None if dir_in is None else json_rounded(dir_in),
              "sites": {k: json_rounded(p) for k, p in sorted(sites_in.items())},
              "wall_thickness_m": wall_thickness_m, "edge_length_m": edge, "sdf_spacing_m": h,
              "remesh": do_remesh, "open_end_depth_m": open_end_depth_m,
              "repair": "volume" if use_volume else "surface"}
    description = (f"Imported lumen surface {path.name} ({units_used}); "
                   f"{'remeshed' if do_remesh else 'triangles kept'}; wall: one "
                   f"{wall_thickness_m * 1e3:g} mm prism per lumen triangle; repairs: "
                   f"{'; '.join(repairs) if repairs else 'none'}.")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = pathlib.Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        write_asset(tmp, name=name, description=description, vertices=lumen.vertices, faces=lumen.faces,
                    hulls=prisms, sites=sites_m, entry_position=entry_m, entry_direction=direction,
                    centerlines=cl, wall_thickness_m=wall_thickness_m, params=params,
                    extra={"open_end": open_end,
                           "counts": {"triangles": int(len(lumen.faces)), "hulls": int(len(prisms))},
                           "ostia": {k: json_rounded(p) for k, p in sorted(ostia.items())},
                           "import": {"repairs": repairs, "notes": notes}})
        report = validator(tmp) if validate else None
        if report is not None and not report.ok:
            raise MeshImportError(f"{path}: the imported asset fails validation: {report.problems[0]}"
                                  f"{f' (and {len(report.problems) - 1} more)' if len(report.problems) > 1 else ''}")
        if out.exists():
            shutil.rmtree(out)
        tmp.chmod(0o755)
        tmp.rename(out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return ImportReport(path=out, name=name, units=units_used, triangles=int(len(lumen.faces)),
                        hulls=int(len(prisms)), remeshed=do_remesh, repairs=repairs, notes=notes,
                        entry_direction=direction, path_length_m=lengths, seconds=time.perf_counter() - t0,
                        validation=report)
