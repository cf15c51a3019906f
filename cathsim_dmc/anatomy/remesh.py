"""Remeshing a lumen surface against its signed distance grid: mesh, refine, relax.

`level_set_surface` meshes the zero set of an `SDFGrid` with manifold3d's
`Manifold.level_set` (marching tetrahedra on a body-centred grid, grid points
snapped to the surface, so few slivers).

A uniform mesh of a few mm cannot follow the narrow branches and the rounded
carinas between neighbouring ostia (radius ~2 mm): there adjacent triangles
fold by up to ~90 deg, vertex normals lean ~50 deg off their faces and the
extruded wall thins out. So triangles next to sharp edges are split
(`refine_creases`: red-green refinement, new vertices projected onto the
surface) and the mesh is relaxed tangentially on the surface
(`relax_on_surface`). Short edges, slivers and folds are then removed by local
edits (`surface_cleanup`); the rim of a plane cut is made regular and capped by
`rim`.

Every step keeps each triangle facing along the surface normal (the SDF
gradient) and is deterministic. Vertices in `frozen` (the open-end band) are
never moved.
"""

from __future__ import annotations

import manifold3d
import numpy as np

from cathsim_dmc.anatomy.sdf import FAR_M, SDFGrid
from cathsim_dmc.anatomy.surface_cleanup import faces_follow_surface, folded_faces
from cathsim_dmc.anatomy.triangles import canonical_order, edge_faces, face_normals, unique_edges, vertex_normals


def level_set_surface(
    grid: SDFGrid, lo: np.ndarray, hi: np.ndarray, edge_m: float, tolerance_m: float | None = None
) -> manifold3d.Manifold:
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
    flat = (-vals).ravel().tolist()  # level_set wants positive inside
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


def refine_creases(v, f, grid: SDFGrid, max_dihedral_deg: float, levels: int, y_min: float, frozen=None):
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


def refine_sagging(v, f, grid: SDFGrid, local_radius, max_sag: float, levels: int, y_min: float, frozen=None):
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
        probes = np.stack(
            [
                tri.mean(axis=1),
                0.5 * (tri[:, 0] + tri[:, 1]),
                0.5 * (tri[:, 1] + tri[:, 2]),
                0.5 * (tri[:, 2] + tri[:, 0]),
            ],
            axis=1,
        ).reshape(-1, 3)
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
    if frozen is not None:  # callable: vertices -> bool mask of vertices to leave alone
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
    m = mid_id[face_edges]  # (F, 3): midpoint of edge c (f[c] -> f[c+1]) or -1
    ns = (m >= 0).sum(axis=1)
    out = [f[ns == 0]]
    r = ns == 3
    a, b, c = f[r, 0], f[r, 1], f[r, 2]
    mab, mbc, mca = m[r, 0], m[r, 1], m[r, 2]
    out += [np.stack(t, axis=1) for t in ((a, mab, mca), (mab, b, mbc), (mca, mbc, c), (mab, mbc, mca))]
    g = ns == 1
    k = np.argmax(m[g] >= 0, axis=1)  # which edge is split
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
            target = v[move]  # first just project onto the surface
        else:
            n = vertex_normals(v, f)
            centroid = np.stack([np.bincount(src, v[dst, k], minlength=len(v)) for k in range(3)], 1)
            d = centroid / deg[:, None] - v
            d -= np.sum(d * n, axis=1, keepdims=True) * n
            target = v[move] + 0.5 * d[move]
        candidate = v.copy()
        candidate[move] = grid.project_onto_surface(target)
        if not faces_follow_surface(candidate, f, grid):
            break  # a triangle would fold: keep the last good state
        v = candidate
    return v
