"""Is the wire inside the vessel? A lumen distance field cheap enough for every control step.

An exact signed distance to the lumen mesh costs ~125 us per point (trimesh closest
point plus pseudo-normal sign), and a wire has ~70 points to check each control step.
So the distance is sampled once per asset on a regular grid and looked up by trilinear
interpolation (~13 us for 70 points; 2.8-4 s to build one 1 mm field of ~5 MB):

- the unsigned distance is exact at every node within `truncation_m` of the surface
  (each triangle updates the nodes of its bounding box grown by the truncation) and
  clamped to `truncation_m` elsewhere, where only the side matters;
- the side comes from ray parity along the grid's three axes, by majority vote, so one
  ray that grazes an edge or a vertex cannot flip a node.

Trilinear interpolation is exact for a flat wall and errs near curved walls and sharp
edges. Measured on type1 at 1 mm spacing against the exact signed distance, 20,000 points
within 3 mm of the wall: median error 0.004 mm; 0.5-2.5 mm outside the wall, where the
escape threshold lies, -0.06 to +0.19 mm (positive: the grid reads a point as less far
out); the largest errors, up to -0.29 mm, sit just inside the sharp rim of the open end.

Fields are cached in memory per mesh and on disk under the anatomy cache
(``<cache>/lumen_fields``, keyed by the mesh, the grid parameters and `FIELD_VERSION`),
so a process pays the build (seconds) once per asset and later processes load it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import pathlib
import tempfile
from typing import Iterable

import numpy as np
from scipy import ndimage

FIELD_VERSION = 1
DEFAULT_SPACING_M = 1e-3
DEFAULT_TRUNCATION_M = 4e-3
# One field per compiled model: kept as many as the model cache keeps (cathsim_dmc.sim.model_cache;
# about 1 MB each), so a random-anatomy pool does not rebuild its fields (2-3 s each) in turn.
MAX_CACHED_FIELDS = int(os.environ.get("CATHSIM_DMC_MAX_CACHED_MODELS", 256))
_RAY_OFFSET = (1.2345e-4, 3.1416e-4)  # grid units: keeps parity rays off mesh vertices and edges
_memory_cache: dict = {}


@dataclasses.dataclass(frozen=True)
class LumenField:
    """Signed distance to a closed lumen surface (POSITIVE inside) on a regular grid."""

    origin_m: np.ndarray  # (3,) position of values_m[0, 0, 0]
    spacing_m: float
    values_m: np.ndarray  # (nx, ny, nz) float32, clamped to +-truncation_m
    truncation_m: float

    @property
    def exact_within_m(self) -> float:
        """Depths up to this far from the surface (either side) interpolate exact node values."""
        return self.truncation_m - self.spacing_m * np.sqrt(3.0)

    @property
    def nbytes(self) -> int:
        return int(self.values_m.nbytes)

    def signed_distance_m(self, points) -> np.ndarray:
        """Interpolated signed distance (m, positive inside) at (N, 3) points.

        Points off the grid, and NaN points, read -truncation_m: far outside.
        """
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        g = ((points - self.origin_m) / self.spacing_m).T
        # The outer nodes all read -truncation_m, so "constant" extends the field unchanged.
        out = ndimage.map_coordinates(
            self.values_m,
            np.nan_to_num(g, nan=-1.0),
            output=np.float64,
            order=1,
            mode="constant",
            cval=-self.truncation_m,
        )
        return out


def build_lumen_field(
    vertices, faces, spacing_m: float = DEFAULT_SPACING_M, truncation_m: float = DEFAULT_TRUNCATION_M
) -> LumenField:
    """Samples the signed distance to a closed, outward-oriented mesh (metres) on a grid."""
    if spacing_m <= 0 or truncation_m <= spacing_m * np.sqrt(3.0):
        raise ValueError(
            f"spacing_m={spacing_m} and truncation_m={truncation_m}: need 0 < spacing_m "
            f"and truncation_m > spacing_m * sqrt(3), or no node is exact"
        )
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    # Every node within the truncation of the mesh, plus two cells, so that the outer
    # nodes all read -truncation and points off the grid are rightly outside.
    margin = truncation_m + 2 * spacing_m
    origin = vertices.min(axis=0) - margin
    shape = np.ceil((vertices.max(axis=0) + margin - origin) / spacing_m).astype(int) + 1
    triangles = (vertices[faces] - origin) / spacing_m  # grid units from here on
    distance = _truncated_distance(triangles, shape, truncation_m / spacing_m)
    votes = sum(_ray_parity(triangles, shape, axis) for axis in range(3))
    values = np.where(votes >= 2, distance, -distance) * spacing_m
    return LumenField(
        origin_m=origin,
        spacing_m=float(spacing_m),
        values_m=values.astype(np.float32),
        truncation_m=float(truncation_m),
    )


def _truncated_distance(
    triangles: np.ndarray, shape: np.ndarray, truncation: float, chunk_pairs: int = 400_000
) -> np.ndarray:
    """min(distance to the mesh, truncation) at every node, in grid units."""
    import trimesh  # local: only building a field needs it

    distance = np.full(int(np.prod(shape)), truncation, dtype=np.float64)
    lo = np.clip(np.ceil(triangles.min(axis=1) - truncation).astype(int), 0, shape - 1)
    hi = np.clip(np.floor(triangles.max(axis=1) + truncation).astype(int), 0, shape - 1)
    dims = hi - lo + 1
    counts = np.prod(dims, axis=1)
    strides = np.array([shape[1] * shape[2], shape[2], 1])
    start = 0
    while start < len(triangles):
        # As many triangles as keep the node-triangle pairs near chunk_pairs.
        stop = start + max(1, int(np.searchsorted(np.cumsum(counts[start:]), chunk_pairs)))
        tri = np.repeat(np.arange(start, stop), counts[start:stop])
        k = np.arange(len(tri)) - np.repeat(np.cumsum(counts[start:stop]) - counts[start:stop], counts[start:stop])
        ny, nz = dims[tri, 1], dims[tri, 2]
        node = lo[tri] + np.stack([k // (ny * nz), (k // nz) % ny, k % nz], axis=1)
        closest = trimesh.triangles.closest_point(triangles[tri], node.astype(np.float64))
        d = np.linalg.norm(closest - node, axis=1)
        near = d < truncation
        np.minimum.at(distance, node[near] @ strides, d[near])
        start = stop
    return distance.reshape(shape)


def _ray_parity(triangles: np.ndarray, shape: np.ndarray, axis: int) -> np.ndarray:
    """1 where a ray along -`axis` from the node crosses the mesh an odd number of times."""
    u_axis, v_axis = [a for a in range(3) if a != axis]
    offset = np.array(_RAY_OFFSET)
    uv = triangles[:, :, [u_axis, v_axis]] - offset  # rays through integer (u, v)
    lo = np.clip(np.ceil(uv.min(axis=1)).astype(int), 0, shape[[u_axis, v_axis]] - 1)
    hi = np.clip(np.floor(uv.max(axis=1)).astype(int), -1, shape[[u_axis, v_axis]] - 1)
    dims = np.maximum(hi - lo + 1, 0)
    counts = np.prod(dims, axis=1)
    tri = np.repeat(np.arange(len(triangles)), counts)
    k = np.arange(len(tri)) - np.repeat(np.cumsum(counts) - counts, counts)
    column = lo[tri] + np.stack([k // dims[tri, 1], k % dims[tri, 1]], axis=1)
    # Barycentric coordinates of the ray in the triangle's (u, v) projection.
    a, b, c = (uv[tri, i] - column for i in range(3))
    cross = lambda p, q: p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0]
    wa, wb, wc = cross(b, c), cross(c, a), cross(a, b)
    area = wa + wb + wc
    hit = (np.abs(area) > 1e-12) & (((wa >= 0) & (wb >= 0) & (wc >= 0)) | ((wa <= 0) & (wb <= 0) & (wc <= 0)))
    tri, column = tri[hit], column[hit]
    t = (
        wa[hit] * triangles[tri, 0, axis] + wb[hit] * triangles[tri, 1, axis] + wc[hit] * triangles[tri, 2, axis]
    ) / area[hit]
    first = np.maximum(np.ceil(t).astype(int), 0)  # the first node past the crossing
    keep = first < shape[axis]
    flips = np.zeros(shape, dtype=np.uint8)
    index = [None, None, None]
    index[u_axis], index[v_axis], index[axis] = column[keep, 0], column[keep, 1], first[keep]
    np.add.at(flips, tuple(index), 1)
    return np.cumsum(flips, axis=axis, dtype=np.uint8) & 1


def _field_key(vertices, faces, spacing_m, truncation_m) -> str:
    digest = hashlib.sha256()
    for part in (
        f"{FIELD_VERSION} {spacing_m!r} {truncation_m!r}".encode(),
        np.ascontiguousarray(vertices, dtype=np.float32).tobytes(),
        np.ascontiguousarray(faces, dtype=np.int32).tobytes(),
    ):
        digest.update(len(part).to_bytes(8, "little"))
        digest.update(part)
    return digest.hexdigest()[:32]


def field_cache_dir() -> pathlib.Path:
    from cathsim_dmc.anatomy.generate import cache_root

    return cache_root().parent / "lumen_fields"


def lumen_field(
    asset, spacing_m: float = DEFAULT_SPACING_M, truncation_m: float = DEFAULT_TRUNCATION_M, cache: bool = True
) -> LumenField:
    """The `LumenField` of an `AortaAsset`'s visual (lumen) mesh, built once and cached."""
    key = _field_key(asset.visual_vertices, asset.visual_faces, spacing_m, truncation_m)
    if cache and key in _memory_cache:
        return _memory_cache[key]
    path = field_cache_dir() / f"{key}.npz"
    field = _load(path) if cache else None
    if field is None:
        field = build_lumen_field(asset.visual_vertices, asset.visual_faces, spacing_m, truncation_m)
        if cache:
            _save(field, path)
    if cache:
        _memory_cache[key] = field
    return field


