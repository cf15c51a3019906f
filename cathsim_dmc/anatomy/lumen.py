"""The lumen surface the wall is built on, and how a generated arch gets one.

`Lumen`: a closed (watertight, so inside/outside tests work), outward-oriented
triangle surface whose open-end cap triangles are flagged (the wire enters
there, so no wall piece is built on them), with the vertex normals the wall is
extruded along (`lumen_normals`). Generated arches get theirs from
`build_lumen`, imported meshes from `open_end.build_open_lumen`.

`build_lumen`: the zero set of the arch's blended-tube SDF (`sdf.arch_sdf_grid`)
is meshed (`remesh.level_set_surface`), cut flat by a plane at the inferior end
of the descending aorta (the rim triangles are regularised in cylindrical
coordinates, `rim.clean_rim`), refined (at creases, and where a triangle
cuts into a narrow vessel: `remesh.refine_sagging`) and relaxed on the surface,
and closed with a flat cap. Everything is deterministic: the mesher's output is
put in canonical order before it is processed.

Mesher versions (`build_lumen`'s `mesher_version`; the asset records it in
meta.json, `asset.build_asset`): 1 is the pipeline before the pinched-branch fix
(manifold3d's interpolated level-set vertices, crease refinement only), kept so
that the shipped assets rebuild byte for byte (`asset.SHIPPED_MESHER_VERSIONS`);
2 (`MESHER_VERSION`, the default) adds the level-set tolerance and
`remesh.refine_sagging`. A new version must leave the older ones' output alone.
"""

from __future__ import annotations

import dataclasses

import manifold3d
import numpy as np
from scipy import spatial

from cathsim_dmc.anatomy.arch import ArchModel
from cathsim_dmc.anatomy.remesh import (
    level_set_surface,
    manifold_arrays,
    refine_creases,
    refine_sagging,
    relax_on_surface,
)
from cathsim_dmc.anatomy.rim import clean_rim, close_cap
from cathsim_dmc.anatomy.sdf import SDFGrid, arch_sdf_grid
from cathsim_dmc.anatomy.surface_cleanup import SHORT_EDGE_FRACTION, collapse_short_edges, fix_slivers, folded_faces
from cathsim_dmc.anatomy.triangles import canonical_order, drop_unused_vertices, edge_faces, vertex_normals


@dataclasses.dataclass(frozen=True)
class Lumen:
    vertices: np.ndarray  # (V, 3) float64, metres
    faces: np.ndarray  # (F, 3) int64, counter-clockwise seen from outside
    cap: np.ndarray  # (F,) bool: triangle lies on the open-end cut plane
    normals: np.ndarray  # (V, 3) unit outward vertex normals (cap faces excluded)


def rim_vertices(faces: np.ndarray, cap: np.ndarray) -> np.ndarray:
    """Sorted ids of the vertices shared by a cap face and a wall face: the open end's rim."""
    rim = np.unique(faces[cap])
    return rim[np.isin(rim, faces[~cap])]


def lumen_normals(vertices: np.ndarray, faces: np.ndarray, cap: np.ndarray, cut_normal: np.ndarray) -> np.ndarray:
    """(V, 3) unit vertex normals of the non-cap faces, those of the rim laid into the cut plane.

    `cut_normal`: a unit normal of the open end's plane (either sign). The wall
    is extruded along these normals, so it ends in a flat annulus at the open end.
    """
    normals = vertex_normals(vertices, faces, ~cap)
    rim = rim_vertices(faces, cap)
    normals[rim] -= np.outer(normals[rim] @ cut_normal, cut_normal)
    normals[rim] /= np.linalg.norm(normals[rim], axis=1, keepdims=True)
    return normals


class FoldedSurfaceError(RuntimeError):
    """A wall triangle of the lumen faces against the surface normal (`where`: its centroid, m)."""

    def __init__(self, message: str, where=None):
        super().__init__(message)
        self.where = where


def check_lumen_surface(v, f, cap, grid: SDFGrid):
    """Fail loudly on an open surface or a wall triangle turned against the surface normal."""
    _, _, faces_of_edge = edge_faces(f)
    if np.any(faces_of_edge[:, 1] < 0):
        raise RuntimeError("Lumen surface is not closed.")
    wall = f[~cap]
    bad = folded_faces(v, wall, grid)
    if len(bad):
        where = v[wall[bad[0]]].mean(axis=0)
        raise FoldedSurfaceError(
            f"Lumen surface has {len(bad)} folded triangle{'s' * (len(bad) > 1)}, the first at "
            f"[{', '.join(f'{x * 1e3:.1f}' for x in where)}] mm; try another edge_length_m.",
            where=where,
        )


