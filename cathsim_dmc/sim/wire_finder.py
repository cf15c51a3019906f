"""Finding the guidewire in a fluoroscopic frame, as an image tracker on a C-arm does.

The wire is the thinnest dark feature of the frame: radio-opaque, it passes about a tenth of
the X-rays (`raster.WIRE_OPACITY`), while the contrast-filled vessels darken it smoothly
over millimetres. In the logarithm of the frame (attenuations add there), a morphological
closing over a few pixels fills in what is thinner than its window, the wire, and keeps
what is wider, the vessels and their edges; the wire is where the frame lies well below
its closing (`wire_mask`). `wire_path_px` then walks the wire's pixels from the one
nearest the sheath, across gaps of a pixel or two that noise opens, and takes as the tip
the pixel farthest from it along the wire.

Pixel coordinates are (u right, v down) of the pixel centres, `i + 0.5` for pixel i, as in
`cathsim_dmc.sim.raster`.
"""

from __future__ import annotations

from collections import deque

import cv2
import numpy as np

CLOSING_PX = 5  # wider than the drawn wire (one or two pixels), narrower than a branch
LINE_DEPTH = 0.5  # the wire: the log frame at least this far below its closing (a factor 0.6)
MAX_GAP_PX = 2  # steps across missing pixels of the wire, at most this many pixels


def wire_mask(frame: np.ndarray) -> np.ndarray:
    """Boolean mask of the wire's pixels in a fluoroscopic frame (uint8, H x W or H x W x 1)."""
    log = np.log(np.asarray(frame, dtype=np.float32).reshape(frame.shape[:2]) + 1.0)
    closed = cv2.morphologyEx(log, cv2.MORPH_CLOSE, np.ones((CLOSING_PX, CLOSING_PX), np.uint8))
    return log - closed < -LINE_DEPTH


def wire_path_px(mask: np.ndarray, entry_px) -> np.ndarray | None:
    """The wire's pixels from its tip back to the one nearest `entry_px` (u, v), along the
    wire ((n, 2) pixel centres, tip first); None if the mask is empty."""
    rows, cols = np.nonzero(mask)
    if len(rows) == 0:
        return None
    nearest = np.argmin((cols + 0.5 - entry_px[0]) ** 2 + (rows + 0.5 - entry_px[1]) ** 2)
    start = (int(rows[nearest]), int(cols[nearest]))
    steps = [(dr, dc) for dr in range(-MAX_GAP_PX, MAX_GAP_PX + 1) for dc in range(-MAX_GAP_PX, MAX_GAP_PX + 1)]
    steps = sorted(((dr, dc, float(np.hypot(dr, dc))) for dr, dc in steps if dr or dc), key=lambda s: s[2])
    height, width = mask.shape
    distance = np.full(mask.shape, np.inf)
    distance[start] = 0.0
    parent = {start: None}
    queue, farthest = deque([start]), start
    # Breadth-first over the wire's pixels (steps of one pixel first, so distances follow the wire).
    while queue:
        r, c = queue.popleft()
        for dr, dc, length in steps:
            nr, nc = r + dr, c + dc
            if 0 <= nr < height and 0 <= nc < width and mask[nr, nc] and distance[nr, nc] == np.inf:
                distance[nr, nc] = distance[r, c] + length
                parent[(nr, nc)] = (r, c)
                queue.append((nr, nc))
                if distance[nr, nc] > distance[farthest]:
                    farthest = (nr, nc)
    path = [farthest]
    while parent[path[-1]] is not None:
        path.append(parent[path[-1]])
    return np.array([(c + 0.5, r + 0.5) for r, c in path])
