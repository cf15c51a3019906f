"""Lumen surface and wall collision prisms for a generated arch.

Lumen: the zero set of a smooth union (blend `blend_radius_m`) of the tapered
vessel tubes. The SDF is sampled on a regular grid with numpy and meshed with
manifold3d's `Manifold.level_set` (marching tetrahedra on a body-centred grid,
grid points snapped to the surface, so few slivers). The smooth union makes
every ostium a continuous fillet, so the wall has no lips.

A uniform ~3 mm mesh cannot follow the narrow branches and the rounded carinas
between neighbouring ostia (radius ~2 mm): there adjacent triangles fold by up
to ~90 deg, vertex normals lean ~50 deg off their faces and the extruded wall
thins out. So triangles next to sharp edges are split (red-green refinement,
new vertices projected onto the surface) and the mesh is relaxed tangentially
on the surface.

The inferior end of the descending aorta is cut flat by a plane (the rim
triangles are regularised in cylindrical coordinates). The mesh is kept closed
(watertight, so inside/outside tests work) with a flat cap; the cap triangles
are flagged so that no collision piece is built on them: the wire enters there.

Wall: every non-cap lumen triangle is extruded outward along the unit vertex
normals into a 6-point convex prism (`extrude_prisms`). Neighbouring prisms
share their side edges (same vertices, same normals), so the wall has no gaps,
and every prism starts on the lumen surface, so no piece intrudes into it.
Everything is deterministic: the mesher's output is put in canonical order
before it is processed.
"""

from __future__ import annotations

import dataclasses

import manifold3d
import numpy as np
from scipy import spatial

from cathsim_dmc.anatomy.arch import ArchModel

_FAR = 1.0  # SDF value (m) used far from every vessel


@dataclasses.dataclass(frozen=True)
class SDFGrid:
    """Signed distance (positive OUTSIDE the lumen) on a regular grid."""

    origin: np.ndarray   # (3,) position of values[0, 0, 0]
    spacing: float
    values: np.ndarray   # (nx, ny, nz) float64

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Trilinear interpolation at (N, 3) points (clamped to the grid)."""
        g = (np.asarray(points, float) - self.origin) / self.spacing
        shape = np.array(self.values.shape)
        i0 = np.clip(np.floor(g).astype(int), 0, shape - 2)
        f = np.clip(g - i0, 0.0, 1.0)
        v = self.values
        out = 0.0
        for dx in (0, 1):
            wx = f[:, 0] if dx else 1 - f[:, 0]
            for dy in (0, 1):
                wy = f[:, 1] if dy else 1 - f[:, 1]
                for dz in (0, 1):
                    wz = f[:, 2] if dz else 1 - f[:, 2]
                    out = out + wx * wy * wz * v[i0[:, 0] + dx, i0[:, 1] + dy, i0[:, 2] + dz]
        return out


@dataclasses.dataclass(frozen=True)
class Lumen:
    vertices: np.ndarray     # (V, 3) float64, metres
    faces: np.ndarray        # (F, 3) int64, counter-clockwise seen from outside
    cap: np.ndarray          # (F,) bool: triangle lies on the open-end cut plane
    normals: np.ndarray      # (V, 3) unit outward vertex normals (cap faces excluded)


def smooth_min(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Quadratic polynomial smooth minimum (blend width k)."""
    h = np.clip(k - np.abs(a - b), 0.0, None) / k
    return np.minimum(a, b) - h * h * k * 0.25


