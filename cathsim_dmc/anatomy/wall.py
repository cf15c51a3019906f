"""The vessel wall: one convex collision prism per lumen triangle.

Every non-cap lumen triangle is extruded outward along the unit vertex normals
(`Lumen.normals`) into a 6-point convex prism. Neighbouring prisms share their
side edges (same vertices, same normals), so the wall has no gaps, and every
prism starts on the lumen surface, so no piece intrudes into it.
"""

from __future__ import annotations

import numpy as np

from cathsim_dmc.anatomy.lumen import Lumen
from cathsim_dmc.anatomy.triangles import face_normals


def extrude_prisms(lumen: Lumen, thickness: float, max_stretch: float = 1.6) -> np.ndarray:
    """(H, 6, 3) prisms: each wall triangle, then the same triangle offset outward (`thickness` in m).

    Every vertex moves along its unit vertex normal, so neighbouring prisms
    share their side edges. Where the normal leans away from an adjacent face
    (curved regions, e.g. the carinas between ostia), a plain offset of
    `thickness` would leave that face's prism thinner than `thickness` along its
    own normal; the offset is lengthened to thickness / cos(lean), capped at
    `max_stretch` x thickness, so the wall keeps its thickness everywhere.
    """
    f = lumen.faces[~lumen.cap]
    v, n = lumen.vertices, lumen.normals
    fn = face_normals(v, f)
    lean = np.ones(len(v))
    for c in range(3):
        np.minimum.at(lean, f[:, c], np.sum(n[f[:, c]] * fn, axis=1))
    offset = thickness / np.clip(lean, 1.0 / max_stretch, 1.0)
    outer = v + offset[:, None] * n
    return np.concatenate([v[f], outer[f]], axis=1)
