"""Crop an imported lumen to what the task needs, and smooth it locally (the importer's
`crop=auto` and its fold remedies).

A segmentation holds more vessel than a navigation task uses: the aortic root and the
ascending aorta below the arch, the distal ends of the branches, vertebral and coronary
stumps. Those regions are often the roughest of a scan (a decimated closed end, a cut
branch), and a fold there stopped imports that no path needed. `crop_to_paths` keeps the
lumen within a margin, measured through the lumen, of the entry-to-site paths: the
inscribed ball of every path point, grown `margin_m` further along the vessels. Past each
site a branch therefore keeps `margin_m`, and a vessel the paths do not use keeps
`margin_m` from where it leaves them. The rest is cut off where it leaves the kept region;
each cut closes as a cap across its vessel (the grown front of a tube is nearly a
cross-section).

Distances through the lumen grow one node at a time (on nodes about 1 mm apart),
alternating 6- and 26-neighbour steps: along the axes the front reaches the margin, along
diagonals up to 26% farther (20 steps from one node: 20.75 to 25.25 nodes).
"""

from __future__ import annotations

from typing import List, Sequence

import numpy as np
from scipy import ndimage

from cathsim_dmc.anatomy.polyline import resample_polyline
from cathsim_dmc.anatomy.sdf import SDFGrid

CAP_ROUNDING_M = 0.001  # the crop's caps are smoothed over this length (see remove_region)


def _node(grid: SDFGrid, p) -> tuple:
    n = np.array(grid.values.shape) - 1
    return tuple(np.clip(np.rint((np.asarray(p, dtype=np.float64) - grid.origin) / grid.spacing).astype(int), 0, n))


CROP_NODE_M = 0.001  # the crop's region is found on nodes about this far apart (the cut is then smoothed)


def path_tube(grid: SDFGrid, paths: Sequence[np.ndarray], stride: int = 1) -> np.ndarray:
    """Lumen nodes inside the inscribed ball (the lumen radius + 1 node) of a point of a path, on
    every `stride`-th node of the grid."""
    h = grid.spacing
    inside = grid.values[::stride, ::stride, ::stride] < 0
    pts = np.concatenate([resample_polyline(np.asarray(p, dtype=np.float64), 0.5 * h) for p in paths])
    radius = np.maximum(-grid(pts), 0.0) + stride * h
    n = np.array(inside.shape) - 1
    idx = np.clip(np.rint((pts - grid.origin) / (stride * h)).astype(int), 0, n)
    seeds = np.zeros(inside.shape, dtype=bool)
    ball = np.zeros(inside.shape, dtype=np.float32)
    # Where two path points share a node, the larger ball wins.
    order = np.argsort(radius)
    seeds[tuple(idx.T)] = True
    ball[tuple(idx[order].T)] = radius[order]
    dist, nearest = ndimage.distance_transform_edt(~seeds, return_indices=True)
    reach = ball[tuple(nearest)]
    del nearest
    return inside & (dist * stride * h <= reach)


def grow_within(seed: np.ndarray, inside: np.ndarray, distance_m: float, spacing: float) -> np.ndarray:
    """`seed` grown by `distance_m` through `inside` only (a distance through the lumen, see the module)."""
    steps = int(np.ceil(distance_m / spacing))
    face = ndimage.generate_binary_structure(3, 1)
    full = ndimage.generate_binary_structure(3, 3)
    grown = seed & inside
    # A 26-neighbour step covers sqrt(3) node lengths diagonally, a 6-neighbour one 1: alternating them
    # keeps the front between the margin (along the axes) and 26% beyond it (diagonally).
    for k in range(steps):
        grown = ndimage.binary_dilation(grown, full if k % 2 else face) & inside
    return grown


def remove_region(grid: SDFGrid, removed: np.ndarray, entry, round_m: float = 0.0) -> SDFGrid:
    """The lumen with the nodes of `removed` cut away (max(sdf, -sdf_removed) around them), keeping
    only the piece that holds the entry. `round_m` > 0 smooths the cut over that length (Gaussian
    sigma) within a few sigma of it: the node staircase of the cut and its rim's sharp edge become
    a smooth cap that a coarse remesh follows without denting the wall."""
    h = grid.spacing
    pad = 4 + int(np.ceil(4 * round_m / h))
    values = grid.values.copy()
    regions, count = ndimage.label(removed)
    # Each removed region in its own box: one box around them all can be most of the grid.
    for box in ndimage.find_objects(regions):
        box = tuple(slice(max(b.start - pad, 0), min(b.stop + pad, n)) for b, n in zip(box, removed.shape))
        sub = removed[box]
        sdf_removed = (
            np.where(
                sub,
                -np.maximum(ndimage.distance_transform_edt(sub) - 0.5, 0.0),
                np.maximum(ndimage.distance_transform_edt(~sub) - 0.5, 0.0),
            )
            * h
        )
        cut = np.maximum(values[box], -sdf_removed)
        if round_m > 0:
            near = np.abs(sdf_removed) < 3 * round_m
            cut = np.where(near, ndimage.gaussian_filter(cut, round_m / h, mode="nearest"), cut)
        values[box] = cut
    pieces, _ = ndimage.label(values < 0)
    e = _node(grid, entry)
    if pieces[e] > 0:
        values = np.where((values < 0) & (pieces != pieces[e]), h, values)
    return SDFGrid(origin=grid.origin, spacing=h, values=values)


