"""The rim where a plane cuts a lumen open (the wire's way in): `clean_rim` makes the rim
triangles regular and `close_cap` closes the rim with a flat fan."""

from __future__ import annotations

import numpy as np

from cathsim_dmc.anatomy.triangles import (
    boundary_edges,
    boundary_loops,
    drop_unused_vertices,
    face_normals,
    fan_triangles,
    unique_edges,
)


def clean_rim(v, f, axis_xz, y_cut, edge, iterations=20, radius=None):
    """Relax the triangles the plane cut leaves at the rim of the open end.

    Cutting triangles close to their vertices leaves slivers along the rim. Near
    the open end the descending aorta is a straight tube along +y, so vertices
    can slide over it in cylindrical coordinates (angle, height) without
    leaving the surface: a few rounds of Laplacian smoothing in those
    coordinates (rim vertices slide only along the rim, the others within a
    band of a few edges above it) make the rim triangles regular. Rim edges far
    shorter than the others are first collapsed into their midpoint.
    """
    v, f = _collapse_short_rim_edges(v.copy(), f.copy(), y_cut, 0.35 * edge)
    rim_e = boundary_edges(f)
    rim = np.unique(rim_e)
    in_reach = v[:, 1] < y_cut + 2.5 * edge
    if radius is not None:  # only around the open end (imported meshes may reach below it elsewhere)
        in_reach &= np.hypot(v[:, 0] - axis_xz[0], v[:, 2] - axis_xz[1]) < radius
    band = np.nonzero(in_reach)[0]
    inner = np.setdiff1d(band, rim)
    e = unique_edges(f)
    e = np.concatenate([e, e[:, ::-1]])  # both directions
    e_in = e[np.isin(e[:, 0], inner)]
    e_rim = np.concatenate([rim_e, rim_e[:, ::-1]])  # rim vertices: neighbours along the rim
    dx, dz = v[:, 0] - axis_xz[0], v[:, 2] - axis_xz[1]
    rho = np.hypot(dx, dz)
    theta = np.arctan2(dz, dx)
    y = v[:, 1].copy()
    wrap = lambda a: (a + np.pi) % (2 * np.pi) - np.pi
    moved = np.union1d(rim, inner)
    in_band = np.any(np.isin(f, moved), axis=1)

    def place():
        out = v.copy()
        out[moved, 0] = axis_xz[0] + rho[moved] * np.cos(theta[moved])
        out[moved, 2] = axis_xz[1] + rho[moved] * np.sin(theta[moved])
        out[moved, 1] = y[moved]
        return out

    def facing_out(vv):
        """Band faces must keep facing away from the tube axis."""
        fb = f[in_band]
        c = vv[fb].mean(axis=1)
        radial = np.stack([c[:, 0] - axis_xz[0], np.zeros(len(c)), c[:, 2] - axis_xz[1]], axis=1)
        radial /= np.linalg.norm(radial, axis=1, keepdims=True)
        return np.all(np.sum(face_normals(vv, fb) * radial, axis=1) > 0.2)

    best = v
    for _ in range(iterations):
        for edges, move_y in ((e_rim, False), (e_in, True)):
            src, dst = edges[:, 0], edges[:, 1]
            deg = np.maximum(np.bincount(src, minlength=len(v)), 1).astype(float)
            idx = np.unique(src)
            dth = np.bincount(src, wrap(theta[dst] - theta[src]), minlength=len(v))
            theta[idx] += 0.5 * dth[idx] / deg[idx]
            if move_y:
                dy = np.bincount(src, y[dst] - y[src], minlength=len(v))
                y[idx] += 0.5 * dy[idx] / deg[idx]
        candidate = place()
        if not facing_out(candidate):
            break  # keep the last state that had no folded triangle
        best = candidate
    return best, f


def _collapse_short_rim_edges(v, f, y_cut, tol):
    """Merge the two ends of each rim edge shorter than `tol` into their midpoint."""
    while True:
        rim_e = boundary_edges(f)
        length = np.linalg.norm(v[rim_e[:, 0]] - v[rim_e[:, 1]], axis=1)
        for i in np.argsort(length, kind="stable"):
            if length[i] >= tol:
                return v, f
            a, b = (int(x) for x in rim_e[i])
            has_a, has_b = np.any(f == a, axis=1), np.any(f == b, axis=1)
            shared = has_a & has_b
            nb = lambda x: set(f[np.any(f == x, axis=1)].ravel().tolist()) - {x}
            if nb(a) & nb(b) != set(f[shared].ravel().tolist()) - {a, b}:
                continue  # merging would pinch the surface
            v[a] = 0.5 * (v[a] + v[b])
            v[a, 1] = y_cut
            f = f[~shared]
            f[f == b] = a
            v, f = drop_unused_vertices(v, f)
            break
        else:
            return v, f


def close_cap(v, f, y_cut):
    """Close the one planar rim (in the plane y = `y_cut`) with a fan of triangles around its centroid."""
    loops = boundary_loops(f)
    if loops is None:
        raise RuntimeError("Open-end rim is not a simple loop.")
    if len(loops) != 1:
        raise RuntimeError("Open end has more than one rim loop." if loops else "Open end has no rim.")
    loop = loops[0]
    ctr = v[loop].mean(axis=0)
    ctr[1] = y_cut
    return np.concatenate([v, ctr[None]]), np.concatenate([f, fan_triangles(loop, len(v))])
