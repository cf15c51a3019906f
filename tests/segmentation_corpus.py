"""Segmentation-style lumen meshes made from the project's own type I arch, for the importer's tests.

What a user exports from a CT segmentation, and what the strict surface repair
refuses or mishandles:

- ``noisy``: the isosurface of a binary voxel mask (1 mm voxels, lightly
  smoothed, like a labelmap's surface export) with 0.1 mm vertex noise: terraced,
  many thin triangles;
- ``decimated``: that surface decimated by vertex clustering (2.5 mm cells):
  collapsed and duplicate triangles, self-intersections, and edges shared by
  three or more triangles (pinches);
- ``pinched``: the noisy surface with extra triangles hung on a few of its edges
  (non-manifold fins, as left by a voxel-to-mesh export where voxels touch at an edge);
- ``stump``: a 2.8 mm side branch, 7 mm long, on the ascending aorta (a coronary stump);
- ``wall_shell``: an outer surface 2 mm outside the lumen plus the lumen surface
  turned inward: the vessel wall as a solid, not the lumen.

Every variant is written in millimetres (as segmentation tools export) with the
arch's entry and target sites, in millimetres too.
"""

from __future__ import annotations

import functools
import pathlib

import numpy as np
import trimesh
from scipy import ndimage

from cathsim_dmc.anatomy import PRESETS, build_arch
from cathsim_dmc.anatomy.isosurface import zero_surface
from cathsim_dmc.anatomy.sdf import arch_sdf_grid

VARIANTS = ("noisy", "decimated", "pinched", "stump", "wall_shell")
VOXEL_M = 0.001                      # about 260k triangles; 0.0009 gives about 320k


@functools.lru_cache(maxsize=1)
def _arch():
    model = build_arch(PRESETS["type1"])
    return model, arch_sdf_grid(model)


def _resampled(grid, spacing):
    """The grid's SDF trilinearly resampled at `spacing` (m): (values, origin)."""
    zoom = grid.spacing / spacing
    values = ndimage.zoom(grid.values, zoom, order=1, mode="nearest")
    return values, grid.origin


def _stump_sdf(model, origin, spacing, shape):
    """Signed distance (m) of a capsule on the ascending aorta, pointing anterior (+z)."""
    aorta = model.aorta
    s = aorta.arclength
    i = int(np.searchsorted(s, s[-1] - 0.015))
    p0 = aorta.points[i]
    tangent = aorta.points[min(i + 1, len(s) - 1)] - aorta.points[max(i - 1, 0)]
    out = np.cross(tangent, [1.0, 0.0, 0.0])
    out /= np.linalg.norm(out)
    if out[2] < 0:
        out = -out
    p1 = p0 + (aorta.radius[i] + 0.007) * out
    axes = [origin[k] + spacing * np.arange(shape[k]) for k in range(3)]
    x = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    t = np.clip(((x - p0) @ (p1 - p0)) / np.dot(p1 - p0, p1 - p0), 0.0, 1.0)
    return np.linalg.norm(x - (p0 + t[..., None] * (p1 - p0)), axis=-1) - 0.0014


def _mask_surface(inside: np.ndarray, origin, spacing):
    """Isosurface of a binary mask, smoothed over about one voxel (a labelmap's surface export)."""
    field = 0.5 - ndimage.gaussian_filter(inside.astype(np.float64), 0.7)
    return zero_surface(field, origin, spacing)


def _noise(v, rng, sigma=0.0001):
    return v + rng.normal(0.0, sigma, v.shape)


def _cluster(v, f, cell):
    """Vertex-clustering decimation: every vertex moves to its cell's mean; collapsed triangles go."""
    key = np.floor(v / cell).astype(np.int64)
    _, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    centres = np.zeros((inverse.max() + 1, 3))
    np.add.at(centres, inverse, v)
    centres /= np.bincount(inverse)[:, None]
    g = inverse[f]
    keep = (g[:, 0] != g[:, 1]) & (g[:, 1] != g[:, 2]) & (g[:, 0] != g[:, 2])
    return centres, g[keep]


def make_variant(name: str, folder, voxel_m: float = VOXEL_M) -> "tuple[pathlib.Path, np.ndarray, dict]":
    """Write variant `name` to `folder`, from a voxel mask of `voxel_m`: (mesh path, entry in mm, sites in mm)."""
    if name not in VARIANTS:
        raise ValueError(f"variant {name!r} is not one of {VARIANTS}")
    model, grid = _arch()
    rng = np.random.default_rng(VARIANTS.index(name))
    values, origin = _resampled(grid, voxel_m)
    if name == "stump":
        values = np.minimum(values, _stump_sdf(model, origin, voxel_m, values.shape))
    inside = values < 0
    v, f = _mask_surface(inside, origin, voxel_m)
    v = _noise(v, rng)
    if name == "decimated":
        v, f = _cluster(v, f, 0.0025)
    elif name == "pinched":
        # Fins: a third triangle on a few edges, to a vertex just off the surface.
        edges = trimesh.Trimesh(v, f, process=False).edges_unique
        pick = rng.choice(len(edges), 6, replace=False)
        tips = v[edges[pick, 0]] + rng.normal(0.0, 0.0003, (6, 3))
        f = np.concatenate([f, np.column_stack([edges[pick], len(v) + np.arange(6)])])
        v = np.concatenate([v, tips])
    elif name == "wall_shell":
        outer_v, outer_f = _mask_surface(values < 0.002, origin, voxel_m)
        f = np.concatenate([outer_f, f[:, ::-1] + len(outer_v)])
        v = np.concatenate([_noise(outer_v, rng), v])
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"type1_{name}.stl"
    trimesh.Trimesh(v * 1e3, f, process=False).export(path)
    return path, model.entry_position * 1e3, {k: p * 1e3 for k, p in model.sites.items()}
