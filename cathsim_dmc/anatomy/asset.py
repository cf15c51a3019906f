"""Aorta asset folders: write, read and validate; build one from `ArchParams`.

An asset folder (format_version 1) holds:

- ``meta.json``: name, units, description, sites, entry (position + unit
  insertion direction), centerlines (entry -> site polylines with the lumen
  radius at each point), wall thickness, bounds of the visual mesh, arch-type
  distance and CCA diameter measured on the geometry, and the generator
  parameters (so the build is reproducible). Extra keys: ``open_end`` (the
  plane disc where the wire enters; the visual mesh is closed there but no
  collision piece covers it), ``counts``, ``ostia`` (where each branch leaves
  the aorta; the validation samples densely around them), and for generated
  arches ``arch_type`` (measured class), ``tortuosity`` (path/chord of the arch
  and of each branch's first 3 cm), ``max_aortic_diameter_m`` and, when built
  with a mesher later than version 1, ``mesher_version`` (`lumen` module
  docstring; absent means 1, so the assets built before it keep their bytes); imported
  meshes ``import`` (repairs and notes) and, from a mesh in patient axes (``frame=LPS`` or
  ``RAS``), ``source_frame``: the frame, its units and the 4x4 transforms ``to_sim`` (a mesh
  point to the asset's metres) and ``from_sim`` (back; absent means the simulator's axes).
- ``visual.stl``: binary STL of the closed lumen surface, metres, outward normals.
- ``collision.npz``: ``vertices`` float32 (M, 3) and ``hull_offsets`` int32
  (H + 1,); hull i is ``vertices[hull_offsets[i]:hull_offsets[i + 1]]``, a
  convex point set (6 points for the wall prisms).

Everything is written deterministically (fixed STL header, no timestamps,
canonical vertex order, fixed float rounding in JSON), so the same parameters
give byte-identical files.
"""

from __future__ import annotations

import dataclasses
import io
import json
import pathlib
import re
import time
import zipfile
from typing import Dict, Mapping, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from cathsim_dmc.anatomy.polyline import polyline_length

FORMAT_VERSION = 1
META_FILE = "meta.json"
VISUAL_FILE = "visual.stl"
COLLISION_FILE = "collision.npz"
_STL_HEADER = b"cathsim-dmc lumen surface, metres".ljust(80, b" ")
_STL_DTYPE = np.dtype([("normal", "<f4", (3,)), ("v", "<f4", (3, 3)), ("attr", "<u2")])
_JSON_DECIMALS = 8  # 10 nm: far below any meshing tolerance


class Centerline(NamedTuple):
    points: np.ndarray  # (N, 3) metres, from the entry to the site
    radius: np.ndarray  # (N,) lumen radius at each point, metres


@dataclasses.dataclass(frozen=True)
class AortaAsset:
    """A loaded aorta asset. Arrays are read-only."""

    path: pathlib.Path
    name: str
    meta: dict
    sites: Dict[str, np.ndarray]
    entry_position: np.ndarray
    entry_direction: np.ndarray
    centerlines: Dict[str, Centerline]
    wall_thickness_m: float
    bounds: np.ndarray  # (2, 3): min, max of the visual mesh
    arch_type_distance_m: Optional[float]
    cca_diameter_m: Optional[float]
    visual_vertices: np.ndarray  # (V, 3) float32
    visual_faces: np.ndarray  # (F, 3) int32
    hull_vertices: np.ndarray  # (M, 3) float32
    hull_offsets: np.ndarray  # (H + 1,) int32
    params: dict

    @property
    def hull_count(self) -> int:
        return len(self.hull_offsets) - 1

    @property
    def hulls(self) -> Tuple[np.ndarray, ...]:
        """Each collision hull as its own (k, 3) float32 array."""
        o = self.hull_offsets
        return tuple(self.hull_vertices[o[i] : o[i + 1]] for i in range(len(o) - 1))


# ----------------------------------------------------------------------------
# Low-level file formats


def _write_stl(path: pathlib.Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    v = np.asarray(vertices, dtype=np.float32)
    tri = v[np.asarray(faces)]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).astype(np.float64)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    rec = np.zeros(len(tri), dtype=_STL_DTYPE)
    rec["normal"] = n.astype(np.float32)
    rec["v"] = tri
    with open(path, "wb") as fh:
        fh.write(_STL_HEADER)
        fh.write(np.uint32(len(tri)).tobytes())
        fh.write(rec.tobytes())


