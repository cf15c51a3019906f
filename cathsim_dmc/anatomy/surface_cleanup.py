"""Local edits that clean a surface meshed against its signed distance grid: collapse short
edges (`collapse_short_edges`), remove sliver triangles (`fix_slivers`) and undo folds
(`repair_folds`, `folded_faces`).

An edit is kept only if every triangle it touches still faces along the surface normal
(the SDF gradient, `faces_follow_surface`); every edit is deterministic. Vertices in
`frozen` (the open-end band) are never moved or removed.
"""

from __future__ import annotations

import numpy as np

from cathsim_dmc.anatomy.sdf import SDFGrid
from cathsim_dmc.anatomy.triangles import corner_angles_rad, face_normals, unique_edges

SLIVER_ANGLE_DEG = 12.0
# Edges of the raw level-set mesh shorter than this fraction of the requested
# edge length are collapsed. Measured: healthy meshes have no edge below
# ~0.2x; in about one build of six the mesher snaps a cluster of vertices
# together at the closed end of a narrow branch (edges of 0.005-0.03 mm), and
# refining around that cluster folds triangles over.
SHORT_EDGE_FRACTION = 0.1


def collapse_short_edges(
    v, f, grid: SDFGrid, min_length: float, frozen: np.ndarray | None = None, max_rounds: int = 1000
):
    """Collapse every edge shorter than `min_length` (shortest first) into its projected midpoint.

    A collapse is skipped if it would pinch the surface (link condition) or turn
    a triangle against the surface normal. Meshes without short edges are
    returned unchanged.
    """
    frozen = np.zeros(len(v), dtype=bool) if frozen is None else np.asarray(frozen, dtype=bool).copy()
    accept = lambda vv, touched, before: len(touched) == 0 or faces_follow_surface(vv, touched, grid, min_cos=0.2)
    skip = set()
    for _ in range(max_rounds):
        e = unique_edges(f)
        length = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
        short = np.nonzero((length < min_length) & ~np.any(frozen[e], axis=1))[0]
        short = [i for i in short[np.argsort(length[short], kind="stable")] if tuple(e[i]) not in skip]
        if not short:
            break
        for i in short:
            a, b = (int(x) for x in e[i])
            res = _try_collapse(v, f, a, b, grid, frozen, None, accept=accept)
            if res is not None:
                v, f, frozen = res
                skip = set()
                break
            skip.add((a, b))
        else:
            break
    return v, f


def fix_slivers(
    v,
    f,
    grid: SDFGrid,
    frozen: np.ndarray | None = None,
    min_angle_deg: float = SLIVER_ANGLE_DEG,
    max_rounds: int = 500,
):
    """Remove triangles with an angle below `min_angle_deg` (their prisms would be degenerate).

    The mesher and the relaxation occasionally pile a few vertices together
    (e.g. at the pole of a branch's closed end). A needle (one short edge) is
    collapsed to its midpoint projected onto the surface; a cap (one angle near
    180 deg) has its longest edge flipped. A change is kept only if every
    touched triangle stays aligned with the surface and the worst angle around
    it improves. Meshes without slivers are returned unchanged. Vertices in
    `frozen` are never moved or removed.
    """
    frozen = np.zeros(len(v), dtype=bool) if frozen is None else np.asarray(frozen, dtype=bool).copy()
    v, f = v.copy(), f.copy()

    def aligned(vv, ff):
        return len(ff) == 0 or faces_follow_surface(vv, ff, grid, min_cos=0.3)

    for _ in range(max_rounds):
        ang = _angles_deg(v, f)
        bad = np.nonzero(ang.min(axis=1) < min_angle_deg)[0]
        bad = bad[~np.any(frozen[f[bad]], axis=1)]
        if not len(bad):
            break
        changed = False
        for t in bad[np.argsort(ang[bad].min(axis=1), kind="stable")]:
            tri = f[t]
            big = int(np.argmax(ang[t]))
            if ang[t, big] > 120.0:
                # Cap: flip the edge opposite the big angle.
                a, b = tri[(big + 1) % 3], tri[(big + 2) % 3]
                changed = _try_flip(v, f, a, b, aligned)
            else:
                # Needle: collapse the shortest edge (opposite the smallest angle).
                small = int(np.argmin(ang[t]))
                a, b = tri[(small + 1) % 3], tri[(small + 2) % 3]
                res = _try_collapse(v, f, a, b, grid, frozen, aligned)
                if res is not None:
                    v, f, frozen = res
                    changed = True
            if changed:
                break
        if not changed:
            break
    return v, f


def folded_faces(v, f, grid: SDFGrid, min_cos: float = 0.0) -> np.ndarray:
    """Indices of the faces turned against (or across) the surface normal at their centroid."""
    n = grid.surface_normal(v[f].mean(axis=1))
    return np.nonzero(np.sum(face_normals(v, f) * n, axis=1) <= min_cos)[0]


