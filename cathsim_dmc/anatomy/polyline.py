"""Polylines (centerlines, paths to the sites): arc length, length and resampling. Metres."""

from __future__ import annotations

import math

import numpy as np


def arclength(points: np.ndarray) -> np.ndarray:
    """(N,) distance along the polyline (N, 3) from its first point to each point."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])


def polyline_length(points: np.ndarray) -> float:
    """Total length of the polyline (N, 3)."""
    return float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)))


def resample_polyline(points: np.ndarray, spacing_m: float) -> np.ndarray:
    """The polyline at (nearly) uniform arc-length spacing <= `spacing_m`, both ends kept.

    Repeated points are dropped first: they would give np.interp a zero-length step.
    """
    points = np.asarray(points, dtype=np.float64)
    d = np.linalg.norm(np.diff(points, axis=0), axis=1)
    points = np.concatenate([points[:1], points[1:][d > 1e-12]])
    s = arclength(points)
    n = max(2, int(math.ceil(s[-1] / spacing_m)) + 1)
    t = np.linspace(0.0, s[-1], n)
    return np.stack([np.interp(t, s, points[:, k]) for k in range(3)], axis=1)