def sdf_grid(model: ArchModel) -> SDFGrid:
    """Sample the blended-tube SDF of `model` on a grid."""
    p = model.params
    h = p.sdf_spacing_m
    pad = 3 * p.edge_length_m + p.blend_radius_m
    lo = np.min([np.min(v.points - v.radius[:, None], axis=0) for v in model.vessels], axis=0) - pad
    hi = np.max([np.max(v.points + v.radius[:, None], axis=0) for v in model.vessels], axis=0) + pad
    # Snap the grid to multiples of h so small parameter changes do not shift it.
    lo = np.floor(lo / h) * h
    n = np.ceil((hi - lo) / h).astype(int) + 1
    axes = [lo[k] + h * np.arange(n[k]) for k in range(3)]
    band = p.blend_radius_m + 4 * p.edge_length_m

    def tube(v):
        """Union-of-spheres distance of one vessel, exact within `band` of it."""
        d = np.full(tuple(n), _FAR)
        vlo = np.min(v.points - v.radius[:, None], axis=0) - band
        vhi = np.max(v.points + v.radius[:, None], axis=0) + band
        sl = tuple(slice(int(np.searchsorted(axes[k], vlo[k])),
                         int(np.searchsorted(axes[k], vhi[k])) + 1) for k in range(3))
        sub = np.stack(np.meshgrid(*[axes[k][sl[k]] for k in range(3)], indexing="ij"), -1)
        q = sub.reshape(-1, 3)
        tree = spatial.cKDTree(v.points)
        # A few nearest centreline samples: the radius varies along the tube.
        dist, idx = tree.query(q, k=4, distance_upper_bound=float(v.radius.max()) + band)
        ok = np.isfinite(dist)
        r = np.where(ok, v.radius[np.minimum(idx, len(v.radius) - 1)], 0.0)
        sd = np.where(ok, dist - r, _FAR).min(axis=1)
        d[sl] = sd.reshape(sub.shape[:3])
        return d

    vals = tube(model.aorta)
    for v in model.vessels[1:]:
        vals = smooth_min(vals, tube(v), p.blend_radius_m)
    # Cap the far field so the blend never reaches across empty space.
    return SDFGrid(origin=lo, spacing=h, values=np.minimum(vals, _FAR))


def _level_set(grid: SDFGrid, lo: np.ndarray, hi: np.ndarray, edge: float) -> manifold3d.Manifold:
    """manifold3d level set of the grid SDF (inside-positive), trilinear in Python."""
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
            return -_FAR
        fx, fy, fz = gx - i, gy - j, gz - k
        b = i * sx + j * sy + k
        c00 = flat[b] * (1 - fz) + flat[b + 1] * fz
        c01 = flat[b + sy] * (1 - fz) + flat[b + sy + 1] * fz
        c10 = flat[b + sx] * (1 - fz) + flat[b + sx + 1] * fz
        c11 = flat[b + sx + sy] * (1 - fz) + flat[b + sx + sy + 1] * fz
        return (c00 * (1 - fy) + c01 * fy) * (1 - fx) + (c10 * (1 - fy) + c11 * fy) * fx

    box = [float(c) for c in lo] + [float(c) for c in hi]
    return manifold3d.Manifold.level_set(f, box, edge)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray, use: np.ndarray | None = None) -> np.ndarray:
    """Angle-weighted unit vertex normals from the faces selected by `use`."""
    f = faces if use is None else faces[use]
    tri = vertices[f]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    acc = np.zeros_like(vertices)
    for c in range(3):
        e1 = tri[:, (c + 1) % 3] - tri[:, c]
        e2 = tri[:, (c + 2) % 3] - tri[:, c]
        cosang = np.sum(e1 * e2, 1) / (np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1))
        ang = np.arccos(np.clip(cosang, -1.0, 1.0))
        np.add.at(acc, f[:, c], fn * ang[:, None])
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    return np.divide(acc, norm, out=np.zeros_like(acc), where=norm > 0)


def _canonical(vertices: np.ndarray, faces: np.ndarray):
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


# A coarse mesh can fold a triangle where the lumen curves tightly (seen at 6-8 mm
# edges on some arches); the surface is then rebuilt with edges this much shorter.
FOLD_RETRY_EDGE_FACTOR = 0.9
MIN_RETRY_EDGE_M = 0.003


class FoldedSurfaceError(RuntimeError):
    pass


def build_lumen(model: ArchModel, grid: SDFGrid | None = None) -> Lumen:
    """Watertight, outward-oriented lumen surface with the open-end cap flagged.

    Meshed at ``edge_length_m``; if that folds a triangle, at edges 10% shorter each
    time down to 3 mm (deterministic: the same parameters give the same surface).
    """
    grid = sdf_grid(model) if grid is None else grid
    edge = model.params.edge_length_m
    while True:
        try:
            return _build_lumen(model, grid, edge)
        except FoldedSurfaceError:
            edge *= FOLD_RETRY_EDGE_FACTOR
            if edge < MIN_RETRY_EDGE_M:
                raise


