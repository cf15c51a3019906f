"""Step 4 of a mesh import: the signed distance grid of a closed lumen mesh, with its memory
planned before anything large is allocated (see `importer`)."""

from __future__ import annotations

from typing import Optional

import numpy as np
from scipy import ndimage

from cathsim_dmc.anatomy.import_error import MeshImportError
from cathsim_dmc.anatomy.sdf import SDFGrid, signed_distance

MAX_GRID_NODES = 30_000_000
# Peak memory of the grid stages, per grid node and per node inside the lumen (the
# centerline graph): the type I arch at sdf_mm=0.5 (14.4 M nodes, 1.3 M in the lumen)
# peaked at 1.8 GB.
GRID_BYTES_PER_NODE = 100
GRID_BYTES_PER_LUMEN_NODE = 300
MEMORY_FRACTION = 0.7  # of MemAvailable the import may plan to use


def grid_shape(v, spacing: float, pad: float) -> "tuple[np.ndarray, np.ndarray]":
    """(origin, nodes per axis) of the SDF grid around vertices `v`."""
    lo = np.floor((v.min(axis=0) - pad) / spacing) * spacing
    return lo, np.ceil((v.max(axis=0) + pad - lo) / spacing).astype(int) + 1


def check_grid_memory(v, f, spacing: float, pad: float, path, available_bytes: Optional[int] = None) -> int:
    """The planned peak memory of the grid stages (bytes), or MeshImportError (one line,
    naming sdf_mm) if it exceeds MEMORY_FRACTION of the available memory: refused before
    anything large is allocated."""
    from cathsim_dmc.core.checks import available_memory_bytes

    _, n = grid_shape(v, spacing, pad)
    nodes = float(np.prod(n.astype(float)))
    tri = v[f]
    volume = abs(float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()) / 6.0)
    need = GRID_BYTES_PER_NODE * nodes + GRID_BYTES_PER_LUMEN_NODE * volume / spacing**3
    have = available_memory_bytes() if available_bytes is None else int(available_bytes)
    if need > MEMORY_FRACTION * have:
        enough = spacing * (need / (MEMORY_FRACTION * have)) ** (1 / 3)
        raise MeshImportError(
            f"{path}: a {n[0]}x{n[1]}x{n[2]} grid at sdf_mm={spacing * 1e3:.2f} needs about "
            f"{need / 2**30:.1f} GiB, {have / 2**30:.1f} GiB available; pass sdf_mm="
            f"{np.ceil(enough * 1e4) / 10:.1f} or more"
        )
    return int(need)


def mesh_sdf_grid(v, f, spacing: float, pad: float) -> SDFGrid:
    """SDF grid (positive OUTSIDE) of a closed mesh: exact within ~1 node of the surface.

    Nodes next to the surface (every node within one node of a dense surface
    sample) get the exact signed distance; the rest are classified by a flood
    fill from the grid border and get a distance-transform distance.
    """
    import trimesh

    h = float(spacing)
    lo, n = grid_shape(v, h, pad)
    if int(np.prod(n)) > MAX_GRID_NODES:
        raise MeshImportError(f"the mesh needs a {n[0]}x{n[1]}x{n[2]} grid at {h * 1e3:.2f} mm; pass a larger sdf_mm")
    sv, _ = trimesh.remesh.subdivide_to_size(v, f, max_edge=0.5 * h)
    idx = np.clip(np.rint((sv - lo) / h).astype(int), 0, n - 1)
    band = np.zeros(tuple(n), dtype=bool)
    band[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    band = ndimage.binary_dilation(band, structure=np.ones((3, 3, 3), dtype=bool))
    nodes = np.argwhere(band)
    sd_band = signed_distance(v, f, lo + h * nodes)  # + inside
    labels, _ = ndimage.label(~band)
    border = np.unique(
        np.concatenate(
            [
                labels[0].ravel(),
                labels[-1].ravel(),
                labels[:, 0].ravel(),
                labels[:, -1].ravel(),
                labels[:, :, 0].ravel(),
                labels[:, :, -1].ravel(),
            ]
        )
    )
    outside = np.isin(labels, border[border > 0])
    inside = ~band & ~outside
    inside[tuple(nodes[sd_band > 0].T)] = True
    d_in = ndimage.distance_transform_edt(inside) * h
    d_out = ndimage.distance_transform_edt(~inside) * h
    values = np.where(inside, -np.maximum(d_in - 0.5 * h, 0.0), np.maximum(d_out - 0.5 * h, 0.0))
    values[tuple(nodes.T)] = -sd_band
    return SDFGrid(origin=lo, spacing=h, values=values)