def repair_folds(v, f, grid: SDFGrid, frozen: np.ndarray | None = None, max_rounds: int = 200):
    """Local repair of folded triangles: collapse an edge of each, else even out its neighbourhood.

    A fold (a triangle facing against the SDF gradient) is where the mesh could not
    follow a tight curve: a jagged branch tip, an ostium's ridge, a side stump.
    Each folded triangle's edges are tried shortest first (a collapse is kept if
    every touched triangle then faces along the surface); if none can go, the
    vertices around it are moved to the mean of their neighbours and projected
    back onto the surface. Returns (v, f, folds left). Vertices in `frozen` never move.
    """
    frozen = np.zeros(len(v), dtype=bool) if frozen is None else np.asarray(frozen, dtype=bool).copy()
    accept = lambda vv, touched, before: len(touched) == 0 or faces_follow_surface(vv, touched, grid, min_cos=0.1)
    smoothed = set()
    for _ in range(max_rounds):
        bad = folded_faces(v, f, grid, 0.05)
        bad = bad[~np.any(frozen[f[bad]], axis=1)]
        if not len(bad):
            break
        t = int(bad[0])
        tri = f[t]
        lengths = [np.linalg.norm(v[tri[k]] - v[tri[(k + 1) % 3]]) for k in range(3)]
        done = False
        for k in np.argsort(lengths):
            res = _try_collapse(v, f, int(tri[k]), int(tri[(k + 1) % 3]), grid, frozen, None, accept=accept)
            if res is not None:
                v, f, frozen = res
                done = True
                break
        if done:
            continue
        key = tuple(sorted(int(x) for x in tri))
        if key in smoothed:
            break  # smoothing did not help either: report what is left
        smoothed.add(key)
        ring = np.unique(f[np.any(np.isin(f, tri), axis=1)])
        ring = ring[~frozen[ring]]
        for _ in range(3):
            for i in ring:
                nb = np.unique(f[np.any(f == i, axis=1)])
                nb = nb[nb != i]
                v[i] = grid.project_onto_surface(v[nb].mean(axis=0)[None])[0]
    bad = folded_faces(v, f, grid, 0.0)
    return v, f, int(np.sum(~np.any(frozen[f[bad]], axis=1)))


def _angles_deg(v, f):
    """(F, 3) corner angles in degrees; a zero-length edge's corners count as 90 deg, its third as ~0."""
    return np.degrees(corner_angles_rad(v, f, nan_if_degenerate=False))


def _better(after: np.ndarray, before: np.ndarray) -> bool:
    """Fewer sliver angles, or as many and a larger smallest angle."""
    na, nb = int(np.sum(after < SLIVER_ANGLE_DEG)), int(np.sum(before < SLIVER_ANGLE_DEG))
    return na < nb or (na == nb and after.min() > before.min())


def _try_flip(v, f, a, b, aligned) -> bool:
    """Flip edge (a, b) in place if that improves the worst angle of its two faces."""
    has = np.nonzero(np.sum((f == a) | (f == b), axis=1) == 2)[0]
    if len(has) != 2:
        return False
    opp = [int(np.setdiff1d(f[i], [a, b])[0]) for i in has]
    c, d = opp
    if c == d or np.any(np.sum((f == c) | (f == d), axis=1) == 2):
        return False  # the flipped edge exists already
    # Keep orientation: face 0 goes a -> b (or b -> a); build the two new faces accordingly.
    f0 = list(f[has[0]])
    i = f0.index(a)
    forward = f0[(i + 1) % 3] == b  # face 0 = (a, b, c) in order
    new = np.array([[a, d, c], [b, c, d]]) if forward else np.array([[a, c, d], [b, d, c]])
    if not _better(_angles_deg(v, new), _angles_deg(v, f[has])) or not aligned(v, new):
        return False
    f[has] = new
    return True


def _try_collapse(v, f, a, b, grid, frozen, aligned, accept=None):
    """Collapse edge (a, b) into its projected midpoint; returns new (v, f, frozen) or None.

    Default acceptance: the touched triangles stay aligned with the surface
    and their angles improve (`_better`); `accept(v, touched_faces, before)`
    replaces that test.
    """
    if frozen[a] or frozen[b]:
        return None
    shared = np.nonzero(np.sum((f == a) | (f == b), axis=1) == 2)[0]
    if len(shared) != 2:
        return None
    nb = lambda x: set(f[np.any(f == x, axis=1)].ravel().tolist()) - {x}
    if nb(a) & nb(b) != set(f[shared].ravel().tolist()) - {a, b}:
        return None  # link condition: the collapse would pinch the surface
    ring = np.nonzero(np.any((f == a) | (f == b), axis=1))[0]
    ring = np.setdiff1d(ring, shared)
    m = grid.project_onto_surface(0.5 * (v[a] + v[b])[None])[0]
    v2 = v.copy()
    v2[a] = m
    f2 = f.copy()
    f2[f2 == b] = a
    touched = f2[ring]
    if accept is not None:
        if not accept(v2, touched, None):
            return None
    else:
        before = _angles_deg(v, f[np.concatenate([ring, shared])])
        if not _better(_angles_deg(v2, touched), before) or not aligned(v2, touched):
            return None
    f2 = np.delete(f2, shared, axis=0)
    # Drop vertex b (renumber).
    keep = np.ones(len(v2), dtype=bool)
    keep[b] = False
    remap = np.cumsum(keep) - 1
    return v2[keep], remap[f2], frozen[keep]


def faces_follow_surface(v, f, grid: SDFGrid, min_cos: float = 0.2) -> bool:
    """No face turned against the surface normal (the SDF gradient) at its centroid."""
    n = grid.surface_normal(v[f].mean(axis=1))
    return bool(np.all(np.sum(face_normals(v, f) * n, axis=1) > min_cos))
