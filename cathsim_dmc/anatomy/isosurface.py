"""Closed triangle surface of the zero set of a sampled field, vectorised (marching tetrahedra).

`zero_surface(values, origin, spacing)` splits every grid cube that the zero set
crosses into six tetrahedra around its main diagonal (the same split in every
cube, so neighbouring cubes agree on their shared faces) and puts one or two
triangles in each crossed tetrahedron. Vertices on shared grid edges are shared,
so a field that is positive on the grid border gives a closed 2-manifold,
oriented outward (towards positive values).

It is fast (NumPy only, no per-sample Python) but leaves many thin triangles: the
importer uses it to turn a voxel volume into a surface it can measure against,
and the tests use it to make segmentation-style meshes. The lumen itself is
meshed by `remesh.level_set_surface`.
"""

from __future__ import annotations

import itertools

import numpy as np

_CORNERS = np.array(list(itertools.product((0, 1), repeat=3)))  # corner c = (dx, dy, dz)
_BIT = {tuple(c): i for i, c in enumerate(_CORNERS)}
# Six tetrahedra along the diagonal 000 -> 111, one per order of the three axes.
_TETS = np.array(
    [
        [
            _BIT[(0, 0, 0)],
            _BIT[tuple(np.eye(3, dtype=int)[a])],
            _BIT[tuple(np.eye(3, dtype=int)[a] + np.eye(3, dtype=int)[b])],
            _BIT[(1, 1, 1)],
        ]
        for a, b in itertools.permutations(range(3), 2)
    ]
)


def zero_surface(values: np.ndarray, origin, spacing: float) -> "tuple[np.ndarray, np.ndarray]":
    """(vertices (V, 3), faces (F, 3)) of the zero set of `values` (nx, ny, nz), negative inside.

    Grid node (i, j, k) sits at origin + spacing * (i, j, k). Values exactly zero
    count as slightly positive (moved off the node by 1e-9 spacings). The surface is closed where the field is positive
    on the grid border.
    """
    vals = np.asarray(values, dtype=np.float64)
    # A zero node would put several surface vertices on one point (zero-area triangles).
    vals = np.where(vals == 0, 1e-9 * spacing, vals)
    shape = np.array(vals.shape)
    neg = vals < 0
    # Cubes with corners on both sides of the zero set.
    any_neg = np.zeros(shape - 1, dtype=bool)
    all_neg = np.ones(shape - 1, dtype=bool)
    for dx, dy, dz in _CORNERS:
        c = neg[dx : shape[0] - 1 + dx, dy : shape[1] - 1 + dy, dz : shape[2] - 1 + dz]
        any_neg |= c
        all_neg &= c
    cubes = np.argwhere(any_neg & ~all_neg)
    if len(cubes) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    strides = np.array([shape[1] * shape[2], shape[2], 1])
    corner_ids = (cubes[:, None, :] + _CORNERS[None]) @ strides  # (C, 8) flat node ids
    tet_ids = corner_ids[:, _TETS].reshape(-1, 4)  # (6C, 4)
    flat = vals.ravel()
    pos = flat[tet_ids] >= 0
    n_pos = pos.sum(axis=1)
    tris = []
    # One positive or one negative corner: one triangle around that corner.
    for odd_count, odd_is_pos in ((1, True), (3, False)):
        sel = n_pos == odd_count
        t, p = tet_ids[sel], pos[sel]
        odd_mask = p if odd_is_pos else ~p
        odd = t[odd_mask]  # (n,)
        others = t[~odd_mask].reshape(-1, 3)
        tris.append(np.stack([np.stack([odd, others[:, k]], axis=1) for k in range(3)], axis=1))
    # Two and two: a quad, as two triangles.
    sel = n_pos == 2
    t, p = tet_ids[sel], pos[sel]
    pp = t[p].reshape(-1, 2)
    nn = t[~p].reshape(-1, 2)
    e = lambda a, b: np.stack([pp[:, a], nn[:, b]], axis=1)
    tris.append(np.stack([e(0, 0), e(0, 1), e(1, 1)], axis=1))
    tris.append(np.stack([e(0, 0), e(1, 1), e(1, 0)], axis=1))
    edges = np.concatenate(tris)  # (F, 3, 2) node pairs
    key = np.sort(edges, axis=2).reshape(-1, 2)
    uniq, inverse = np.unique(key, axis=0, return_inverse=True)
    faces = inverse.reshape(-1, 3)
    va, vb = flat[uniq[:, 0]], flat[uniq[:, 1]]
    w = np.clip(va / np.where(va == vb, 1.0, va - vb), 0.0, 1.0)[:, None]
    node_xyz = lambda ids: np.stack(np.unravel_index(ids, tuple(shape)), axis=1).astype(np.float64)
    verts = np.asarray(origin, dtype=np.float64) + spacing * ((1 - w) * node_xyz(uniq[:, 0]) + w * node_xyz(uniq[:, 1]))
    # Orient every triangle from the negative side to the positive side.
    ends = edges.reshape(-1, 2)
    first_pos = flat[ends[:, 0]] >= 0
    outward = (
        np.where(
            first_pos[:, None], node_xyz(ends[:, 0]) - node_xyz(ends[:, 1]), node_xyz(ends[:, 1]) - node_xyz(ends[:, 0])
        )
        .reshape(-1, 3, 3)
        .sum(axis=1)
    )
    # Judged on the edge midpoints: interpolated vertices can all but coincide.
    mid = 0.5 * (node_xyz(ends[:, 0]) + node_xyz(ends[:, 1])).reshape(-1, 3, 3)
    normal = np.cross(mid[:, 1] - mid[:, 0], mid[:, 2] - mid[:, 0])
    flip = np.sum(normal * outward, axis=1) < 0
    faces[flip] = faces[flip][:, ::-1]
    return verts, faces
