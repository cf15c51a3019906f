"""Rebuild a lumen from a defective surface through a voxel volume (the importer's `repair=volume`).

Segmentation exports are often not a clean closed surface: edges shared by three
or more triangles (pinches where two voxels touch at an edge), self-intersections
after decimation, small gaps, folded slivers, an outer wall surface around the
lumen, side-branch stumps. None of that matters to a volume:

1. **voxelise**: grid nodes next to the triangles (sampled every half node) form
   a thin shell; the outside is what a flood fill from the grid border reaches
   without crossing it. If the flood reaches the entry or a site, the shell is
   thickened one node at a time (a morphological closing) until it does not,
   up to `max_gap_m`: gaps narrower than that are closed. Flat open vessel ends
   are capped first, since they are wider than any closing should be;
2. **keep the lumen**: the connected piece of the inside that holds the entry (and
   must hold the sites). Anything else is dropped: loose pieces, and for a wall
   shell (an inner and an outer surface) the wall between them; pockets enclosed
   by the lumen (closed shells inside it) are filled;
3. **signed distance**: to the nearest surface sample near the shell, a distance
   transform further away, the sign from the classification; optionally
   Gaussian-smoothed (`smooth_m`);
4. **trim** (`trim_side_branches`): side branches narrower than a diameter, that no
   entry-to-site path uses (coronary or intercostal stumps), are cut off.

The result is an `SDFGrid` the importer meshes like a generated arch.
"""

from __future__ import annotations

from typing import Callable, List, Mapping, Sequence

import numpy as np
from scipy import ndimage, spatial

from cathsim_dmc.anatomy.polyline import resample_polyline
from cathsim_dmc.anatomy.sdf import SDFGrid
from cathsim_dmc.anatomy.triangles import boundary_loops, fan_triangles


class VolumeError(ValueError):
    """The volume cannot give a lumen (the importer adds the file name)."""


def _fmt_mm(p) -> str:
    return "[" + ", ".join(f"{x * 1e3:.1f}" for x in np.asarray(p, dtype=float)) + "] mm"


def cap_flat_ends(v: np.ndarray, f: np.ndarray, max_out_of_plane: float = 0.05):
    """(faces with a fan over every flat boundary loop, vertices with the fan centres, caps made).

    A soup whose boundary does not form simple loops is returned as it is: the
    closing in `volume_sdf_grid` deals with small gaps."""
    loops = boundary_loops(f)
    if not loops:
        return v, f, 0
    added, caps = [], []
    for loop in loops:
        p = v[loop]
        c = p.mean(axis=0)
        _, _, vt = np.linalg.svd(p - c)
        size = float(np.max(np.linalg.norm(p - c, axis=1)))
        if len(loop) < 5 or float(np.max(np.abs((p - c) @ vt[2]))) > max_out_of_plane * size:
            continue
        caps.append(fan_triangles(loop, len(v) + len(added)))
        added.append(c)
    if not caps:
        return v, f, 0
    return np.concatenate([v, np.array(added)]), np.concatenate([f] + caps), len(caps)


def surface_samples(v: np.ndarray, f: np.ndarray, max_spacing: float) -> np.ndarray:
    """Points on every triangle no further than `max_spacing` apart (vertices included)."""
    tri = v[f]
    longest = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
    n = np.maximum(np.ceil(longest / max_spacing).astype(int), 1)
    out = [v[np.unique(f)]]  # vertices no triangle uses are not surface
    for k in np.unique(n):
        sel = tri[n == k]
        # Barycentric lattice with k divisions per edge.
        i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
        keep = i + j <= k
        a, b = i[keep] / k, j[keep] / k
        w = np.stack([1 - a - b, a, b], axis=1)  # (L, 3)
        out.append(np.einsum("lc,tcd->tld", w, sel).reshape(-1, 3))
    return np.concatenate(out)