def _read_stl(path: pathlib.Path) -> Tuple[np.ndarray, np.ndarray]:
    data = path.read_bytes()
    if len(data) < 84:
        raise ValueError(f"Aorta asset file {path} is not a binary STL (too short).")
    count = int(np.frombuffer(data, "<u4", 1, 80)[0])
    if len(data) != 84 + count * _STL_DTYPE.itemsize:
        raise ValueError(
            f"Aorta asset file {path} is not a binary STL: {count} triangles "
            f"declared but the file has {len(data)} bytes."
        )
    rec = np.frombuffer(data, _STL_DTYPE, count, 84)
    corners = rec["v"].reshape(-1, 3)
    # STL repeats shared vertices; merge exact duplicates to recover the indexed mesh.
    vertices, inverse = np.unique(corners, axis=0, return_inverse=True)
    return vertices.astype(np.float32), inverse.reshape(-1, 3).astype(np.int32)


def _write_npz(path: pathlib.Path, arrays: Mapping[str, np.ndarray]) -> None:
    """Deterministic compressed npz: fixed member order, zip timestamps and modes."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for key in sorted(arrays):
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.ascontiguousarray(arrays[key]), allow_pickle=False)
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, buf.getvalue())


def json_rounded(x):
    """JSON-ready nested lists rounded to 8 decimals (10 nm for metres): deterministic, compact."""
    a = np.asarray(x, dtype=np.float64)
    a = np.round(a, _JSON_DECIMALS) + 0.0  # + 0.0 turns -0.0 into 0.0
    return a.tolist()


def _dump_json(obj) -> str:
    """Indented JSON with every innermost list of numbers on one line."""
    text = json.dumps(obj, indent=1, allow_nan=False)
    flat = lambda m: "[" + ", ".join(x.strip() for x in m.group(1).split(",")) + "]"
    return re.sub(r"\[\s*([-+0-9.eE,\s]+?)\s*\]", flat, text) + "\n"


def _json_params(params: Mapping) -> dict:
    out = {}
    for k, v in params.items():
        out[k] = round(v, 12) if isinstance(v, float) else v
    return out


# ----------------------------------------------------------------------------
# Writing


def write_asset(
    folder,
    *,
    name: str,
    description: str,
    vertices: np.ndarray,
    faces: np.ndarray,
    hulls: Sequence[np.ndarray],
    sites: Mapping[str, Sequence[float]],
    entry_position: Sequence[float],
    entry_direction: Sequence[float],
    centerlines: Mapping[str, Tuple[np.ndarray, np.ndarray]],
    wall_thickness_m: float,
    params: Mapping,
    arch_type_distance_m: Optional[float] = None,
    cca_diameter_m: Optional[float] = None,
    extra: Optional[Mapping] = None,
) -> pathlib.Path:
    """Write an asset folder (format_version 1). Returns the folder path.

    `vertices`/`faces`: the closed lumen surface (outward normals) in metres.
    `hulls`: convex point sets (an (H, k, 3) array or a list of (k_i, 3) arrays).
    `centerlines`: name -> (points (N, 3), radius (N,)), entry to site.
    """
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    v32 = vertices.astype(np.float32)
    if len(np.unique(v32, axis=0)) != len(v32):
        raise ValueError("Lumen vertices collide after rounding to float32; the mesh is too fine.")

    hull_list = [np.asarray(h, dtype=np.float32) for h in hulls]
    sizes = np.array([len(h) for h in hull_list], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int32)
    hull_vertices = (np.concatenate(hull_list) if hull_list else np.zeros((0, 3))).astype(np.float32)

    direction = np.asarray(entry_direction, dtype=np.float64)
    direction = direction / np.linalg.norm(direction)
    bounds = np.stack([v32.min(axis=0), v32.max(axis=0)]).astype(np.float64)
    meta = {
        "format_version": FORMAT_VERSION,
        "name": name,
        "units": "m",
        "description": description,
        "sites": {k: json_rounded(sites[k]) for k in sorted(sites)},
        "entry": {"position": json_rounded(entry_position), "direction": json_rounded(direction)},
        "centerlines": {
            k: {"points": json_rounded(centerlines[k][0]), "radius_m": json_rounded(centerlines[k][1])}
            for k in sorted(centerlines)
        },
        "wall_thickness_m": float(wall_thickness_m),
        "bounds": json_rounded(bounds),
        "arch_type_distance_m": None if arch_type_distance_m is None else json_rounded(arch_type_distance_m),
        "cca_diameter_m": None if cca_diameter_m is None else json_rounded(cca_diameter_m),
        "params": _json_params(params),
    }
    if extra:
        meta.update({k: v for k, v in extra.items() if k not in meta})
    (folder / META_FILE).write_text(_dump_json(meta))
    _write_stl(folder / VISUAL_FILE, v32, faces)
    _write_npz(folder / COLLISION_FILE, {"vertices": hull_vertices, "hull_offsets": offsets})
    return folder


# ----------------------------------------------------------------------------
# Reading


def _bad(path, what):
    return ValueError(f"Aorta asset {path}: {what}.")


def _vec3(path, key, value):
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise _bad(path, f"'{key}' must be a finite [x, y, z] list, got {value!r}")
    return a


def _readonly(a):
    a = np.array(a)
    a.setflags(write=False)
    return a


def load_asset(path) -> AortaAsset:
    """Load and validate an asset folder. Raises FileNotFoundError/ValueError with one clear sentence."""
    folder = pathlib.Path(path)
    if not folder.is_dir():
        raise FileNotFoundError(f"Aorta asset folder {folder} does not exist.")
    for fname in (META_FILE, VISUAL_FILE, COLLISION_FILE):
        if not (folder / fname).is_file():
            raise FileNotFoundError(f"Aorta asset {folder} is missing {fname}.")
    meta_path = folder / META_FILE
    try:
        meta = json.loads(meta_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"Aorta asset file {meta_path} is not valid JSON ({exc}).") from None
    if not isinstance(meta, dict):
        raise _bad(meta_path, "the top level must be a JSON object")
    version = meta.get("format_version")
    if version != FORMAT_VERSION:
        raise ValueError(
            f"Aorta asset {meta_path} has format_version {version!r}; "
            f"this cathsim-dmc reads format_version {FORMAT_VERSION}."
        )
    required = ("name", "units", "sites", "entry", "centerlines", "wall_thickness_m", "bounds", "params")
    for key in required:
        if key not in meta:
            raise _bad(meta_path, f"missing key '{key}'")
    if meta["units"] != "m":
        raise _bad(meta_path, f"units must be 'm', got {meta['units']!r}")

    sites = {k: _readonly(_vec3(meta_path, f"sites.{k}", v)) for k, v in meta["sites"].items()}
    if not sites:
        raise _bad(meta_path, "'sites' is empty")
    entry = meta["entry"]
    if not isinstance(entry, dict) or "position" not in entry or "direction" not in entry:
        raise _bad(meta_path, "'entry' must have 'position' and 'direction'")
    entry_pos = _vec3(meta_path, "entry.position", entry["position"])
    entry_dir = _vec3(meta_path, "entry.direction", entry["direction"])
    if abs(np.linalg.norm(entry_dir) - 1.0) > 1e-6:
        raise _bad(meta_path, f"'entry.direction' must be a unit vector, got {entry['direction']!r}")
    centerlines = {}
    for k, c in meta["centerlines"].items():
        try:
            pts = np.asarray(c["points"], dtype=np.float64)
            rad = np.asarray(c["radius_m"], dtype=np.float64)
        except (KeyError, TypeError, ValueError):
            raise _bad(meta_path, f"centerline '{k}' must have 'points' (N x 3) and 'radius_m' (N)") from None
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2 or rad.shape != (len(pts),):
            raise _bad(meta_path, f"centerline '{k}' must have 'points' (N x 3, N >= 2) and 'radius_m' (N)")
        centerlines[k] = Centerline(_readonly(pts), _readonly(rad))
    missing = sorted(set(sites) - set(centerlines))
    if missing:
        raise _bad(meta_path, f"sites {missing} have no centerline")
    bounds = np.asarray(meta["bounds"], dtype=np.float64)
    if bounds.shape != (2, 3):
        raise _bad(meta_path, f"'bounds' must be [[xmin, ymin, zmin], [xmax, ymax, zmax]], got {meta['bounds']!r}")

    vis_v, vis_f = _read_stl(folder / VISUAL_FILE)
    col_path = folder / COLLISION_FILE
    try:
        with np.load(col_path, allow_pickle=False) as npz:
            hv = np.asarray(npz["vertices"])
            ho = np.asarray(npz["hull_offsets"])
    except KeyError as exc:
        raise _bad(col_path, f"missing array {exc}") from None
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise ValueError(f"Aorta asset file {col_path} is not a readable npz ({exc}).") from None
    if hv.dtype != np.float32 or hv.ndim != 2 or hv.shape[1] != 3:
        raise _bad(col_path, f"'vertices' must be float32 (M, 3), got {hv.dtype} {hv.shape}")
    if (
        ho.dtype != np.int32
        or ho.ndim != 1
        or len(ho) < 2
        or ho[0] != 0
        or ho[-1] != len(hv)
        or np.any(np.diff(ho) < 4)
    ):
        raise _bad(
            col_path,
            "'hull_offsets' must be int32, start at 0, end at len(vertices) and give every hull at least 4 points",
        )

    def opt(key):
        v = meta.get(key)
        return None if v is None else float(v)

    return AortaAsset(
        path=folder,
        name=str(meta["name"]),
        meta=meta,
        sites=sites,
        entry_position=_readonly(entry_pos),
        entry_direction=_readonly(entry_dir),
        centerlines=centerlines,
        wall_thickness_m=float(meta["wall_thickness_m"]),
        bounds=_readonly(bounds),
        arch_type_distance_m=opt("arch_type_distance_m"),
        cca_diameter_m=opt("cca_diameter_m"),
        visual_vertices=_readonly(vis_v),
        visual_faces=_readonly(vis_f),
        hull_vertices=_readonly(hv),
        hull_offsets=_readonly(ho),
        params=dict(meta["params"]),
    )


# ----------------------------------------------------------------------------
# Building from parameters


@dataclasses.dataclass(frozen=True)
class BuildReport:
    path: pathlib.Path
    triangles: int
    hulls: int
    seconds: float
    arch_type_distance_m: float
    cca_diameter_m: float
    arch_type: str
    path_length_m: Dict[str, float]
    tortuosity: Dict[str, float] = dataclasses.field(default_factory=dict)
    max_aortic_diameter_m: float = 0.0
    obliquity_deg: float = 0.0  # BCA-LSA ostia line from the coronal plane (ArchModel.obliquity_deg)
    mesher_version: int = 1  # lumen.build_lumen's

    @property
    def arch_type_ratio(self) -> float:
        return self.arch_type_distance_m / self.cca_diameter_m


# Generator fields added after assets were shipped: written to meta.json (and hashed
# for the cache) only when they differ from these defaults, so that every asset and
# cache key made before them stays the same, byte for byte.
LATER_FIELD_DEFAULTS = {
    "arch_rotation_deg": 0.0,
    "bca_takeoff_deg": 0.0,
    "lcca_takeoff_deg": 0.0,
    "lsa_takeoff_deg": 0.0,
    "bca_roll_deg": 0.0,
    "lcca_roll_deg": 0.0,
    "lsa_roll_deg": 0.0,
    "branch_tortuosity_amplitude_m": 0.0,
    "branch_tortuosity_wavelength_m": 0.030,
}


def params_record(params) -> dict:
    """The generator parameters as meta.json stores them (`LATER_FIELD_DEFAULTS`)."""
    record = dataclasses.asdict(params)
    for key, default in LATER_FIELD_DEFAULTS.items():
        if record.get(key) == default:
            del record[key]
    return record


# meta.json records `mesher_version` only from version 2 on: an asset without it was built
# with version 1 (every asset made before the key existed, the shipped ones included).
UNRECORDED_MESHER_VERSION = 1

# The shipped presets are built with the version-1 mesher (scripts/build_assets.py), which
# pinches narrow branches on some arches (lumen module docstring; the shipped ones keep
# 0.76-0.87 of their nominal branch radius, experiments/lumen_radius.py), because their expert,
# containment and learning tables were measured on the version-1 meshes: rebuilding them
# would invalidate those tables. When the tables are re-run, rebuild these assets at
# lumen.MESHER_VERSION (drop them from here) in the same change. A preset not listed is
# built at the current version.
SHIPPED_MESHER_VERSIONS = {
    name: 1
    for name in (
        "type1",
        "type2",
        "type3",
        "aneurysm",
        "low_tortuosity",
        "bovine",
        "type1_oblique",
        "type2_oblique",
        "type3_oblique",
    )
}


def recorded_mesher_version(meta: Mapping) -> int:
    """The lumen mesher version an asset's meta.json says it was built with."""
    return int(meta.get("mesher_version", UNRECORDED_MESHER_VERSION))


