"""The vessel wall: one convex collision prism per lumen triangle.

Every non-cap lumen triangle is extruded outward along the unit vertex normals
(`Lumen.normals`) into a 6-point convex prism. Neighbouring prisms share their
side edges (same vertices, same normals), so the wall has no gaps, and every
prism starts on the lumen surface, so no piece intrudes into it.

Where two lumens run closer than the wall is thick (the septum between close ostia,
the carina of a common trunk), a full prism would reach into the neighbouring lumen.
`septum_widths` measures, along each vertex normal, how far out the lumen begins again,
and `thin_at_septa` ends the prisms there halfway across (each side's wall meets the
other's in the middle of the septum); elsewhere the offsets are left as they are.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
from scipy import spatial

from cathsim_dmc.anatomy.lumen import Lumen
from cathsim_dmc.anatomy.triangles import face_normals


def prism_offsets(lumen: Lumen, thickness: float, max_stretch: float = 1.6) -> np.ndarray:
    """(V,) how far each lumen vertex is extruded (m): `thickness`, lengthened where the vertex
    normal leans away from an adjacent face (see `extrude_prisms`)."""
    f = lumen.faces[~lumen.cap]
    v, n = lumen.vertices, lumen.normals
    fn = face_normals(v, f)
    lean = np.ones(len(v))
    for c in range(3):
        np.minimum.at(lean, f[:, c], np.sum(n[f[:, c]] * fn, axis=1))
    return thickness / np.clip(lean, 1.0 / max_stretch, 1.0)


def extrude_prisms(
    lumen: Lumen, thickness: float, max_stretch: float = 1.6, offsets: Optional[np.ndarray] = None
) -> np.ndarray:
    """(H, 6, 3) prisms: each wall triangle, then the same triangle offset outward (`thickness` in m).

    Every vertex moves along its unit vertex normal, so neighbouring prisms
    share their side edges. Where the normal leans away from an adjacent face
    (curved regions, e.g. the carinas between ostia), a plain offset of
    `thickness` would leave that face's prism thinner than `thickness` along its
    own normal; the offset is lengthened to thickness / cos(lean), capped at
    `max_stretch` x thickness, so the wall keeps its thickness everywhere.
    `offsets` (V,), when given, replaces those offsets (`thin_at_septa`).
    """
    f = lumen.faces[~lumen.cap]
    v, n = lumen.vertices, lumen.normals
    offset = prism_offsets(lumen, thickness, max_stretch) if offsets is None else offsets
    outer = v + offset[:, None] * n
    return np.concatenate([v[f], outer[f]], axis=1)


def septum_widths(lumen: Lumen, reach: np.ndarray) -> np.ndarray:
    """(V,) distance (m) along each wall vertex's outward normal to where the ray meets the lumen's
    wall again from outside (a neighbouring lumen across a septum); inf where that is farther than
    the vertex's `reach` (V,) or never. Exact ray-triangle intersection (Moeller-Trumbore) with the
    triangles within reach of each vertex."""
    v, n = lumen.vertices, lumen.normals
    f = lumen.faces[~lumen.cap]
    reach = np.broadcast_to(np.asarray(reach, dtype=np.float64), (len(v),))
    out = np.full(len(v), np.inf)
    used = np.unique(f)
    tri = v[f]
    centre = tri.mean(axis=1)
    size = np.max(np.linalg.norm(tri - centre[:, None], axis=2), axis=1)
    fn = face_normals(v, f)
    # The wall vertices within reach of each triangle (a radius per triangle: its size).
    lists = spatial.cKDTree(v[used]).query_ball_point(centre, float(reach[used].max()) + size)
    counts = np.array([len(c) for c in lists], dtype=np.int64)
    ti = np.repeat(np.arange(len(f)), counts)
    vi = used[np.fromiter((j for c in lists for j in c), dtype=np.int64, count=int(counts.sum()))]
    # Only triangles facing the ray (met from outside) and not touching the vertex itself.
    keep = (np.einsum("ij,ij->i", n[vi], fn[ti]) < 0) & ~np.any(f[ti] == vi[:, None], axis=1)
    vi, ti = vi[keep], ti[keep]
    for s in range(0, len(vi), 500_000):
        a, b = vi[s : s + 500_000], ti[s : s + 500_000]
        o, d = v[a], n[a]
        p0, p1, p2 = tri[b, 0], tri[b, 1], tri[b, 2]
        e1, e2 = p1 - p0, p2 - p0
        pv = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, pv)
        ok = np.abs(det) > 1e-18
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tv = o - p0
        u = np.einsum("ij,ij->i", tv, pv) * inv
        qv = np.cross(tv, e1)
        w = np.einsum("ij,ij->i", d, qv) * inv
        t = np.einsum("ij,ij->i", e2, qv) * inv
        hit = ok & (u >= 0) & (w >= 0) & (u + w <= 1) & (t > 1e-7) & (t <= reach[a])
        np.minimum.at(out, a[hit], t[hit])
    return out


def thin_at_septa(lumen: Lumen, offsets: np.ndarray) -> "tuple[np.ndarray, np.ndarray]":
    """(offsets, septum widths): each vertex whose normal meets the lumen again within its offset
    (`septum_widths`) extruded to half that width instead; the others keep theirs."""
    width = septum_widths(lumen, offsets)
    thin = width < offsets
    return np.where(thin, 0.5 * width, offsets), width
