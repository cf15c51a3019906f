"""Triangle-mesh primitives shared by the lumen builders, the importer and the validation.

A mesh is (V, 3) float64 vertices (metres) and (F, 3) int64 faces, counter-clockwise
seen from outside; edge c of a face runs from its vertex c to vertex c + 1.
"""

from __future__ import annotations

import numpy as np


def directed_edges(faces: np.ndarray) -> np.ndarray:
    """(3F, 2) every face's edges as (from, to): all edges 0, then all edges 1, then all edges 2."""
    return np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])


def unique_edges(faces: np.ndarray) -> np.ndarray:
    """(E, 2) undirected edges (smaller index first), sorted."""
    return np.unique(np.sort(directed_edges(faces), axis=1), axis=0)


def edge_faces(faces: np.ndarray):
    """(unique edges (E, 2), each face's 3 edge ids (F, 3), each edge's two faces (E, 2), -1 if open)."""
    n = len(faces)
    edges, inv = np.unique(np.sort(directed_edges(faces), axis=1), axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    face_edges = inv.reshape(3, n).T
    order = np.argsort(inv, kind="stable")
    count = np.bincount(inv, minlength=len(edges))
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    both = np.full((len(edges), 2), -1)
    both[:, 0] = order[first] % n
    two = count == 2
    both[two, 1] = order[first[two] + 1] % n
    return edges, face_edges, both


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """Directed edges whose reverse is missing: the rims of the mesh's holes."""
    e = directed_edges(faces)
    key = e[:, 0] * (faces.max() + 1) + e[:, 1]
    rkey = e[:, 1] * (faces.max() + 1) + e[:, 0]
    return e[~np.isin(key, rkey)]


def boundary_loops(faces: np.ndarray):
    """The holes' rims as closed loops of vertex ids (in edge order, each starting at its smallest
    id, loops by their first id), or None if two rims touch or a rim does not close."""
    b = boundary_edges(faces)
    if len(b) == 0:
        return []
    nxt = {}
    for a, c in b:
        if int(a) in nxt:
            return None  # a vertex where two holes touch
        nxt[int(a)] = int(c)
    loops, seen = [], set()
    for start in sorted(nxt):
        if start in seen:
            continue
        loop = [start]
        seen.add(start)
        while nxt.get(loop[-1], start) != start:
            loop.append(nxt[loop[-1]])
            if loop[-1] in seen or len(loop) > len(nxt):
                return None
            seen.add(loop[-1])
        if loop[-1] not in nxt:
            return None
        loops.append(loop)
    return loops


def fan_triangles(loop, apex: int) -> np.ndarray:
    """Triangles closing the rim `loop` (traversed from loop[i] to loop[i + 1] by the mesh's own
    faces) around the vertex `apex`, oriented like the mesh."""
    return np.array([[apex, loop[(i + 1) % len(loop)], loop[i]] for i in range(len(loop))])


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) unit face normals; (0, 0, 0) for a face without area."""
    n = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def corner_angles_rad(vertices: np.ndarray, faces: np.ndarray, nan_if_degenerate: bool = True) -> np.ndarray:
    """(F, 3) interior angle at each face's corner c, in radians.

    A corner on a zero-length edge has no angle: NaN, or pi / 2 if not `nan_if_degenerate`
    (so that a comparison still sees the face's other, near-zero angle).
    """
    tri = vertices[faces]
    out = []
    for c in range(3):
        e1 = tri[:, (c + 1) % 3] - tri[:, c]
        e2 = tri[:, (c + 2) % 3] - tri[:, c]
        lengths = np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):  # the NaN of a degenerate corner is meant
            cosang = np.sum(e1 * e2, 1) / (lengths if nan_if_degenerate else np.maximum(lengths, 1e-300))
        out.append(np.arccos(np.clip(cosang, -1.0, 1.0)))
    return np.stack(out, axis=1)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray, use: np.ndarray | None = None) -> np.ndarray:
    """Angle-weighted unit vertex normals from the faces selected by `use`.

    A vertex of a face without area gets no normal, (0, 0, 0): the face's NaN normal spoils
    the vertex's sum. The shipped meshes were built with this rule, so it stays.
    """
    f = faces if use is None else faces[use]
    tri = vertices[f]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    with np.errstate(invalid="ignore", divide="ignore"):  # the NaN of a face without area is meant (above)
        fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    ang = corner_angles_rad(vertices, f)
    acc = np.zeros_like(vertices)
    for c in range(3):
        np.add.at(acc, f[:, c], fn * ang[:, c, None])
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    return np.divide(acc, norm, out=np.zeros_like(acc), where=norm > 0)


def triangle_quality(vertices: np.ndarray, faces: np.ndarray) -> dict:
    """Edge lengths (m: edge_mean, edge_min, edge_max) and each face's smallest angle (degrees: min_angle)."""
    tri = vertices[faces]
    edges = np.stack([np.linalg.norm(tri[:, (c + 1) % 3] - tri[:, c], axis=1) for c in range(3)], 1)
    min_angle = np.degrees(corner_angles_rad(vertices, faces)).min(axis=1)
    return {
        "edge_mean": float(edges.mean()),
        "edge_min": float(edges.min()),
        "edge_max": float(edges.max()),
        "min_angle": min_angle,
    }


def canonical_order(vertices: np.ndarray, faces: np.ndarray):
    """Deterministic ordering: vertices sorted by (float32) position, faces by index.

    STL and the npz store float32, so the order is computed on float32 values;
    each face is rotated (orientation kept) to start at its smallest index.
    """
    v32 = vertices.astype(np.float32)
    order = np.lexsort((v32[:, 2], v32[:, 1], v32[:, 0]))
    remap = np.empty(len(order), dtype=np.int64)
    remap[order] = np.arange(len(order))
    f = remap[faces]
    roll = np.argmin(f, axis=1)
    f = np.stack([f[np.arange(len(f)), (roll + c) % 3] for c in range(3)], axis=1)
    f = f[np.lexsort((f[:, 2], f[:, 1], f[:, 0]))]
    return vertices[order], f


def drop_unused_vertices(vertices: np.ndarray, faces: np.ndarray):
    """The vertices some face uses (in their order) and the faces renumbered to them."""
    used = np.unique(faces)
    remap = -np.ones(len(vertices), dtype=np.int64)
    remap[used] = np.arange(len(used))
    return vertices[used], remap[faces]
