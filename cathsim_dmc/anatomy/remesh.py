"""Remeshing a lumen surface against its signed distance grid: mesh, refine, relax, clean.

`level_set_surface` meshes the zero set of an `SDFGrid` with manifold3d's
`Manifold.level_set` (marching tetrahedra on a body-centred grid, grid points
snapped to the surface, so few slivers).

A uniform mesh of a few mm cannot follow the narrow branches and the rounded
carinas between neighbouring ostia (radius ~2 mm): there adjacent triangles
fold by up to ~90 deg, vertex normals lean ~50 deg off their faces and the
extruded wall thins out. So triangles next to sharp edges are split
(`refine_creases`: red-green refinement, new vertices projected onto the
surface) and the mesh is relaxed tangentially on the surface
(`relax_on_surface`); short edges and sliver triangles are collapsed or
flipped (`collapse_short_edges`, `fix_slivers`).

Where a plane cuts the vessel open (the wire's way in), `clean_rim` makes the
rim triangles regular and `close_cap` closes the rim with a flat fan.

Every step keeps each triangle facing along the surface normal (the SDF
gradient) and is deterministic. Vertices in `frozen` (the open-end band) are
never moved.
"""

from __future__ import annotations

import manifold3d
import numpy as np

from cathsim_dmc.anatomy.sdf import FAR_M, SDFGrid
from cathsim_dmc.anatomy.triangles import (boundary_edges, boundary_loops, canonical_order, corner_angles_rad,
                                           drop_unused_vertices, edge_faces, face_normals, fan_triangles,
                                           unique_edges, vertex_normals)


def level_set_surface(grid: SDFGrid, lo: np.ndarray, hi: np.ndarray, edge_m: float,
                      tolerance_m: float | None = None) -> manifold3d.Manifold:
    """Closed surface of the zero set of `grid` within the box `lo`-`hi`, meshed at `edge_m` edges.

    manifold3d samples the grid SDF (inside-positive) trilinearly, in Python.
    `tolerance_m`: every vertex is searched for along its grid edge until it lies
    within this distance of the zero set. None keeps manifold3d's default, the
    linear interpolation between the edge's two grid points (about `edge_m`
    apart): where the field is far from linear over that span (a tube not much
    wider than `edge_m`, where the edge runs past the tube's axis) the vertex
    then lands millimetres inside the lumen.
    """
    vals = grid.values
    nx, ny, nz = vals.shape
    flat = (-vals).ravel().tolist()          # level_set wants positive inside
    ox, oy, oz = (float(c) for c in grid.origin)
    inv = 1.0 / grid.spacing
    sy, sx = nz, ny * nz

    def f(x, y, z):
        gx, gy, gz = (x - ox) * inv, (y - oy) * inv, (z - oz) * inv
        i, j, k = int(gx), int(gy), int(gz)
        if i < 0 or j < 0 or k < 0 or i >= nx - 1 or j >= ny - 1 or k >= nz - 1:
            return -FAR_M
        fx, fy, fz = gx - i, gy - j, gz - k
        b = i * sx + j * sy + k
        c00 = flat[b] * (1 - fz) + flat[b + 1] * fz
        c01 = flat[b + sy] * (1 - fz) + flat[b + sy + 1] * fz
        c10 = flat[b + sx] * (1 - fz) + flat[b + sx + 1] * fz
        c11 = flat[b + sx + sy] * (1 - fz) + flat[b + sx + sy + 1] * fz
        return (c00 * (1 - fy) + c01 * fy) * (1 - fx) + (c10 * (1 - fy) + c11 * fy) * fx

    box = [float(c) for c in lo] + [float(c) for c in hi]
    tolerance = -1.0 if tolerance_m is None else float(tolerance_m)
    return manifold3d.Manifold.level_set(f, box, edge_m, 0.0, tolerance)


def manifold_arrays(surface: manifold3d.Manifold):
    """Vertices (float64, m) and faces of a manifold3d surface, in canonical order: the mesher may
    run in parallel, so the order is fixed before anything depends on it."""
    mesh = surface.to_mesh64()
    v = np.array(mesh.vert_properties, dtype=np.float64)[:, :3].copy()
    f = np.array(mesh.tri_verts, dtype=np.int64)
    return canonical_order(v, f)


