"""Signed distance to the lumen (metres): sampled on a grid, of a generated arch, of a closed mesh.

`SDFGrid` is a signed distance (positive OUTSIDE) sampled on a regular grid, with
trilinear interpolation, its gradient and a projection onto its zero set; the
lumen is meshed from it and remeshed against it (`remesh.py`). `arch_sdf_grid`
samples a generated arch: the smooth union (blend `blend_radius_m`) of its
tapered vessel tubes, so every ostium is a continuous fillet.

`signed_distance` (positive INSIDE) and `unsigned_distance` are exact distances
to a triangle mesh, for the validation, the importer and the centerline radii.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import spatial

from cathsim_dmc.anatomy.arch import ArchModel
from cathsim_dmc.anatomy.triangles import face_normals, vertex_normals

FAR_M = 1.0  # SDF value (m) used far from every vessel


@dataclasses.dataclass(frozen=True)
class SDFGrid:
    """Signed distance (positive OUTSIDE the lumen) on a regular grid."""

    origin: np.ndarray  # (3,) position of values[0, 0, 0]
    spacing: float
    values: np.ndarray  # (nx, ny, nz) float64

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

    def gradient(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) central differences over a quarter of the grid spacing."""
        h = 0.25 * self.spacing
        eye = np.eye(3) * h
        return np.stack([(self(points + eye[k]) - self(points - eye[k])) / (2 * h) for k in range(3)], axis=1)

    def surface_normal(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) unit gradient: the outward normal of the level set through each point."""
        g = self.gradient(points)
        return g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)

    def project_onto_surface(self, points: np.ndarray, iterations: int = 5) -> np.ndarray:
        """Newton steps from (N, 3) points onto the zero set."""
        x = np.array(points, dtype=np.float64)
        max_step = 4.0 * self.spacing  # a flat patch of the field (tiny gradient) must not throw a point away
        for _ in range(iterations):
            d = self(x)
            g = self.gradient(x)
            step = (d / np.maximum(np.sum(g * g, axis=1), 1e-12))[:, None] * g
            norm = np.linalg.norm(step, axis=1, keepdims=True)
            x -= np.where(norm > max_step, step * (max_step / np.maximum(norm, 1e-300)), step)
        return x


def smooth_min(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Quadratic polynomial smooth minimum (blend width k)."""
    h = np.clip(k - np.abs(a - b), 0.0, None) / k
    return np.minimum(a, b) - h * h * k * 0.25


def arch_sdf_grid(model: ArchModel) -> SDFGrid:
    """Sample the blended-tube SDF of `model` on a grid of `sdf_spacing_m`."""
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
        d = np.full(tuple(n), FAR_M)
        vlo = np.min(v.points - v.radius[:, None], axis=0) - band
        vhi = np.max(v.points + v.radius[:, None], axis=0) + band
        sl = tuple(
            slice(int(np.searchsorted(axes[k], vlo[k])), int(np.searchsorted(axes[k], vhi[k])) + 1) for k in range(3)
        )
        sub = np.stack(np.meshgrid(*[axes[k][sl[k]] for k in range(3)], indexing="ij"), -1)
        q = sub.reshape(-1, 3)
        tree = spatial.cKDTree(v.points)
        # A few nearest centreline samples: the radius varies along the tube.
        dist, idx = tree.query(q, k=4, distance_upper_bound=float(v.radius.max()) + band)
        ok = np.isfinite(dist)
        r = np.where(ok, v.radius[np.minimum(idx, len(v.radius) - 1)], 0.0)
        sd = np.where(ok, dist - r, FAR_M).min(axis=1)
        d[sl] = sd.reshape(sub.shape[:3])
        return d

    vals = tube(model.aorta)
    for v in model.vessels[1:]:
        vals = smooth_min(vals, tube(v), p.blend_radius_m)
    # Cap the far field so the blend never reaches across empty space.
    return SDFGrid(origin=lo, spacing=h, values=np.minimum(vals, FAR_M))


def _closest_point_mm(vertices_mm, faces, points_mm):
    """trimesh's (closest points, distances, face ids), all in millimetres: its closest-point
    tolerances are absolute and misjudge sub-millimetre triangles expressed in metres."""
    import trimesh  # local: only these distances need it

    return trimesh.proximity.closest_point(trimesh.Trimesh(vertices_mm, faces, process=False), points_mm)


def unsigned_distance(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N,) distance (m) from each point to the nearest of the triangles `faces`."""
    _, dist, _ = _closest_point_mm(np.asarray(vertices) * 1e3, faces, np.asarray(points) * 1e3)
    return dist * 1e-3


def signed_distance(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Signed distance (m) from `points` to a closed, outward-oriented mesh; POSITIVE inside.

    Closest point from trimesh's proximity query; the sign from the angle-weighted
    pseudo-normal of the closest feature (face, edge or vertex), which is exact
    for closed manifolds (Baerentzen & Aanaes 2005) and needs no ray casting.
    """
    import trimesh

    vertices = np.asarray(vertices, dtype=np.float64) * 1e3
    faces = np.asarray(faces, dtype=np.int64)
    points = np.asarray(points, dtype=np.float64) * 1e3
    closest, dist, tid = _closest_point_mm(vertices, faces, points)
    dist = dist * 1e-3
    fn = face_normals(vertices, faces)
    vn = vertex_normals(vertices, faces)
    # Edge c of a face is the one opposite its vertex c.
    e = np.stack([faces[:, [1, 2]], faces[:, [2, 0]], faces[:, [0, 1]]], axis=1)  # (F, 3, 2)
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