def _build_lumen(model: ArchModel, grid: SDFGrid, edge: float) -> Lumen:
    p = model.params
    shape = np.array(grid.values.shape)
    lo = grid.origin + grid.spacing
    hi = grid.origin + grid.spacing * (shape - 2)
    man = _level_set(grid, lo, hi, edge)
    # Open inferior end: cut square to the descending aorta (which runs along +y
    # there) at the open-end plane; the part above is kept and capped flat.
    c = model.open_end_center
    man = man.trim_by_plane((0.0, 1.0, 0.0), float(c[1]))
    if man.status() != manifold3d.Error.NoError or man.is_empty():
        raise RuntimeError(f"Lumen meshing failed: {man.status()}")
    mesh = man.to_mesh64()
    v = np.array(mesh.vert_properties, dtype=np.float64)[:, :3].copy()
    f = np.array(mesh.tri_verts, dtype=np.int64)
    # The mesher may run in parallel: fix the order before anything depends on it.
    v, f = _canonical(v, f)
    # Drop manifold's ear-clipped cap, clean the rim, close it with a fan.
    y_cut = float(c[1])
    v[np.abs(v[:, 1] - y_cut) < 1e-9, 1] = y_cut
    f = f[~_cap_mask(v, f, y_cut)]
    used = np.unique(f)
    remap = -np.ones(len(v), dtype=np.int64)
    remap[used] = np.arange(len(used))
    v, f = v[used], remap[f]
    v, f = _clean_rim(v, f, c[[0, 2]], y_cut, edge)
    y_band = y_cut + 3 * edge
    v, f = collapse_short_edges(v, f, grid, SHORT_EDGE_FRACTION * edge, frozen=v[:, 1] < y_band)
    v, f = _refine_curved(v, f, grid, p.max_dihedral_deg, p.refine_levels, y_band)
    v = _relax(v, f, grid, frozen=v[:, 1] < y_band, iterations=p.relax_iterations)
    v, f = fix_slivers(v, f, grid, frozen=v[:, 1] < y_band)
    v, f = _close_cap(v, f, y_cut)
    v, f = _canonical(v, f)
    cap = _cap_mask(v, f, y_cut)
    normals = vertex_normals(v, f, ~cap)
    # Rim normals lie in the cut plane, so the wall ends in a flat annulus there.
    rim = np.unique(f[cap])
    rim = rim[np.isin(rim, f[~cap])]
    normals[rim, 1] = 0.0
    normals[rim] /= np.linalg.norm(normals[rim], axis=1, keepdims=True)
    _check_surface(v, f, cap, grid)
    return Lumen(vertices=v, faces=f, cap=cap, normals=normals)


def _check_surface(v, f, cap, grid: SDFGrid):
    """Fail loudly on an open surface or a wall triangle turned against the surface normal."""
    _, _, edge_faces = _edge_faces(f)
    if np.any(edge_faces[:, 1] < 0):
        raise RuntimeError("Lumen surface is not closed.")
    if not _faces_follow_surface(v, f[~cap], grid, min_cos=0.0):
        raise FoldedSurfaceError("Lumen surface has a folded triangle; try another edge_length_m.")


