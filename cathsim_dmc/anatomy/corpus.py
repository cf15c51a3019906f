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
  turned inward: the vessel wall as a solid, not the lumen;
- ``jagged_cap``: the ascending aorta ends 2 cm short of its root in a flat cap slanted
  55 degrees off square, and that end (cap and the wall within 12 mm of it) is decimated
  to a few large, jagged triangles, as decimated scans and CAD phantoms close their cut
  vessels. Imported without a crop, its wedge-shaped rim folds the surface at every edge
  length;
- ``cfd_caps``: a CFD wall: every vessel is cut square 6 mm before its end and left
  open, and the flat inlet and outlet caps are separate files beside it
  (``cap_files``);
- ``cfd_open``: the same open wall without its cap files (the importer finds the rims);
- ``staircase``: the voxel faces of a 1.5 mm mask, unsmoothed (a labelmap exported
  without smoothing): 1.5 mm steps everywhere;
- ``self_intersecting``: the noisy surface with 20 vertices of the BCA's ostium rim
  thrown about 2 mm in random directions, so that their triangles cross others.

The **close ostia** class (`CLOSE_OSTIA_VARIANTS`) is made from generated arches whose BCA
and LCCA leave the arch close together (`CLOSE_OSTIA_PARAMS`: a narrow, 52 mm arch with a
36 mm ascending aorta, a 2 mm junction blend), so that the tissue between the two lumens
(the septum) is thinner than the simulator's 2 mm wall:

- ``close_ostia``: the BCA and LCCA ostia 1 mm apart wall to wall (11.4 mm centre to
  centre), leaning 10 degrees towards each other: a septum of about 1 mm between them;
- ``shared_trunk``: a bovine arch, the BCA and LCCA from a 6 mm common trunk, parting
  slowly (headings -20 and +10 degrees): a septum down to about 2 mm above the trunk's carina.

