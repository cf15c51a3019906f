"""The error a mesh import raises, and how its messages print a point."""

from __future__ import annotations

import numpy as np


class MeshImportError(ValueError):
    """A mesh that cannot be imported; the message is one line naming the file and the problem."""


def format_point(p, scale=1.0, digits=1) -> str:
    """`p` / `scale` as "[x, y, z]" with `digits` decimals, for one-line error messages."""
    return "[" + ", ".join(f"{x / scale:.{digits}f}" for x in np.asarray(p, dtype=float)) + "]"