def volume_sdf_grid(
    v: np.ndarray,
    f: np.ndarray,
    spacing: float,
    pad: float,
    entry: np.ndarray,
    sites: Mapping[str, np.ndarray],
    *,
    max_gap_m: float = 0.002,
    smooth_m: float = 0.0,
    max_nodes: int = 60_000_000,
    shown: Callable[[np.ndarray], np.ndarray] = np.asarray,
) -> "tuple[SDFGrid, List[str]]":
    """Signed distance grid (positive outside) of the lumen around `entry`, and notes on what was done.

    `v` (metres) and `f` need not form a closed or manifold surface; see the module docstring.
    `entry` None keeps the largest enclosed piece (to find the entry and the sites on).
    Raises VolumeError (one line) when the entry is not enclosed, the sites lie in another
    piece, or the grid would exceed `max_nodes`. Its messages show a point `p` as `shown(p)` (the
    importer's map back into the mesh's frame).
    """
    notes: List[str] = []
    h = float(spacing)
    v, f, capped = cap_flat_ends(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64))
    if capped:
        notes.append(f"capped {capped} flat open vessel end{'s' * (capped > 1)}")
    lo = np.floor((v.min(axis=0) - pad) / h) * h
    n = np.ceil((v.max(axis=0) + pad - lo) / h).astype(int) + 1
    if int(np.prod(n.astype(float))) > max_nodes:
        raise VolumeError(f"the volume needs a {n[0]}x{n[1]}x{n[2]} grid at sdf_mm={h * 1e3:.2f}; pass a larger sdf_mm")
    shape = tuple(int(x) for x in n)
    samples = surface_samples(v, f, 0.5 * h)
    shell = np.zeros(shape, dtype=bool)
    idx = np.clip(np.rint((samples - lo) / h).astype(int), 0, n - 1)
    # Samples at most half a node apart put a shell node at one end of every grid edge the surface
    # crosses, so the shell seals the outside from the inside (6-connected flood fill).
    shell[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    seeds = {
        **({} if entry is None else {"entry": np.asarray(entry, dtype=np.float64)}),
        **{f"sites.{k}": np.asarray(p, dtype=np.float64) for k, p in sites.items()},
    }
    seed_idx = {k: tuple(np.clip(np.rint((p - lo) / h).astype(int), 0, n - 1)) for k, p in seeds.items()}
    for k, ix in seed_idx.items():
        if shell[ix]:
            raise VolumeError(
                f"{k}={_fmt_mm(shown(seeds[k]))} lies within {h * 1e3:.1f} mm of the surface; put it "
                f"further inside the vessel or pass a smaller sdf_mm"
            )
    # Outside: the flood from the border; a leak into a seed is closed by thickening the shell.
    max_close = int(np.floor(max_gap_m / (2 * h)))
    free_depth = None
    for close in range(max_close + 1):
        if close == 0:
            blocked = shell
        else:
            if free_depth is None:
                free_depth = ndimage.distance_transform_edt(~shell)  # nodes to the shell
            blocked = free_depth <= close
        labels, count = ndimage.label(~blocked)
        is_border = np.zeros(count + 1, dtype=bool)
        for face in (labels[0], labels[-1], labels[:, 0], labels[:, -1], labels[:, :, 0], labels[:, :, -1]):
            is_border[np.unique(face)] = True
        is_border[0] = False
        leaked = [k for k, ix in seed_idx.items() if is_border[labels[ix]]]
        if not leaked:
            break
    else:
        raise VolumeError(
            f"the surface is open: the outside reaches {leaked[0]}={_fmt_mm(shown(seeds[leaked[0]]))} through "
            f"a gap wider than {max_gap_m * 1e3:.1f} mm; close the vessel's ends or pass a larger "
            f"close_mm"
        )
    del free_depth, blocked
    outside = is_border[labels]
    if close:
        # Grow the flood back by the thickening, so the closing moves no wall.
        outside = (ndimage.distance_transform_edt(~outside) <= close) & ~shell
        notes.append(f"closed gaps up to {2 * close * h * 1e3:.1f} mm wide in the surface")
    inside = ~shell & ~outside
    del labels, outside
    pieces, count = ndimage.label(inside)
    if entry is None:  # the largest piece (the vessel, for finding the entry and the sites)
        if count == 0:
            raise VolumeError(f"the surface encloses no volume at sdf_mm={h * 1e3:.2f} (open, or thinner than a node?)")
        sizes = np.bincount(pieces.ravel())
        sizes[0] = 0
        lumen_label = int(np.argmax(sizes))
    else:
        lumen_label = pieces[seed_idx["entry"]]
    apart = [k for k, ix in seed_idx.items() if pieces[ix] != lumen_label]
    if apart:
        raise VolumeError(
            f"{apart[0]}={_fmt_mm(shown(seeds[apart[0]]))} is not in the same vessel as the entry (the "
            f"surface separates them); check the point or pass a smaller sdf_mm"
        )
    lumen = pieces == lumen_label
    dropped_pieces = count - 1
    del pieces, inside
    # Shell nodes take the side they are reached from first, growing the lumen and the rest into the
    # shell a layer at a time (ties go outside: the shell is at most a few nodes thick).
    rest = ~shell & ~lumen
    unknown = shell.copy()
    cross = ndimage.generate_binary_structure(3, 1)
    for _ in range(4):
        if not unknown.any():
            break
        grow_in = ndimage.binary_dilation(lumen, cross) & unknown
        grow_out = ndimage.binary_dilation(rest, cross) & unknown
        lumen |= grow_in & ~grow_out
        rest |= grow_out
        unknown &= ~(grow_in | grow_out)
    # Closed shells inside the lumen (specks a segmentation left unlabelled) are lumen.
    filled = ndimage.binary_fill_holes(lumen)
    pockets, n_pockets = ndimage.label(filled & ~lumen)
    if n_pockets:
        notes.append(
            f"filled {n_pockets} enclosed pocket{'s' * (n_pockets > 1)} inside the lumen "
            f"({float(np.count_nonzero(pockets)) * (h * 1e3) ** 3:.0f} mm^3)"
        )
        lumen = filled
    del filled, pockets
    # Signed distance: to the triangles next to the lumen's boundary, a distance transform elsewhere
    # (outside too: projections onto the surface follow its gradient).
    d_in = ndimage.distance_transform_edt(lumen)
    d_out = ndimage.distance_transform_edt(~lumen)
    near = np.where(lumen, d_in <= 2, d_out <= 2)
    values = np.where(lumen, -np.maximum(d_in - 0.5, 0.0), np.maximum(d_out - 0.5, 0.0)) * h
    del d_in, d_out
    # Surface samples far from the kept lumen's boundary: a second surface (a wall shell) or pieces dropped.
    far = np.abs(values[idx[:, 0], idx[:, 1], idx[:, 2]]) > 2 * h
    if far.mean() > 0.25:
        notes.append(
            f"the mesh has a second surface around the lumen ({100 * far.mean():.0f}% of it lies "
            f"{np.median(np.abs(values[tuple(idx[far].T)])) * 1e3:.1f} mm outside; a wall shell, inner and "
            f"outer vessel surface?): using the inner surface around the entry"
        )
    elif dropped_pieces:
        notes.append(f"dropped {dropped_pieces} enclosed piece{'s' * (dropped_pieces > 1)} not connected to the entry")
    band = np.argwhere(near)
    dist, _ = spatial.cKDTree(samples).query(lo + h * band)
    values[tuple(band.T)] = np.where(lumen[tuple(band.T)], -dist, dist)
    if smooth_m > 0:
        values = ndimage.gaussian_filter(values, smooth_m / h, mode="nearest")
    return SDFGrid(origin=lo, spacing=h, values=values), notes


def trim_side_branches(
    grid: SDFGrid, paths: Sequence[np.ndarray], entry: np.ndarray, min_diameter_m: float
) -> "tuple[SDFGrid, List[str]]":
    """Cut off side branches narrower than `min_diameter_m` that no path in `paths` runs through.

    A branch is narrow where a ball of that diameter does not fit (a morphological
    opening of the lumen removes it); every node within the lumen radius (+ 1
    node) of a path is kept whatever its width, and only pieces that stick out of
    the opened lumen at least as far as the diameter are cut, so the rest of the
    wall (and the roughness of a jagged surface) does not move.
    """
    if min_diameter_m <= 0:
        return grid, []
    h = grid.spacing
    inside = grid.values < 0
    r = 0.5 * min_diameter_m / h  # in nodes
    # Opening: the nodes a ball of the diameter fits around (the grid is a distance already), grown back.
    core = grid.values < -0.5 * min_diameter_m
    to_core = ndimage.distance_transform_edt(~core)
    opened = to_core <= r
    del core
    candidates = inside & ~opened
    if not candidates.any():
        return grid, []
    # Nodes near a path stay.
    pts = np.concatenate([resample_polyline(np.asarray(p, dtype=np.float64), h) for p in paths])
    radius = np.maximum(-grid(pts), 0.0) + h
    cand = np.argwhere(candidates)
    dist, nearest = spatial.cKDTree(pts).query(grid.origin + h * cand, distance_upper_bound=float(radius.max()))
    on_path = np.isfinite(dist)
    on_path[on_path] = dist[on_path] <= radius[nearest[on_path]]
    candidates[tuple(cand[on_path].T)] = False
    pieces, count = ndimage.label(candidates)
    if count == 0:
        return grid, []
    # A branch sticks out of the opened lumen at least as far as it is wide; the roughness of a
    # jagged surface (a decimated export) is shallower, and stays.
    protrusion = np.zeros(count + 1)
    protrusion[1:] = (ndimage.maximum(to_core, pieces, index=np.arange(1, count + 1)) - r) * h
    del to_core
    cut = protrusion >= min_diameter_m
    cut[0] = False
    if not cut.any():
        return grid, []
    removed = cut[pieces]
    # Subtract the removed pieces, max(sdf, -sdf_removed), in the box around them only.
    where = np.argwhere(removed)
    lo_i = np.maximum(where.min(axis=0) - 4, 0)
    hi_i = np.minimum(where.max(axis=0) + 5, np.array(removed.shape))
    box = tuple(slice(a, b) for a, b in zip(lo_i, hi_i))
    sub = removed[box]
    sdf_removed = (
        np.where(
            sub,
            -np.maximum(ndimage.distance_transform_edt(sub) - 0.5, 0.0),
            np.maximum(ndimage.distance_transform_edt(~sub) - 0.5, 0.0),
        )
        * h
    )
    values = grid.values.copy()
    values[box] = np.maximum(values[box], -sdf_removed)
    # Keep the lumen piece around the entry (a cut can leave nothing else, but be sure).
    pieces2, _ = ndimage.label(values < 0)
    e = tuple(np.clip(np.rint((np.asarray(entry) - grid.origin) / h).astype(int), 0, np.array(values.shape) - 1))
    if pieces2[e] > 0:
        values = np.where((values < 0) & (pieces2 != pieces2[e]), h, values)
    volume_mm3 = float(removed.sum()) * (h * 1e3) ** 3
    n_cut = int(cut.sum())
    return SDFGrid(origin=grid.origin, spacing=h, values=values), [
        f"trimmed {n_cut} side branch{'es' * (n_cut > 1)} narrower than {min_diameter_m * 1e3:.1f} mm "
        f"({volume_mm3:.0f} mm^3; trim_mm=0 keeps them)"
    ]