def crop_to_paths(grid: SDFGrid, paths: Sequence[np.ndarray], entry, margin_m: float) -> "tuple[SDFGrid, List[str]]":
    """The lumen within `margin_m` (through the lumen) of `paths`, and a note on what was cut."""
    inside = grid.values < 0
    # Found on a coarser set of nodes (CROP_NODE_M apart): the growth is a loop over whole-grid
    # dilations, and the cut is smoothed over about that length anyway.
    stride = max(1, int(round(CROP_NODE_M / grid.spacing)))
    coarse = inside[::stride, ::stride, ::stride]
    kept = grow_within(path_tube(grid, paths, stride), coarse, margin_m, stride * grid.spacing)
    if stride > 1:  # a fine node takes a coarse neighbour's state: grown one coarse node, the lumen's rim is covered
        kept = ndimage.binary_dilation(kept, ndimage.generate_binary_structure(3, 3))
    for axis in range(3):
        kept = np.repeat(kept, stride, axis=axis)
    kept = kept[: inside.shape[0], : inside.shape[1], : inside.shape[2]]
    cut = inside & ~kept
    del kept
    if not cut.any():
        return grid, []
    _, regions = ndimage.label(cut)
    volume_mm3 = float(cut.sum()) * (grid.spacing * 1e3) ** 3
    share = float(cut.sum()) / float(inside.sum())
    cropped = remove_region(grid, cut, entry, round_m=CAP_ROUNDING_M)
    return cropped, [
        f"cropped {regions} region{'s' * (regions > 1)} more than {margin_m * 1e3:.0f} mm from every "
        f"entry-to-site path ({volume_mm3 / 1e3:.1f} cm^3, {100 * share:.0f}% of the lumen; crop=none "
        f"keeps them)"
    ]


def distance_to_paths_m(paths: Sequence[np.ndarray], point) -> float:
    """Straight-line distance (m) from `point` to the nearest point of `paths`."""
    pts = np.concatenate([resample_polyline(np.asarray(p, dtype=np.float64), 0.0005) for p in paths])
    return float(np.min(np.linalg.norm(pts - np.asarray(point, dtype=np.float64), axis=1)))


def _box_around(grid: SDFGrid, where, reach_m: float):
    """(the slices of the grid's nodes within `reach_m` of `where`, per axis, and each such
    node's distance from `where`, m)."""
    h = grid.spacing
    centre = np.array(_node(grid, where))
    r = int(np.ceil(reach_m / h))
    lo = np.maximum(centre - r, 0)
    hi = np.minimum(centre + r + 1, np.array(grid.values.shape))
    axes = [grid.origin[k] + h * np.arange(lo[k], hi[k]) for k in range(3)]
    x = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    return tuple(slice(a, b) for a, b in zip(lo, hi)), np.linalg.norm(x - np.asarray(where, dtype=np.float64), axis=-1)


def smooth_around(grid: SDFGrid, where, radius_m: float, sigma_m: float) -> SDFGrid:
    """The grid Gaussian-smoothed (`sigma_m`) within `radius_m` of `where`, blended smoothly into the
    rest over the outer third: a coarser volume where a surface would not mesh, the same elsewhere."""
    h = grid.spacing
    box, d = _box_around(grid, where, radius_m + 3 * sigma_m)
    values = grid.values.copy()
    smoothed = ndimage.gaussian_filter(values[box], sigma_m / h, mode="nearest")
    weight = np.clip((radius_m - d) / (radius_m / 3), 0.0, 1.0)
    values[box] = weight * smoothed + (1 - weight) * values[box]
    return SDFGrid(origin=grid.origin, spacing=h, values=values)


def thin_outside(values: np.ndarray, spacing: float, width_m: float) -> np.ndarray:
    """Bool per node: outside the lumen (`values` > 0, a signed distance) where no ball of diameter
    `width_m` fits in the outside around it: a septum between two lumens thinner than `width_m`, or
    the sharp crest of the ridge (carina) where two branches part."""
    r = 0.5 * width_m
    core = values >= r  # centres of the balls that fit
    if not core.any():
        return values > 0
    covered = ndimage.distance_transform_edt(~core) * spacing <= r
    return (values > 0) & ~covered


def thicken_septa(grid: SDFGrid, where, radius_m: float, width_m: float) -> "tuple[SDFGrid, float]":
    """(the grid with every septum and ridge crest within `radius_m` of `where` thickened to
    `width_m`, the thinnest septum found there (m)): the medial nodes of the thin outside
    (`thin_outside`) are pushed `width_m / 2` away from both lumens, which give up that much of
    their width next to it. A septum the mesher cannot resolve (thinner than a few grid nodes,
    or than its edges) folds or pinches the surface; a thicker one meshes. Elsewhere the grid
    is unchanged."""
    h = grid.spacing
    box, d = _box_around(grid, where, radius_m + 2 * width_m)
    sub = grid.values[box]
    near = d <= radius_m
    thin = thin_outside(sub, h, width_m) & near
    # The medial nodes: a thin node no neighbour of which lies deeper in the outside.
    ridge = thin & (sub >= ndimage.maximum_filter(sub, size=3) - 0.5 * h)
    if not ridge.any():
        return grid, float("inf")
    thinnest = 2.0 * float(sub[ridge].min())
    to_ridge = ndimage.distance_transform_edt(~ridge) * h
    values = grid.values.copy()
    values[box] = np.maximum(sub, 0.5 * width_m - to_ridge)
    return SDFGrid(origin=grid.origin, spacing=h, values=values), thinnest
