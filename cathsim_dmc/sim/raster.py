"""Top-view images without OpenGL: project, then draw with OpenCV or numpy.

The top camera is orthographic and fixed in the world, so everything that does not move
(the vessel) is drawn once per compiled model, and per step only the guidewire, a
polyline through its segment joints, is projected and drawn. Coordinates follow
`arena.top_camera_matrix`: pixel `i` spans [i, i + 1], so its centre is `i + 0.5`.

The fluoroscopy roadmap darkens the vessel by the length of the X-ray path through the
contrast-filled lumen, found per pixel by rasterising the lumen surface: for a closed
surface seen along the view axis, path length = sum of the depths where the ray enters
(faces towards the camera) minus those where it leaves (faces away). This is exact for
any lumen shape (branches, the aneurysm, imported meshes); an estimate from the
centerline radii would miss the ascending aorta, which no entry-to-target centerline
passes through.
"""

from __future__ import annotations

import cv2
import mujoco
import numpy as np

from cathsim_dmc.sim.arena import top_camera_matrix

_SHIFT = 4  # cv2 subpixel bits: coordinates in 1/16 pixel
_TIE_BREAK = 1e-7  # offsets sample points off exact triangle edges (no double counts)

# Fluoroscopy style (fractions of white). A contrast-filled aorta 25 mm thick transmits
# exp(-40 * 0.025) = 37% of the background, an 8 mm branch 73%: a clear roadmap at 8 bit.
FLUORO_BACKGROUND = 0.78
CONTRAST_ATTENUATION_PER_M = 40.0
WIRE_OPACITY = 0.9  # radio-opaque: the darkest thing in the image
# At 80 px a pixel spans ~3 mm, more than three wire diameters; a fluoroscope's focal-spot and
# detector blur make a wire look wider than it is. The fluoro wire is drawn at least
# this wide (output pixels) so that it stays the darkest feature, not a faint line.
FLUORO_WIRE_MIN_WIDTH_PX = 1.0


def camera_axes(physics, camera: str):
    """World -> pixel matrix (3x4) at 1 px and the unit view axis (towards the camera)."""
    cam = physics.model.name2id(camera, "camera")
    if physics.model.cam_projection[cam] != mujoco.mjtProjection.mjPROJ_ORTHOGRAPHIC:
        raise ValueError(f"camera {camera!r} is not orthographic; the raster path needs an orthographic camera")
    towards_camera = physics.data.cam_xmat[cam].reshape(3, 3)[:, 2].copy()
    return top_camera_matrix(physics, camera, size=1), towards_camera


def project(points: np.ndarray, matrix_1px: np.ndarray, size: int) -> np.ndarray:
    """(n, 3) world points -> (n, 2) pixel coordinates (u right, v down) at `size` px."""
    return size * (points @ matrix_1px[:2, :3].T + matrix_1px[:2, 3])


def mesh_in_world(physics, geom_id: int):
    """Vertices (world, metres) and faces of a mesh geom, as the renderer draws them
    (MuJoCo re-centres mesh vertices at compile time; the geom frame undoes it)."""
    model = physics.model
    mesh = model.geom_dataid[geom_id]
    va, vn = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
    fa, fn = model.mesh_faceadr[mesh], model.mesh_facenum[mesh]
    rot = physics.data.geom_xmat[geom_id].reshape(3, 3)
    vertices = model.mesh_vert[va : va + vn].astype(np.float64) @ rot.T + physics.data.geom_xpos[geom_id]
    return vertices, model.mesh_face[fa : fa + fn].astype(np.int64)