def _edge_faces(f):
    """Unique edges of `f`, each face's 3 edge ids (edge c = f[c] -> f[c+1]) and each edge's faces."""
    n = len(f)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    edges, inv = np.unique(np.sort(e, axis=1), axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    face_edges = inv.reshape(3, n).T
    order = np.argsort(inv, kind="stable")
    count = np.bincount(inv, minlength=len(edges))
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    edge_faces = np.full((len(edges), 2), -1)
    edge_faces[:, 0] = order[first] % n
    two = count == 2
    edge_faces[two, 1] = order[first[two] + 1] % n
    return edges, face_edges, edge_faces


def _project(points, grid: SDFGrid, iterations=5):
    """Newton steps onto the zero set of the grid SDF."""
    x = np.array(points, dtype=np.float64)
    h = 0.25 * grid.spacing
    eye = np.eye(3) * h
    for _ in range(iterations):
        d = grid(x)
        g = np.stack([(grid(x + eye[k]) - grid(x - eye[k])) / (2 * h) for k in range(3)], axis=1)
        x -= (d / np.maximum(np.sum(g * g, axis=1), 1e-12))[:, None] * g
    return x


def _refine_curved(v, f, grid: SDFGrid, max_dihedral_deg: float, levels: int, y_min: float,
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
        edges, face_edges, edge_faces = _edge_faces(f)
        fn = _face_normals(v, f)
        inner = edge_faces[:, 1] >= 0
        cosang = np.ones(len(edges))
        cosang[inner] = np.sum(fn[edge_faces[inner, 0]] * fn[edge_faces[inner, 1]], axis=1)
        sharp = cosang < np.cos(np.radians(max_dihedral_deg))
        marked = np.zeros(len(f), dtype=bool)
        marked[edge_faces[sharp].ravel()] = True
        marked &= v[f].min(axis=1)[:, 1] > y_min
        if frozen is not None:        # callable: vertices -> bool mask of vertices to leave alone
            marked &= ~np.any(frozen(v)[f], axis=1)
        if not marked.any():
            break
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
        mids = _project(0.5 * (v[edges[split, 0]] + v[edges[split, 1]]), grid)
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
        f = np.concatenate(out)
    return v, f


def _relax(v, f, grid: SDFGrid, frozen: np.ndarray, iterations: int = 4):
    """Tangential Laplacian relaxation with re-projection onto the lumen surface.

    Evens out the triangles refinement leaves behind (bisected neighbours) and
    puts every vertex on the surface; `frozen` vertices (the open-end rim band)
    do not move.
    """
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
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
        candidate[move] = _project(target, grid)
        if not _faces_follow_surface(candidate, f, grid):
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
    accept = lambda vv, touched, before: len(touched) == 0 or _faces_follow_surface(vv, touched, grid, min_cos=0.2)
    skip = set()
    for _ in range(max_rounds):
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        e = np.unique(np.sort(e, axis=1), axis=0)
        length = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
        short = np.nonzero((length < min_length) & ~np.any(frozen[e], axis=1))[0]
        short = [i for i in short[np.argsort(length[short], kind="stable")] if tuple(e[i]) not in skip]
        if not short:
            break
        for i in short:
            a, b = (int(x) for x in e[i])
            res = _try_collapse(v, f, a, b, grid, frozen, None, None, accept=accept)
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

    def angles(vv, ff):
        tri = vv[ff]
        out = []
        for c in range(3):
            e1 = tri[:, (c + 1) % 3] - tri[:, c]
            e2 = tri[:, (c + 2) % 3] - tri[:, c]
            cosang = np.sum(e1 * e2, 1) / np.maximum(np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-300)
            out.append(np.degrees(np.arccos(np.clip(cosang, -1, 1))))
        return np.stack(out, axis=1)

    def aligned(vv, ff):
        return len(ff) == 0 or _faces_follow_surface(vv, ff, grid, min_cos=0.3)

    for _ in range(max_rounds):
        ang = angles(v, f)
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
                changed = _try_flip(v, f, a, b, angles, aligned)
            else:
                # Needle: collapse the shortest edge (opposite the smallest angle).
                small = int(np.argmin(ang[t]))
                a, b = tri[(small + 1) % 3], tri[(small + 2) % 3]
                res = _try_collapse(v, f, a, b, grid, frozen, angles, aligned)
                if res is not None:
                    v, f, frozen = res
                    changed = True
            if changed:
                break
        if not changed:
            break
    return v, f


def _better(after: np.ndarray, before: np.ndarray) -> bool:
    """Fewer sliver angles, or as many and a larger smallest angle."""
    na, nb = int(np.sum(after < SLIVER_ANGLE_DEG)), int(np.sum(before < SLIVER_ANGLE_DEG))
    return na < nb or (na == nb and after.min() > before.min())


def _try_flip(v, f, a, b, angles, aligned) -> bool:
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
    if not _better(angles(v, new), angles(v, f[has])) or not aligned(v, new):
        return False
    f[has] = new
    return True


def _try_collapse(v, f, a, b, grid, frozen, angles, aligned, accept=None):
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
    m = _project(0.5 * (v[a] + v[b])[None], grid)[0]
    v2 = v.copy()
    v2[a] = m
    f2 = f.copy()
    f2[f2 == b] = a
    touched = f2[ring]
    if accept is not None:
        if not accept(v2, touched, None):
            return None
    else:
        before = angles(v, f[np.concatenate([ring, shared])])
        if not _better(angles(v2, touched), before) or not aligned(v2, touched):
            return None
    f2 = np.delete(f2, shared, axis=0)
    # Drop vertex b (renumber).
    keep = np.ones(len(v2), dtype=bool)
    keep[b] = False
    remap = np.cumsum(keep) - 1
    return v2[keep], remap[f2], frozen[keep]


def _sdf_gradient(points, grid: SDFGrid):
    h = 0.25 * grid.spacing
    eye = np.eye(3) * h
    g = np.stack([(grid(points + eye[k]) - grid(points - eye[k])) / (2 * h) for k in range(3)], axis=1)
    return g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)


def _faces_follow_surface(v, f, grid: SDFGrid, min_cos: float = 0.2) -> bool:
    """No face turned against the surface normal (the SDF gradient) at its centroid."""
    n = _sdf_gradient(v[f].mean(axis=1), grid)
    return bool(np.all(np.sum(_face_normals(v, f) * n, axis=1) > min_cos))


def _cap_mask(v, f, y_cut, tol=1e-7):
    return np.all(np.abs(v[f][:, :, 1] - y_cut) < tol, axis=1)


def _boundary_edges(f):
    """Directed edges of `f` whose reverse is missing (the open rim)."""
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = e[:, 0] * (f.max() + 1) + e[:, 1]
    rkey = e[:, 1] * (f.max() + 1) + e[:, 0]
    return e[~np.isin(key, rkey)]


def _face_normals(v, f):
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def _clean_rim(v, f, axis_xz, y_cut, edge, iterations=20, radius=None):
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
    rim_e = _boundary_edges(f)
    rim = np.unique(rim_e)
    in_reach = v[:, 1] < y_cut + 2.5 * edge
    if radius is not None:      # only around the open end (imported meshes may reach below it elsewhere)
        in_reach &= np.hypot(v[:, 0] - axis_xz[0], v[:, 2] - axis_xz[1]) < radius
    band = np.nonzero(in_reach)[0]
    inner = np.setdiff1d(band, rim)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
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
        return np.all(np.sum(_face_normals(vv, fb) * radial, axis=1) > 0.2)

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
        rim_e = _boundary_edges(f)
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
            used = np.unique(f)
            remap = -np.ones(len(v), dtype=np.int64)
            remap[used] = np.arange(len(used))
            v, f = v[used], remap[f]
            break
        else:
            return v, f


def _close_cap(v, f, y_cut):
    """Close the planar rim with a fan of triangles around its centroid."""
    rim_e = _boundary_edges(f)
    nxt = {int(a): int(b) for a, b in rim_e}
    if len(nxt) != len(rim_e):
        raise RuntimeError("Open-end rim is not a simple loop.")
    start = min(nxt)
    loop = [start]
    while nxt[loop[-1]] != start:
        loop.append(nxt[loop[-1]])
        if len(loop) > len(rim_e):
            raise RuntimeError("Open-end rim is not a simple loop.")
    if len(loop) != len(rim_e):
        raise RuntimeError("Open end has more than one rim loop.")
    ctr = v[loop].mean(axis=0)
    ctr[1] = y_cut
    ci = len(v)
    # The tube faces traverse the rim as a->b; the cap must traverse it b->a.
    fan = np.array([[ci, loop[(i + 1) % len(loop)], loop[i]] for i in range(len(loop))])
    return np.concatenate([v, ctr[None]]), np.concatenate([f, fan])


def triangle_quality(vertices: np.ndarray, faces: np.ndarray) -> dict:
    """Edge-length and minimum-angle statistics (degrees)."""
    tri = vertices[faces]
    edges = np.stack([np.linalg.norm(tri[:, (c + 1) % 3] - tri[:, c], axis=1) for c in range(3)], 1)
    angles = []
    for c in range(3):
        e1 = tri[:, (c + 1) % 3] - tri[:, c]
        e2 = tri[:, (c + 2) % 3] - tri[:, c]
        cosang = np.sum(e1 * e2, 1) / (np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1))
        angles.append(np.degrees(np.arccos(np.clip(cosang, -1, 1))))
    min_angle = np.min(angles, axis=0)
    return {"edge_mean": float(edges.mean()), "edge_min": float(edges.min()),
            "edge_max": float(edges.max()), "min_angle": min_angle}