def refine_creases(v, f, grid: SDFGrid, max_dihedral_deg: float, levels: int, y_min: float,
                   frozen=None):
    """Split triangles around creases sharper than `max_dihedral_deg` (red-green refinement).

    Uniform meshing at ~3 mm leaves narrow branches with 8-9 facets and folds
    the carinas between ostia into single sharp edges. Faces next to such edges
    are split 1-to-4 (neighbours left with one split edge are bisected, those
    with two are split too) and every new vertex is projected onto the lumen
    surface; repeated `levels` times. Faces below `y_min` (the open end) are
    left alone.
    """
    for _ in range(levels):
        edges, face_edges, faces_of_edge = edge_faces(f)
        fn = face_normals(v, f)
        inner = faces_of_edge[:, 1] >= 0
        cosang = np.ones(len(edges))
        cosang[inner] = np.sum(fn[faces_of_edge[inner, 0]] * fn[faces_of_edge[inner, 1]], axis=1)
        sharp = cosang < np.cos(np.radians(max_dihedral_deg))
        marked = np.zeros(len(f), dtype=bool)
        marked[faces_of_edge[sharp].ravel()] = True
        marked = _unfrozen(v, f, marked, y_min, frozen)
        if not marked.any():
            break
        v, f = split_faces(v, f, grid, marked)
    return v, f


def refine_sagging(v, f, grid: SDFGrid, local_radius, max_sag: float, levels: int, y_min: float,
                   frozen=None):
    """Split triangles that cut into the lumen by more than `max_sag` of its local radius.

    A flat triangle with its corners on the surface of a tube of radius r and
    spanning an angle a of its circumference passes r (1 - cos(a / 2)) inside it
    (at 7 mm edges on a 3.5 mm-radius branch: about half the radius), and the
    crease test does not always catch it. Faces whose centroid or an edge's
    midpoint lies deeper than `max_sag` x `local_radius(that point)` inside the
    surface are split as in `refine_creases`, up to `levels` times. Faces below
    `y_min` are left alone, and so are folded faces. A level that would fold more
    faces than there were is not applied and ends the refinement: where the mesher
    left a branch broken (the final check rejects the surface and it is meshed
    again with shorter edges), splitting multiplied the folds (3 -> 38, 33 -> 117)
    and the sliver clean-up of the doomed surface took up to a minute.
    """
    for _ in range(levels):
        tri = v[f]
        probes = np.stack([tri.mean(axis=1), 0.5 * (tri[:, 0] + tri[:, 1]), 0.5 * (tri[:, 1] + tri[:, 2]),
                           0.5 * (tri[:, 2] + tri[:, 0])], axis=1).reshape(-1, 3)
        marked = np.any((-grid(probes) > max_sag * local_radius(probes)).reshape(-1, 4), axis=1)
        folded = folded_faces(v, f, grid)
        marked[folded] = False
        marked = _unfrozen(v, f, marked, y_min, frozen)
        if not marked.any():
            break
        v2, f2 = split_faces(v, f, grid, marked)
        if len(folded_faces(v2, f2, grid)) > len(folded):
            break
        v, f = v2, f2
    return v, f


def _unfrozen(v, f, marked, y_min, frozen):
    """`marked` without the faces below `y_min` or touching a `frozen` vertex."""
    marked = marked & (v[f].min(axis=1)[:, 1] > y_min)
    if frozen is not None:        # callable: vertices -> bool mask of vertices to leave alone
        marked &= ~np.any(frozen(v)[f], axis=1)
    return marked