def _load(path: pathlib.Path):
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as npz:
            field = LumenField(
                origin_m=npz["origin_m"],
                spacing_m=float(npz["spacing_m"]),
                values_m=npz["values_m"],
                truncation_m=float(npz["truncation_m"]),
            )
        os.utime(path)  # most recently used
        return field
    except Exception:  # a truncated or foreign file: build again and replace it
        return None


def _save(field: LumenField, path: pathlib.Path) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # Atomic: concurrent builds of the same field never read a partial file.
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            np.savez_compressed(
                fh,
                origin_m=field.origin_m,
                spacing_m=field.spacing_m,
                values_m=field.values_m,
                truncation_m=field.truncation_m,
            )
        os.replace(tmp, path)
        old = sorted(path.parent.glob("*.npz"), key=lambda p: p.stat().st_mtime_ns, reverse=True)
        for stale in old[MAX_CACHED_FIELDS:]:
            stale.unlink(missing_ok=True)
    except OSError:
        pass  # a read-only cache only costs build time


@dataclasses.dataclass(frozen=True)
class Channel:
    """A straight tube (a capsule: round ends) of `radius_m` around the segment start_m -> end_m."""

    start_m: np.ndarray
    end_m: np.ndarray
    radius_m: float

    def contains(self, points) -> np.ndarray:
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        start, axis = np.asarray(self.start_m, float), np.asarray(self.end_m, float) - self.start_m
        t = np.clip((points - start) @ axis / max(float(axis @ axis), 1e-300), 0.0, 1.0)
        return np.linalg.norm(points - start - t[:, None] * axis, axis=1) <= self.radius_m


class Containment:
    """Which points lie inside the lumen (up to `tolerance_m` past its wall) or inside a channel.

    The wire's channels (the robot's guide channel and introducer) lie outside the
    anatomy by design; any other point outside the lumen has escaped.
    """

    def __init__(self, field: LumenField, tolerance_m: float, channels: Iterable[Channel] = ()):
        if not 0.0 <= tolerance_m <= field.exact_within_m:
            raise ValueError(
                f"tolerance_m={tolerance_m} must lie in [0, {field.exact_within_m:.4g}] m, "
                f"where this field's interpolation is exact (truncation_m - spacing_m * sqrt(3))"
            )
        self.field = field
        self.tolerance_m = float(tolerance_m)
        self.channels = tuple(channels)

    def contains(self, points) -> np.ndarray:
        """(N,) bool for (N, 3) points in metres; NaN points are outside."""
        inside = self.field.signed_distance_m(points) >= -self.tolerance_m
        for channel in self.channels:
            inside |= channel.contains(points)
        return inside