def build_asset(params, folder, mesher_version: Optional[int] = None) -> BuildReport:
    """Generate the arch described by `params` and write it to `folder`.

    `mesher_version`: `lumen.build_lumen`'s; None is the current `lumen.MESHER_VERSION`
    (the shipped presets pin theirs: `SHIPPED_MESHER_VERSIONS`).
    """
    from cathsim_dmc.anatomy.arch import build_arch, path_to_site
    from cathsim_dmc.anatomy.lumen import MESHER_VERSION, build_lumen
    from cathsim_dmc.anatomy.parameters import BRANCHES
    from cathsim_dmc.anatomy.sdf import unsigned_distance
    from cathsim_dmc.anatomy.wall import extrude_prisms

    mesher_version = MESHER_VERSION if mesher_version is None else int(mesher_version)
    t0 = time.perf_counter()
    model = build_arch(params)
    lumen = build_lumen(model, mesher_version=mesher_version)
    prisms = extrude_prisms(lumen, params.wall_thickness_m)
    centerlines, lengths = {}, {}
    wall = lumen.faces[~lumen.cap]
    for b in BRANCHES:
        pts = path_to_site(model, b)
        # Lumen radius = distance to the wall (the open end is not wall).
        centerlines[b] = (pts, unsigned_distance(lumen.vertices, wall, pts))
        lengths[b] = polyline_length(pts)
    p = model.params
    tortuosity = model.tortuosity()
    max_diameter = 2.0 * float(model.aorta.radius.max())
    if model.arch_type_measured != p.arch_type:
        raise ValueError(
            f"ArchParams '{p.name}' is labelled arch type {p.arch_type} but its BCA origin lies "
            f"{model.arch_type_distance_m / model.cca_diameter_m:.2f} CCA diameters below the arch top "
            f"(type {model.arch_type_measured}); fix bca_origin_drop_m or arch_type."
        )
    description = (
        f"Procedural aortic arch '{p.name}' (arch type {p.arch_type}, measured "
        f"{model.arch_type_measured}): descending aorta (open inferior end, wire entry), arch, "
        f"ascending aorta closed at the root; BCA, LCCA, LSA closed {p.branch_length_m('bca') * 100:.1f}/"
        f"{p.branch_length_m('lcca') * 100:.1f}/{p.branch_length_m('lsa') * 100:.1f} cm past their ostia. "
        f"Lumen: smooth union of tapered tubes ({p.blend_radius_m * 1e3:.0f} mm blend); "
        f"wall: one {p.wall_thickness_m * 1e3:.0f} mm prism per lumen triangle."
    )
    if p.bovine:
        description += " Bovine arch: the BCA and LCCA share one ostium."
    if p.aneurysm_diameter_m > 0:
        description += f" Aortic aneurysm of {max_diameter * 1e3:.0f} mm diameter."
    if p.tortuosity_amplitude_m > 0:
        description += f" Tortuous descending aorta ({p.tortuosity_amplitude_m * 1e3:.0f} mm lateral amplitude)."
    write_asset(
        folder,
        name=p.name,
        description=description,
        vertices=lumen.vertices,
        faces=lumen.faces,
        hulls=prisms,
        sites={b: model.sites[b] for b in BRANCHES},
        entry_position=model.entry_position,
        entry_direction=model.entry_direction,
        centerlines=centerlines,
        wall_thickness_m=p.wall_thickness_m,
        params=params_record(p),
        arch_type_distance_m=model.arch_type_distance_m,
        cca_diameter_m=model.cca_diameter_m,
        extra={
            "open_end": {
                "center": json_rounded(model.open_end_center),
                "normal": [0.0, -1.0, 0.0],
                "radius_m": json_rounded(model.open_end_radius),
            },
            "counts": {"triangles": int(len(lumen.faces)), "hulls": int(len(prisms))},
            "arch_type": model.arch_type_measured,
            **({"arch_obliquity_deg": round(model.obliquity_deg, 3)} if p.arch_rotation_deg else {}),
            "ostia": {b: json_rounded(model.ostia[b]) for b in BRANCHES},
            "tortuosity": {k: round(v, 6) for k, v in tortuosity.items()},
            "max_aortic_diameter_m": json_rounded(max_diameter),
            **({"mesher_version": mesher_version} if mesher_version != UNRECORDED_MESHER_VERSION else {}),
        },
    )
    return BuildReport(
        path=pathlib.Path(folder),
        triangles=int(len(lumen.faces)),
        hulls=int(len(prisms)),
        seconds=time.perf_counter() - t0,
        arch_type_distance_m=model.arch_type_distance_m,
        cca_diameter_m=model.cca_diameter_m,
        arch_type=model.arch_type_measured,
        path_length_m=lengths,
        tortuosity=tortuosity,
        max_aortic_diameter_m=max_diameter,
        obliquity_deg=model.obliquity_deg,
        mesher_version=mesher_version,
    )
