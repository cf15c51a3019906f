"""The vessel wall as a sampled distance field, with a compiled contact test.

`Aorta(wall="field")` puts the wall into the model as one geom of type SDF plus the
lumen's signed distance, sampled on a sparse grid, in a custom numeric field of the same
name (layout in ``native/wall_field.c``). MuJoCo calls its collision functions through a
table, `mjCOLLISIONFUNC`; `install` routes the table's SDF entries through the compiled
test, which answers for geoms that carry such a field and hands every other SDF geom back
to MuJoCo's own function. A capsule then costs one short walk along its axis through the
field instead of a convex test against each of the dozens of wall prisms around it.

The C source is compiled once per source and MuJoCo version with the system C compiler
(``cc``, or ``$CC``) into the cache folder, next to the compiled models.
"""

from __future__ import annotations

import ctypes
import glob
import hashlib
import os
import pathlib
import shutil
import subprocess
import tempfile
import threading

import mujoco
import numpy as np

from cathsim_dmc.anatomy import cache_root

FIELD_SPACING_M = 0.5e-3  # node spacing of the sampled field
FIELD_BAND_M = 3e-3  # nodes further than this from the lumen are not stored (no contact there)
FIELD_MAGIC = 7.07e6  # must match native/wall_field.c
HEADER = 12
BLOCK = 8

_SOURCE = pathlib.Path(__file__).with_name("native") / "wall_field.c"
_lock = threading.Lock()
_native: ctypes.CDLL | None = None

_double_p = np.ctypeslib.ndpointer(dtype=np.float64, flags="C_CONTIGUOUS")
_int_p = np.ctypeslib.ndpointer(dtype=np.int32, flags="C_CONTIGUOUS")


class NativeBuildError(RuntimeError):
    """The compiled contact test could not be built (no C compiler, or it failed)."""


def _libmujoco_path() -> str:
    folder = os.path.dirname(mujoco.__file__)
    found = sorted(
        glob.glob(os.path.join(folder, "libmujoco.so*")) + glob.glob(os.path.join(folder, "libmujoco*.dylib"))
    )
    if not found:
        raise NativeBuildError(f"no libmujoco shared library next to the mujoco package in {folder}")
    return found[0]


def _compile(target: pathlib.Path) -> None:
    wanted = os.environ.get("CC")
    compiler = shutil.which(wanted) if wanted else (shutil.which("cc") or shutil.which("gcc") or shutil.which("clang"))
    if not compiler:
        found = f"CC={wanted!r} is not an executable" if wanted else "no cc, gcc or clang on PATH"
        raise NativeBuildError(
            f"the distance-field wall (physics=fast_field) compiles its contact test once and needs a "
            f"C compiler ({found}; Debian: apt-get install gcc); physics=fast needs none"
        )
    include = os.path.join(os.path.dirname(mujoco.__file__), "include")
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=target.parent, suffix=".so.tmp")
    os.close(fd)
    command = [compiler, "-O2", "-shared", "-fPIC", "-I", include, str(_SOURCE), "-o", tmp, "-lm"]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        os.unlink(tmp)
        raise NativeBuildError(f"compiling {_SOURCE.name} failed ({' '.join(command)}):\n{result.stderr.strip()}")
    os.replace(tmp, target)  # atomic: parallel test workers never load a partial file


def source_digest() -> str:
    """Identifies the compiled code (its source and MuJoCo's version): the library's file
    name, and part of a compiled model's cache key, since the field is built by it."""
    return hashlib.sha256(_SOURCE.read_bytes() + mujoco.__version__.encode()).hexdigest()[:16]


def native() -> ctypes.CDLL:
    """The compiled contact test, built if needed and installed into MuJoCo's table."""
    global _native
    with _lock:
        if _native is not None:
            return _native
        target = cache_root().parent / "native" / f"wall_field-{source_digest()}.so"
        if not target.is_file():
            try:
                _compile(target)
            except OSError:  # a read-only cache folder: build in the temporary folder instead
                target = pathlib.Path(tempfile.gettempdir()) / f"cathsim_dmc-{os.getuid()}" / target.name
                if not target.is_file():
                    _compile(target)
        lib = ctypes.CDLL(str(target))
        lib.cathsim_wall_install.argtypes = [ctypes.c_void_p]
        lib.cathsim_wall_install.restype = ctypes.c_int
        lib.cathsim_wall_distance.argtypes = [_double_p, _double_p]
        lib.cathsim_wall_distance.restype = ctypes.c_double
        lib.cathsim_wall_mark_blocks.argtypes = [
            ctypes.c_int,
            _double_p,
            ctypes.c_double,
            _double_p,
            _int_p,
            ctypes.c_double,
            _double_p,
        ]
        lib.cathsim_wall_fill.argtypes = [
            ctypes.c_int,
            _double_p,
            _double_p,
            ctypes.c_double,
            _double_p,
            _int_p,
            ctypes.c_double,
            _double_p,
            ctypes.c_void_p,
            _double_p,
            _double_p,
        ]
        # The same library the mujoco bindings loaded (the loader shares one copy per file).
        libmujoco = ctypes.CDLL(_libmujoco_path())
        table = ctypes.addressof(ctypes.c_void_p.in_dll(libmujoco, "mjCOLLISIONFUNC"))
        lib.cathsim_wall_install(ctypes.c_void_p(table))
        _native = lib
        return lib