Each is the isosurface of a 0.5 mm voxel mask, decimated (manifold3d's edge collapse
within 0.1 mm, then 0.2 mm) to about 7k triangles, with 4 non-manifold edges (a third
triangle hung on each) and 3 small closed shells (1.5 mm spheres: one inside the
descending aorta's lumen, two beside the arch), as a decimated segmentation export keeps
specks and voxels touching at an edge.

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

VARIANTS = (
    "noisy",
    "decimated",
    "pinched",
    "stump",
    "wall_shell",
    "jagged_cap",
    "cfd_caps",
    "cfd_open",
    "staircase",
    "self_intersecting",
)
VOXEL_M = 0.001  # about 260k triangles; 0.0009 gives about 320k
CLOSE_OSTIA_VARIANTS = ("close_ostia", "shared_trunk")
_CLOSE_BASE = dict(ascending_diameter_m=0.036, arch_width_m=0.052, blend_radius_m=0.002)
CLOSE_OSTIA_PARAMS = {
    "close_ostia": PRESETS["type1"].replace(
        name="close_ostia", bca_lcca_gap_m=0.001, bca_takeoff_deg=10.0, lcca_takeoff_deg=-10.0, **_CLOSE_BASE
    ),
    "shared_trunk": PRESETS["bovine"].replace(
        name="shared_trunk",
        bovine_trunk_length_m=0.006,
        bca_angle_deg=-20.0,
        lcca_angle_deg=10.0,
        branch_bend_length_m=0.020,
        **_CLOSE_BASE,
    ),
}
CLOSE_VOXEL_M = 0.0005  # a 1 mm mask would lose a 1 mm septum
CLOSE_DECIMATION_MM = (0.1, 0.2)  # manifold3d simplify tolerances, in turn


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


def _ascending_cut(model, origin, spacing, shape, before_end_m=0.012, tilt_deg=65.0):
    """Signed distance (m) of the half-space beyond a plane across the ascending aorta, `before_end_m`
    short of its root, tilted `tilt_deg` off square (positive on the side cut away): (values, plane
    point, plane normal towards the root). A slanted cut leaves a thin wedge of lumen at its rim."""
    aorta = model.aorta
    s = aorta.arclength
    i = int(np.searchsorted(s, s[-1] - before_end_m))
    p0 = aorta.points[i]
    t = aorta.points[min(i + 1, len(s) - 1)] - aorta.points[max(i - 1, 0)]
    t /= np.linalg.norm(t)
    side = np.cross(t, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    t = np.cos(np.radians(tilt_deg)) * t + np.sin(np.radians(tilt_deg)) * side
    axes = [origin[k] + spacing * np.arange(shape[k]) for k in range(3)]
    x = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    # Only near the ascending aorta: the plane must not cut the arch or the descending aorta.
    near = np.linalg.norm(x - p0, axis=-1) < 2.5 * aorta.radius[i]
    return np.where(near, (x - p0) @ t, -1.0), p0, t


def _jagged(v, f, region, rng, cell=0.010, jitter=0.003):
    """Vertex clustering in `cell` cubes of the vertices in `region` only (the rest stay), each cluster
    moved off its mean by up to `jitter`: a coarse, jagged patch seamed to the fine surface."""
    key = np.floor(v / cell).astype(np.int64)
    ids = np.full(len(v), -1, dtype=np.int64)
    _, inverse = np.unique(key[region], axis=0, return_inverse=True)
    ids[region] = inverse.ravel()
    n_clusters = int(ids.max()) + 1
    ids[~region] = n_clusters + np.arange(int((~region).sum()))
    centres = np.zeros((ids.max() + 1, 3))
    np.add.at(centres, ids, v)
    centres /= np.bincount(ids)[:, None]
    centres[:n_clusters] += rng.uniform(-jitter, jitter, (n_clusters, 3))
    g = ids[f]
    keep = (g[:, 0] != g[:, 1]) & (g[:, 1] != g[:, 2]) & (g[:, 0] != g[:, 2])
    return centres, g[keep]


def _end_planes(model):
    """(point, normal out of the vessel, radius) 6 mm before the end of every vessel: the open
    ends of a CFD wall. The descending aorta's end is its start (the wire comes in there)."""
    ends = []
    a = model.aorta
    for points, radius in [(a.points[::-1], a.radius[::-1]), (a.points, a.radius)] + [
        (b.points, b.radius) for b in model.branches.values()
    ]:
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
        i = int(np.searchsorted(s, s[-1] - 0.006))
        n = points[-1] - points[i]
        ends.append((points[i], n / np.linalg.norm(n), float(radius[i])))
    return ends


def _cut_ends(values, origin, spacing, ends):
    axes = [origin[k] + spacing * np.arange(values.shape[k]) for k in range(3)]
    x = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    for p, n, r in ends:
        near = np.linalg.norm(x - p, axis=-1) < 2.0 * r
        values = np.where(near, np.maximum(values, (x - p) @ n), values)
    return values


def _split_caps(v, f, ends, tol=0.0006):
    """(wall faces, [cap faces of each end]): a cap is every triangle on an end plane, near its vessel."""
    on_cap = np.full(len(f), -1)
    for k, (p, n, r) in enumerate(ends):
        d = np.abs((v - p) @ n) < tol
        near = np.linalg.norm(v - p, axis=1) < 1.5 * r
        on_cap[np.all(d[f] & near[f], axis=1)] = k
    return f[on_cap < 0], [f[on_cap == k] for k in range(len(ends)) if np.any(on_cap == k)]


def _voxel_faces(inside, origin, spacing):
    """The faces of the inside voxels that border outside ones (a cuberille surface), outward."""
    corners = {}
    verts, faces = [], []

    def vid(c):
        key = tuple(c)
        if key not in corners:
            corners[key] = len(verts)
            verts.append(key)
        return corners[key]

    padded = np.pad(inside, 1)
    for axis in range(3):
        step = np.zeros(3, dtype=int)
        step[axis] = 1
        a = padded[1:-1, 1:-1, 1:-1]
        b = np.roll(padded, -1, axis=axis)[1:-1, 1:-1, 1:-1]
        u, w = [(axis + 1) % 3, (axis + 2) % 3]
        eu, ew = np.eye(3, dtype=int)[u], np.eye(3, dtype=int)[w]
        for sign, where in ((1, a & ~b), (-1, ~a & b)):
            for ijk in np.argwhere(where):
                base = ijk + step  # the shared face lies between voxel ijk and ijk + step
                quad = [vid(base), vid(base + eu), vid(base + eu + ew), vid(base + ew)]
                if sign < 0:
                    quad = quad[::-1]
                faces += [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]]
    # Voxel ijk spans origin + spacing * (ijk - 0.5) .. (ijk + 0.5).
    v = origin + spacing * (np.array(verts, dtype=np.float64) - 0.5)
    return v, np.array(faces, dtype=np.int64)


def cap_files(path) -> list:
    """The separate cap surfaces written beside a variant's mesh (cfd_caps only)."""
    path = pathlib.Path(path)
    return sorted(path.parent.glob(f"{path.stem}_cap*.stl"))


def make_variant(name: str, folder, voxel_m: float = VOXEL_M) -> "tuple[pathlib.Path, np.ndarray, dict]":
    """Write variant `name` to `folder`, from a voxel mask of `voxel_m`: (mesh path, entry in mm, sites in mm).

    The close-ostia variants (`CLOSE_OSTIA_VARIANTS`) are made at `CLOSE_VOXEL_M` whatever `voxel_m`."""
    if name in CLOSE_OSTIA_VARIANTS:
        return _close_ostia_variant(name, folder)
    if name not in VARIANTS:
        raise ValueError(f"variant {name!r} is not one of {VARIANTS + CLOSE_OSTIA_VARIANTS}")
    model, grid = _arch()
    rng = np.random.default_rng(VARIANTS.index(name))
    values, origin = _resampled(grid, voxel_m)
    if name == "stump":
        values = np.minimum(values, _stump_sdf(model, origin, voxel_m, values.shape))
    if name == "jagged_cap":
        plane, p0, normal = _ascending_cut(model, origin, voxel_m, values.shape)
        values = np.maximum(values, plane)
    if name.startswith("cfd_"):
        ends = _end_planes(model)
        values = _cut_ends(values, origin, voxel_m, ends)
    if name == "staircase":
        coarse, origin = _resampled(grid, 0.0015)
        v, f = _voxel_faces(coarse < 0, origin, 0.0015)
        return _write(folder, name, v, f, [], model)
    inside = values < 0
    v, f = _mask_surface(inside, origin, voxel_m)
    if name.startswith("cfd_"):  # flat ends, exact on their planes, as a CFD mesher leaves them
        for p, n, r in ends:
            d = (v - p) @ n
            snap = (np.abs(d) < 0.0006) & (np.linalg.norm(v - p, axis=1) < 1.5 * r)
            v[snap] -= np.outer(d[snap], n)
    v = _noise(v, rng) if not name.startswith("cfd_") else v
    if name == "decimated":
        v, f = _cluster(v, f, 0.0025)
    elif name == "jagged_cap":
        near_cap = (np.abs((v - p0) @ normal) < 0.012) & (np.linalg.norm(v - p0, axis=1) < 0.04)
        v, f = _jagged(v, f, near_cap, rng)
    elif name == "pinched":
        # Fins: a third triangle on a few edges, to a vertex just off the surface.
        edges = trimesh.Trimesh(v, f, process=False).edges_unique
        pick = rng.choice(len(edges), 6, replace=False)
        tips = v[edges[pick, 0]] + rng.normal(0.0, 0.0003, (6, 3))
        f = np.concatenate([f, np.column_stack([edges[pick], len(v) + np.arange(6)])])
        v = np.concatenate([v, tips])
    elif name == "self_intersecting":
        # 20 vertices of the ring where the BCA meets the aorta (within 1.5 mm of its radius from its ostium).
        ring = np.flatnonzero(
            np.abs(np.linalg.norm(v - model.ostia["bca"], axis=1) - model.branches["bca"].radius[0]) < 0.0015
        )
        thrown = rng.choice(ring, 20, replace=False)
        v[thrown] += rng.normal(0.0, 0.002 / np.sqrt(3), (20, 3))
    elif name == "wall_shell":
        outer_v, outer_f = _mask_surface(values < 0.002, origin, voxel_m)
        f = np.concatenate([outer_f, f[:, ::-1] + len(outer_v)])
        v = np.concatenate([_noise(outer_v, rng), v])
    caps = []
    if name.startswith("cfd_"):
        f, caps = _split_caps(v, f, ends)
        if name == "cfd_open":
            caps = []
    return _write(folder, name, v, f, caps, model)


def _decimate(v, f, tolerances_mm):
    """manifold3d's edge collapse of the closed surface v, f (m), within each tolerance (mm) in turn."""
    import manifold3d

    man = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=v * 1e3, tri_verts=f.astype(np.uint64)))
    for tol in tolerances_mm:
        man = man.simplify(tol)
    mesh = man.to_mesh64()
    return np.array(mesh.vert_properties)[:, :3] * 1e-3, np.array(mesh.tri_verts, dtype=np.int64)