def extrude_prisms(lumen: Lumen, thickness: float, max_stretch: float = 1.6) -> np.ndarray:
    """(H, 6, 3) prisms: each wall triangle, then the same triangle offset outward.

    Every vertex moves along its unit vertex normal, so neighbouring prisms
    share their side edges. Where the normal leans away from an adjacent face
    (curved regions, e.g. the carinas between ostia), a plain offset of
    `thickness` would leave that face's prism thinner than `thickness` along its
    own normal; the offset is lengthened to thickness / cos(lean), capped at
    `max_stretch` x thickness, so the wall keeps its thickness everywhere.
    """
    f = lumen.faces[~lumen.cap]
    v, n = lumen.vertices, lumen.normals
    fn = _face_normals(v, f)
    lean = np.ones(len(v))
    for c in range(3):
        np.minimum.at(lean, f[:, c], np.sum(n[f[:, c]] * fn, axis=1))
    offset = thickness / np.clip(lean, 1.0 / max_stretch, 1.0)
    outer = v + offset[:, None] * n
    return np.concatenate([v[f], outer[f]], axis=1)


def signed_distance(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Signed distance (m) from `points` to a closed, outward-oriented mesh; POSITIVE inside.

    Closest point from trimesh's proximity query; the sign from the angle-weighted
    pseudo-normal of the closest feature (face, edge or vertex), which is exact
    for closed manifolds (Baerentzen & Aanaes 2005) and needs no ray casting.
    """
    import trimesh

    # trimesh's closest-point tolerances are absolute and misjudge sub-millimetre
    # triangles expressed in metres: query in millimetres.
    vertices = np.asarray(vertices, dtype=np.float64) * 1e3
    faces = np.asarray(faces, dtype=np.int64)
    points = np.asarray(points, dtype=np.float64) * 1e3
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    closest, dist, tid = trimesh.proximity.closest_point(mesh, points)
    dist = dist * 1e-3
    fn = _face_normals(vertices, faces)
    vn = vertex_normals(vertices, faces)
    # Edge c of a face is the one opposite its vertex c.
    e = np.stack([faces[:, [1, 2]], faces[:, [2, 0]], faces[:, [0, 1]]], axis=1)   # (F, 3, 2)
    e = np.sort(e, axis=2).reshape(-1, 2)
    _, edge_id = np.unique(e, axis=0, return_inverse=True)
    edge_id = edge_id.reshape(-1)
    en = np.zeros((edge_id.max() + 1, 3))
    np.add.at(en, edge_id, np.repeat(fn, 3, axis=0))
    edge_id = edge_id.reshape(-1, 3)
    tri = vertices[faces[tid]]
    bary = trimesh.triangles.points_to_barycentric(tri, closest)
    zero = bary < 1e-7
    nzero = zero.sum(axis=1)
    normal = fn[tid].copy()
    on_edge = nzero == 1
    c = np.argmax(zero[on_edge], axis=1)
    normal[on_edge] = en[edge_id[tid[on_edge], c]]
    on_vertex = nzero >= 2
    k = np.argmax(~zero[on_vertex], axis=1)
    normal[on_vertex] = vn[faces[tid[on_vertex], k]]
    outside = np.sum((points - closest) * normal, axis=1) > 0
    return np.where(outside, -dist, dist)