def split_faces(v, f, grid: SDFGrid, marked):
    """Split the `marked` faces 1-to-4, red-green (a neighbour left with one split edge is
    bisected, one with two is split 1-to-4 too); every new vertex is projected onto the surface."""
    edges, face_edges, faces_of_edge = edge_faces(f)
    inner = faces_of_edge[:, 1] >= 0
    split = np.zeros(len(edges), dtype=bool)
    split[face_edges[marked].ravel()] = True
    while True:
        two = split[face_edges].sum(axis=1) == 2
        if not two.any():
            break
        split[face_edges[two].ravel()] = True
    if np.any(split & ~inner):
        raise RuntimeError("Refinement reached the open end.")
    mid_id = -np.ones(len(edges), dtype=np.int64)
    mid_id[split] = len(v) + np.arange(split.sum())
    mids = grid.project_onto_surface(0.5 * (v[edges[split, 0]] + v[edges[split, 1]]))
    v = np.concatenate([v, mids])
    m = mid_id[face_edges]            # (F, 3): midpoint of edge c (f[c] -> f[c+1]) or -1
    ns = (m >= 0).sum(axis=1)
    out = [f[ns == 0]]
    r = ns == 3
    a, b, c = f[r, 0], f[r, 1], f[r, 2]
    mab, mbc, mca = m[r, 0], m[r, 1], m[r, 2]
    out += [np.stack(t, axis=1) for t in ((a, mab, mca), (mab, b, mbc), (mca, mbc, c), (mab, mbc, mca))]
    g = ns == 1
    k = np.argmax(m[g] >= 0, axis=1)            # which edge is split
    rows = np.nonzero(g)[0]
    p0 = f[rows, k]
    p1 = f[rows, (k + 1) % 3]
    p2 = f[rows, (k + 2) % 3]
    mm = m[rows, k]
    out += [np.stack((p0, mm, p2), axis=1), np.stack((mm, p1, p2), axis=1)]
    return v, np.concatenate(out)


def relax_on_surface(v, f, grid: SDFGrid, frozen: np.ndarray, iterations: int = 4):
    """Tangential Laplacian relaxation with re-projection onto the lumen surface.

    Evens out the triangles refinement leaves behind (bisected neighbours) and
    puts every vertex on the surface; `frozen` vertices (the open-end rim band)
    do not move.
    """
    e = unique_edges(f)
    src = np.concatenate([e[:, 0], e[:, 1]])
    dst = np.concatenate([e[:, 1], e[:, 0]])
    deg = np.bincount(src, minlength=len(v)).astype(float)
    move = ~frozen
    for it in range(iterations + 1):
        if it == 0:
            target = v[move]            # first just project onto the surface
        else:
            n = vertex_normals(v, f)
            centroid = np.stack([np.bincount(src, v[dst, k], minlength=len(v)) for k in range(3)], 1)
            d = centroid / deg[:, None] - v
            d -= np.sum(d * n, axis=1, keepdims=True) * n
            target = v[move] + 0.5 * d[move]
        candidate = v.copy()
        candidate[move] = grid.project_onto_surface(target)
        if not faces_follow_surface(candidate, f, grid):
            break        # a triangle would fold: keep the last good state
        v = candidate
    return v


SLIVER_ANGLE_DEG = 12.0
# Edges of the raw level-set mesh shorter than this fraction of the requested
# edge length are collapsed. Measured: healthy meshes have no edge below
# ~0.2x; in about one build of six the mesher snaps a cluster of vertices
# together at the closed end of a narrow branch (edges of 0.005-0.03 mm), and
# refining around that cluster folds triangles over.
SHORT_EDGE_FRACTION = 0.1


def collapse_short_edges(v, f, grid: SDFGrid, min_length: float, frozen: np.ndarray | None = None,
                         max_rounds: int = 1000):
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


def fix_slivers(v, f, grid: SDFGrid, frozen: np.ndarray | None = None, min_angle_deg: float = SLIVER_ANGLE_DEG,
                max_rounds: int = 500):
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
            break            # smoothing did not help either: report what is left
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
        return False        # the flipped edge exists already
    # Keep orientation: face 0 goes a -> b (or b -> a); build the two new faces accordingly.
    f0 = list(f[has[0]])
    i = f0.index(a)
    forward = f0[(i + 1) % 3] == b          # face 0 = (a, b, c) in order
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
        return None          # link condition: the collapse would pinch the surface
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
    if radius is not None:      # only around the open end (imported meshes may reach below it elsewhere)
        in_reach &= np.hypot(v[:, 0] - axis_xz[0], v[:, 2] - axis_xz[1]) < radius
    band = np.nonzero(in_reach)[0]
    inner = np.setdiff1d(band, rim)
    e = unique_edges(f)
    e = np.concatenate([e, e[:, ::-1]])           # both directions
    e_in = e[np.isin(e[:, 0], inner)]
    e_rim = np.concatenate([rim_e, rim_e[:, ::-1]])   # rim vertices: neighbours along the rim
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
            break        # keep the last state that had no folded triangle
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
                continue   # merging would pinch the surface
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