def pseudo_normals(triangles: np.ndarray) -> np.ndarray:
    """Per triangle (n, 7, 3): its unit face normal, then angle-weighted pseudo-normals of
    its three vertices and the pseudo-normals of its edges ab, bc, ca (sums of the faces
    on either side). Vertices and edges are matched by position (rounded to 1e-10 m)."""
    tri = np.asarray(triangles, dtype=np.float64)
    n = len(tri)
    face = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    face /= np.linalg.norm(face, axis=1, keepdims=True)
    _, vid = np.unique(tri.reshape(-1, 3).round(10), axis=0, return_inverse=True)
    vid = vid.reshape(n, 3)
    angles = np.empty((n, 3))
    for corner in range(3):
        a = tri[:, (corner + 1) % 3] - tri[:, corner]
        b = tri[:, (corner + 2) % 3] - tri[:, corner]
        cos = np.einsum("ij,ij->i", a, b) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
        angles[:, corner] = np.arccos(np.clip(cos, -1.0, 1.0))
    vertex = np.zeros((vid.max() + 1, 3))
    np.add.at(vertex, vid.ravel(), (angles[:, :, None] * face[:, None, :]).reshape(-1, 3))
    edges = np.sort(np.stack([vid[:, [0, 1]], vid[:, [1, 2]], vid[:, [2, 0]]], axis=1), axis=2)  # (n, 3, 2)
    _, eid = np.unique(edges.reshape(-1, 2), axis=0, return_inverse=True)
    edge = np.zeros((eid.max() + 1, 3))
    np.add.at(edge, eid.ravel(), np.repeat(face, 3, axis=0))
    return np.concatenate([face[:, None], vertex[vid], edge[eid.reshape(n, 3)]], axis=1)


def build_field(
    triangles, shift_m: float, cut=None, spacing_m: float = FIELD_SPACING_M, band_m: float = FIELD_BAND_M
) -> np.ndarray:
    """The numeric field's data (float64) for a lumen of outward-facing `triangles`.

    Args:
      triangles: (n, 3, 3) lumen triangles in world coordinates (metres), normals
        (right-handed) pointing out of the lumen.
      shift_m: where contacts measure their distance to: the lumen moved out by this
        much (the prism wall's contact margin, so that the margin acts on the lumen).
      cut: (point, outward normal) of a plane beyond which no node is stored (the
        vessel's open end, where the wire comes in), or None.
      spacing_m: node spacing in metres.
      band_m: nodes further than this from the lumen are not stored.
    """
    lib = native()
    tri = np.ascontiguousarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    lo = tri.reshape(-1, 3).min(axis=0) - band_m - spacing_m
    hi = tri.reshape(-1, 3).max(axis=0) + band_m + spacing_m
    origin = np.floor(lo / spacing_m) * spacing_m
    nb = np.ceil((hi - origin) / (spacing_m * BLOCK)).astype(np.int32)
    index = np.full(int(np.prod(nb)), -1.0)
    flat = np.ascontiguousarray(tri.reshape(-1))
    lib.cathsim_wall_mark_blocks(len(tri), flat, spacing_m, origin, nb, band_m, index)
    used = index > 0
    index[used] = np.arange(int(used.sum()), dtype=np.float64)
    data = np.full(int(used.sum()) * BLOCK**3, np.nan)
    best = np.full(len(data), np.inf)
    normals = np.ascontiguousarray(pseudo_normals(tri).reshape(-1))
    plane = None
    if cut is not None:
        plane = np.ascontiguousarray(np.concatenate([np.asarray(cut[0], float), np.asarray(cut[1], float)]))
    lib.cathsim_wall_fill(
        len(tri),
        flat,
        normals,
        spacing_m,
        origin,
        nb,
        band_m,
        index,
        None if plane is None else plane.ctypes.data_as(ctypes.c_void_p),
        data,
        best,
    )
    header = np.zeros(HEADER)
    header[0], header[1], header[2:5], header[5:8], header[8] = FIELD_MAGIC, spacing_m, origin, nb, shift_m
    return np.concatenate([header, index, data])


def distance(field: np.ndarray, points) -> np.ndarray:
    """The field's signed distance to the lumen (m, positive inside) at `points` (NaN
    where not stored), as the contact test reads it."""
    lib = native()
    field = np.ascontiguousarray(field, dtype=np.float64)
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    return np.array([lib.cathsim_wall_distance(field, p) for p in pts])
