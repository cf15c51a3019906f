"""Steps 5-6 of a mesh import: centerlines from the entry to each site through the lumen
voxels, and the entry direction estimated from the lumen (see `importer`)."""

from __future__ import annotations

from typing import Mapping

import numpy as np
from scipy import ndimage, sparse, spatial
from scipy.sparse import csgraph

from cathsim_dmc.anatomy.import_error import MeshImportError
from cathsim_dmc.anatomy.polyline import arclength, resample_polyline
from cathsim_dmc.anatomy.sdf import SDFGrid, signed_distance
from cathsim_dmc.anatomy.validate import PROBE_RADIUS_M

_OFFSETS = np.array([o for o in np.ndindex(3, 3, 3) if o != (1, 1, 1)]) - 1
_OFFSETS = _OFFSETS[[tuple(o) > (0, 0, 0) for o in _OFFSETS]]  # 13 of the 26 neighbours


def _grid_graph(grid: SDFGrid, clearance: float, power: int = 2):
    """Sparse graph over grid nodes at least `clearance` inside the lumen; weights length / depth^power
    (power=0: plain lengths)."""
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
        w.append(length * (grid.spacing / dm) ** power if power else np.full(len(a), length))
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
            raise MeshImportError(
                f"{what} lies where the lumen is narrower than the {2 * probe * 1e3:.1f} mm wire probe"
            )
        return int(i)

    src = node_near(entry, "entry")
    dist, pred = csgraph.dijkstra(graph, directed=False, indices=src, return_predecessors=True)
    out = {}
    for k, site in sites.items():
        dst = node_near(site, f"site {k}")
        if not np.isfinite(dist[dst]):
            raise MeshImportError(
                f"site {k} cannot be reached from the entry through lumen at least {2 * probe * 1e3:.1f} mm wide"
            )
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
    sub = grid.values[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
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
