"""Choose MuJoCo's OpenGL backend before dm_control is imported.

dm_control reads ``MUJOCO_GL`` once, at import time. On a machine without a display
(a server, CI) the default GLFW backend cannot create a context, so we pick a headless
one: EGL (Mesa llvmpipe or a GPU driver) if its library is present, else OSMesa. A
user's own ``MUJOCO_GL`` always wins.
"""

from __future__ import annotations

import ctypes.util
import os

# Debian packages that provide each backend (installed by scripts/setup.sh).
GL_PACKAGES = {
    "egl": "libegl1 libgl1-mesa-dri libopengl0",
    "osmesa": "libosmesa6",
}


def _library_present(name: str) -> bool:
    return ctypes.util.find_library(name) is not None


def select_backend() -> str:
    """Set ``MUJOCO_GL`` (if unset) to a backend that works here; return its value."""
    chosen = os.environ.get("MUJOCO_GL")
    if chosen:
        return chosen
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        chosen = "glfw"
    elif _library_present("EGL"):
        chosen = "egl"
    elif _library_present("OSMesa"):
        chosen = "osmesa"
    else:
        # Leave it to dm_control; render() will fail with `missing_backend_message`.
        return ""
    os.environ["MUJOCO_GL"] = chosen
    return chosen


def missing_backend_message() -> str:
    return (
        "cannot render: no OpenGL backend for MuJoCo. Install EGL "
        f"(apt-get install {GL_PACKAGES['egl']}) or OSMesa "
        f"(apt-get install {GL_PACKAGES['osmesa']}); without a display, import cathsim_dmc before "
        "dm_control or set MUJOCO_GL=egl."
    )