def path_length_map(
    vertices: np.ndarray, faces: np.ndarray, matrix_1px: np.ndarray, towards_camera: np.ndarray, size: int
):
    """Per-pixel length (metres) of the view ray inside a closed surface, sampled at
    pixel centres, and the number of surface crossings (0 outside the silhouette)."""
    uv = project(vertices, matrix_1px, size)
    depth = vertices @ towards_camera
    a, b, c = uv[faces[:, 0]], uv[faces[:, 1]], uv[faces[:, 2]]
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    normal = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]])
    sign = np.sign(normal @ towards_camera)  # +1 where the ray enters (outward normals)
    corners = np.stack([a, b, c], axis=1)
    lo = np.clip(np.ceil(corners.min(axis=1) - 0.5), 0, size - 1).astype(np.int64)
    hi = np.clip(np.floor(corners.max(axis=1) - 0.5), 0, size - 1).astype(np.int64)
    extent = (hi - lo + 1).max(axis=1)
    keep = (np.abs(area2) > 1e-12) & (sign != 0) & np.all(hi >= lo, axis=1)

    total = np.zeros(size * size)
    crossings = np.zeros(size * size)
    window = 1
    while True:
        chosen = np.flatnonzero(keep & (extent <= window) & (extent > window // 2))
        if chosen.size:
            offsets = np.arange(window)
            px = lo[chosen, 0, None, None] + offsets[None, None, :]  # (n, 1, w) columns
            py = lo[chosen, 1, None, None] + offsets[None, :, None]  # (n, w, 1) rows
            x, y = px + 0.5 + _TIE_BREAK, py + 0.5 + 2 * _TIE_BREAK

            def edge(p, q):  # twice the signed area of (p, q, sample)
                return (q[chosen, 0, None, None] - p[chosen, 0, None, None]) * (y - p[chosen, 1, None, None]) - (
                    q[chosen, 1, None, None] - p[chosen, 1, None, None]
                ) * (x - p[chosen, 0, None, None])

            s = area2[chosen, None, None]
            w0, w1, w2 = edge(b, c) / s, edge(c, a) / s, edge(a, b) / s
            inside = (
                (w0 >= 0)
                & (w1 >= 0)
                & (w2 >= 0)
                & (px <= hi[chosen, 0, None, None])
                & (py <= hi[chosen, 1, None, None])
            )
            f = faces[chosen]
            z = w0 * depth[f[:, 0], None, None] + w1 * depth[f[:, 1], None, None] + w2 * depth[f[:, 2], None, None]
            index = np.broadcast_to(py * size + px, inside.shape)[inside]
            total += np.bincount(index, (sign[chosen, None, None] * z)[inside], minlength=size * size)
            crossings += np.bincount(index, minlength=size * size)
        if window >= extent[keep].max(initial=0):
            break
        window *= 2
    length = total.reshape(size, size)
    if length.sum() < 0:  # inward-wound surface
        length = -length
    return np.maximum(length, 0.0), crossings.reshape(size, size).astype(np.int64)


def reduce_area(image: np.ndarray, size: int) -> np.ndarray:
    """Block mean down to (size, size): a box filter over each supersampled pixel."""
    return cv2.resize(image.astype(np.float32), (size, size), interpolation=cv2.INTER_AREA)


def fluoro_roadmap(path_length_m: np.ndarray) -> np.ndarray:
    """Transmitted intensity (0..1) of a contrast-filled lumen: Beer-Lambert."""
    return FLUORO_BACKGROUND * np.exp(-CONTRAST_ATTENUATION_PER_M * path_length_m)


class WireDrawer:
    """Draws a projected polyline on a supersampled canvas, reused between calls."""

    def __init__(self, size: int, supersampling: int):
        self.size = int(size)
        self.k = int(supersampling)
        self._canvas = np.zeros((self.size * self.k,) * 2, np.uint8)

    def _points(self, uv_out: np.ndarray) -> np.ndarray:
        # Output-pixel coordinates -> canvas pixel centres, in 1/16 pixel.
        return np.round((uv_out * self.k - 0.5) * (1 << _SHIFT)).astype(np.int32)

    def coverage(self, uv_out: np.ndarray, width_px: float) -> np.ndarray:
        """Fraction (0..1, float32) of each output pixel covered by a line `width_px`
        output pixels wide. A line thinner than its drawn (integer) canvas thickness
        covers proportionally less: its coverage is scaled by the ratio."""
        width = width_px * self.k
        thickness = max(1, int(round(width)))
        self._canvas.fill(0)
        cv2.polylines(self._canvas, [self._points(uv_out)], False, 255, thickness, cv2.LINE_AA, _SHIFT)
        cover = reduce_area(self._canvas, self.size) * np.float32(width / thickness / 255.0)
        return np.minimum(cover, 1.0, out=cover)

    def disc(self, centre_out: np.ndarray, radius_px: float) -> np.ndarray:
        """Fraction (0..1, float32) of each output pixel covered by a filled disc of
        `radius_px` output pixels around `centre_out` (output-pixel coordinates)."""
        self._canvas.fill(0)
        centre = tuple(int(c) for c in self._points(np.asarray(centre_out, dtype=float)[None])[0])
        radius = int(round(radius_px * self.k * (1 << _SHIFT)))
        cv2.circle(self._canvas, centre, radius, 255, -1, cv2.LINE_AA, _SHIFT)
        return reduce_area(self._canvas, self.size) / np.float32(255.0)

    def mask(self, uv_out: np.ndarray, width_px: float) -> np.ndarray:
        """True where the wire, a tube `width_px` output pixels wide around the polyline,
        covers a canvas pixel centre of the output pixel: the sampling rule of a GL
        segmentation render at the same supersampling (cv2's thin lines follow
        Bresenham's rule instead, which misses pixels a line grazes)."""
        k, n = self.k, self.size * self.k
        radius = width_px * k / 2
        start, end = uv_out[:-1] * k, uv_out[1:] * k
        lo = np.floor(np.minimum(start, end) - radius - 0.5).astype(np.int64)
        hi = np.ceil(np.maximum(start, end) + radius - 0.5).astype(np.int64)
        window = int((hi - lo).max(initial=0)) + 1
        offsets = np.arange(window)
        px = lo[:, 0, None, None] + offsets[None, None, :]  # (segments, 1, window)
        py = lo[:, 1, None, None] + offsets[None, :, None]  # (segments, window, 1)
        d = end - start
        length2 = np.maximum((d * d).sum(axis=1), 1e-12)[:, None, None]
        rx, ry = px + 0.5 - start[:, 0, None, None], py + 0.5 - start[:, 1, None, None]
        along = np.clip((rx * d[:, 0, None, None] + ry * d[:, 1, None, None]) / length2, 0.0, 1.0)
        dx, dy = rx - along * d[:, 0, None, None], ry - along * d[:, 1, None, None]
        hit = (dx * dx + dy * dy <= radius * radius) & (px >= 0) & (px < n) & (py >= 0) & (py < n)
        mask = np.zeros((self.size, self.size), bool)
        mask[np.broadcast_to(py, hit.shape)[hit] // k, np.broadcast_to(px, hit.shape)[hit] // k] = True
        return mask