# A coarse mesh can fold a triangle where the lumen curves tightly (seen at 6-8 mm
# edges on some arches); the surface is then rebuilt with edges this much shorter.
FOLD_RETRY_EDGE_FACTOR = 0.9
MIN_RETRY_EDGE_M = 0.003
# The mesher's vertices lie within this fraction of the SDF grid spacing (0.1 mm at
# 1 mm) of the zero set. With manifold3d's default (the crossing interpolated between
# two grid points ~edge_length_m apart) vertices of a branch little wider than an edge
# landed up to 2.6 mm inside it, and when the projection onto the surface in
# relax_on_surface folded a triangle it was dropped for the whole mesh: a branch kept
# 0.25-0.71 of its radius in 10 of 50 sampled arches (aorta=random, pool_seed=100).
LEVEL_SET_TOLERANCE = 0.1
# Triangles cutting into the lumen deeper than this fraction of the local vessel radius
# are split (up to SAG_REFINE_LEVELS times before the relaxation, once after it;
# remesh.refine_sagging): at 7 mm edges a 3.2-4.8 mm-radius branch otherwise keeps
# 0.73-0.89 of its radius (50 sampled arches), with it 0.85 or more.
MAX_SAG_FRACTION = 0.1
SAG_REFINE_LEVELS = 2
# Version 2 (the three settings above) keeps every branch's lumen at 0.87 or more of its
# nominal radius on those 50 arches (median 0.90); version 1 kept 0.25 or more (median 0.82,
# 10 arches below 0.75): experiments/lumen_radius.py, module docstring.
MESHER_VERSION = 2
MESHER_VERSIONS = (1, 2)


def build_lumen(model: ArchModel, grid: SDFGrid | None = None, mesher_version: int = MESHER_VERSION) -> Lumen:
    """Watertight, outward-oriented lumen surface with the open-end cap flagged.

    Meshed at ``edge_length_m``; if that folds a triangle, at edges 10% shorter each
    time down to 3 mm (deterministic: the same parameters and `mesher_version` give
    the same surface). `mesher_version`: one of `MESHER_VERSIONS` (module docstring).
    """
    if mesher_version not in MESHER_VERSIONS:
        raise ValueError(f"mesher_version={mesher_version!r} is not valid; choose one of {list(MESHER_VERSIONS)}")
    grid = arch_sdf_grid(model) if grid is None else grid
    edge = model.params.edge_length_m
    while True:
        try:
            return _build_lumen(model, grid, edge, mesher_version)
        except FoldedSurfaceError:
            edge *= FOLD_RETRY_EDGE_FACTOR
            if edge < MIN_RETRY_EDGE_M:
                raise


def _build_lumen(model: ArchModel, grid: SDFGrid, edge: float, mesher_version: int) -> Lumen:
    p = model.params
    shape = np.array(grid.values.shape)
    lo = grid.origin + grid.spacing
    hi = grid.origin + grid.spacing * (shape - 2)
    fixed = mesher_version >= 2  # the pinched-branch fix (module docstring)
    man = level_set_surface(grid, lo, hi, edge, tolerance_m=LEVEL_SET_TOLERANCE * grid.spacing if fixed else None)
    # Open inferior end: cut square to the descending aorta (which runs along +y
    # there) at the open-end plane; the part above is kept and capped flat.
    c = model.open_end_center
    man = man.trim_by_plane((0.0, 1.0, 0.0), float(c[1]))
    if man.status() != manifold3d.Error.NoError or man.is_empty():
        raise RuntimeError(f"Lumen meshing failed: {man.status()}")
    v, f = manifold_arrays(man)
    # Drop manifold's ear-clipped cap, clean the rim, close it with a fan.
    y_cut = float(c[1])
    v[np.abs(v[:, 1] - y_cut) < 1e-9, 1] = y_cut
    v, f = drop_unused_vertices(v, f[~_cap_mask(v, f, y_cut)])
    v, f = clean_rim(v, f, c[[0, 2]], y_cut, edge)
    y_band = y_cut + 3 * edge
    v, f = collapse_short_edges(v, f, grid, SHORT_EDGE_FRACTION * edge, frozen=v[:, 1] < y_band)
    v, f = refine_creases(v, f, grid, p.max_dihedral_deg, p.refine_levels, y_band)
    if fixed:
        radius = vessel_radius(model)
        v, f = refine_sagging(v, f, grid, radius, MAX_SAG_FRACTION, SAG_REFINE_LEVELS, y_band)
    v = relax_on_surface(v, f, grid, frozen=v[:, 1] < y_band, iterations=p.relax_iterations)
    if fixed:
        # The relaxation slides vertices round the narrow branches and can open a few chords
        # up again (0.89 -> 0.83 of the radius seen): split those once more.
        v, f = refine_sagging(v, f, grid, radius, MAX_SAG_FRACTION, 1, y_band)
    v, f = fix_slivers(v, f, grid, frozen=v[:, 1] < y_band)
    v, f = close_cap(v, f, y_cut)
    v, f = canonical_order(v, f)
    cap = _cap_mask(v, f, y_cut)
    normals = lumen_normals(v, f, cap, np.array([0.0, 1.0, 0.0]))
    check_lumen_surface(v, f, cap, grid)
    return Lumen(vertices=v, faces=f, cap=cap, normals=normals)


def vessel_radius(model: ArchModel):
    """points (N, 3) -> (N,) nominal radius of the vessel whose tube surface each point is nearest
    (the one with the smallest distance to its centreline minus its radius there)."""
    trees = [(spatial.cKDTree(vessel.points), vessel.radius) for vessel in model.vessels]

    def radius(points):
        best = np.full(len(points), np.inf)
        out = np.zeros(len(points))
        for tree, r in trees:
            d, i = tree.query(points)
            gap = d - r[i]
            nearer = gap < best
            best[nearer] = gap[nearer]
            out[nearer] = r[i][nearer]
        return out

    return radius


def _cap_mask(v, f, y_cut, tol=1e-7):
    """Faces lying in the cut plane y = `y_cut`."""
    return np.all(np.abs(v[f][:, :, 1] - y_cut) < tol, axis=1)