def _speck(centre, radius=0.0015):
    """A small closed shell (an icosphere) at `centre`: (vertices, faces)."""
    s = trimesh.creation.icosphere(subdivisions=1, radius=radius)
    return np.asarray(s.vertices) + centre, np.asarray(s.faces, dtype=np.int64)


def _close_ostia_variant(name, folder):
    model = build_arch(CLOSE_OSTIA_PARAMS[name])
    grid = arch_sdf_grid(model)
    rng = np.random.default_rng(len(VARIANTS) + CLOSE_OSTIA_VARIANTS.index(name))
    values, origin = _resampled(grid, CLOSE_VOXEL_M)
    v, f = _mask_surface(values < 0, origin, CLOSE_VOXEL_M)
    v, f = _decimate(v, f, CLOSE_DECIMATION_MM)
    # Fins: a third triangle on 4 edges, to a vertex just off the surface (non-manifold edges).
    edges = trimesh.Trimesh(v, f, process=False).edges_unique
    pick = rng.choice(len(edges), 4, replace=False)
    tips = v[edges[pick, 0]] + rng.normal(0.0, 0.0003, (4, 3))
    f = np.concatenate([f, np.column_stack([edges[pick], len(v) + np.arange(4)])])
    v = np.concatenate([v, tips])
    # Specks: one inside the descending aorta (7 mm off its axis, 40 mm above the entry), two
    # 4 mm outside the wall of the arch (beside the ascending aorta and the descending one).
    a = model.aorta
    i = int(np.searchsorted(a.arclength, a.arclength[0] + 0.05))
    aside = np.array([0.0, 0.0, 1.0])
    centres = [a.points[i] + 0.007 * aside]
    for s_from_end in (a.arclength[-1] - 0.010, a.arclength[0] + 0.08):
        j = int(np.searchsorted(a.arclength, s_from_end))
        centres.append(a.points[j] + (a.radius[j] + 0.004) * aside)
    for c in centres:
        sv, sf = _speck(c)
        f = np.concatenate([f, sf + len(v)])
        v = np.concatenate([v, sv])
    return _write(folder, name, v, f, [], model, stem=name)


def _write(folder, name, v, f, caps, model, stem=None):
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{stem or f'type1_{name}'}.stl"
    for old in cap_files(path):
        old.unlink()
    trimesh.Trimesh(v * 1e3, f, process=False).export(path)
    for k, cap in enumerate(caps):
        used = np.unique(cap)
        remap = np.zeros(len(v), dtype=np.int64)
        remap[used] = np.arange(len(used))
        trimesh.Trimesh(v[used] * 1e3, remap[cap], process=False).export(folder / f"{path.stem}_cap{k}.stl")
    return path, model.entry_position * 1e3, {k: p * 1e3 for k, p in model.sites.items()}
