"""Patient coordinate frames a lumen mesh can come in, and their map into the simulator's frame.

The simulator's frame ("sim"): +x towards the patient's left, +y superior (towards the
head), +z anterior; the top camera looks along -z (the antero-posterior view). A CT
segmentation comes in the scanner's patient coordinates:

- "LPS" (DICOM, 3D Slicer's model export since 4.11: "SPACE=LPS" in the file header):
  +x left, +y posterior, +z superior;
- "RAS" (some tools): +x right, +y anterior, +z superior.

Each frame's matrix takes a point in that frame to the simulator's frame (a proper
rotation: a signed permutation of the axes, so the map is exact in floating point). The
scanner's origin is kept: a point keeps its distance from the origin.
"""

from __future__ import annotations

from typing import Dict

import numpy as np

SIM_FRAME = "sim"
FRAMES: Dict[str, np.ndarray] = {
    SIM_FRAME: np.eye(3),
    # sim x = L = x, sim y = S = z, sim z = A = -P = -y
    "LPS": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]),
    # sim x = L = -R = -x, sim y = S = z, sim z = A = y
    "RAS": np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]),
}
for _m in FRAMES.values():
    _m.setflags(write=False)


def frame_rotation(frame: str) -> np.ndarray:
    """The 3x3 rotation from `frame` to the simulator's frame; ValueError naming the choices."""
    if frame not in FRAMES:
        raise ValueError(f"frame={frame!r} is not valid; choose one of {list(FRAMES)}")
    return FRAMES[frame]


def sim_axes(frame: str) -> str:
    """The simulator's axes in terms of `frame`'s, e.g. "[x, z, -y]" for LPS: sim x = x, y = z, z = -y."""
    rows = frame_rotation(frame)
    return "[" + ", ".join(("-" if r.sum() < 0 else "") + "xyz"[int(np.argmax(np.abs(r)))] for r in rows) + "]"


def to_sim(points, frame: str) -> np.ndarray:
    """Points (..., 3) or one direction in `frame` expressed in the simulator's frame (same units)."""
    p = np.asarray(points, dtype=np.float64)
    if frame == SIM_FRAME:
        return p
    return p @ frame_rotation(frame).T + 0.0  # + 0.0: no -0.0 from the signs


def from_sim(points, frame: str) -> np.ndarray:
    """The inverse of `to_sim`."""
    p = np.asarray(points, dtype=np.float64)
    if frame == SIM_FRAME:
        return p
    return p @ frame_rotation(frame) + 0.0


def to_sim_matrix(frame: str, scale: float) -> np.ndarray:
    """4x4 homogeneous transform from a point in `frame` and the mesh's units to the simulator's
    frame in metres (`scale`: metres per mesh unit); its inverse maps the asset back."""
    m = np.eye(4)
    m[:3, :3] = frame_rotation(frame) * scale
    return m
