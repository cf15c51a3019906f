"""Steps 1-3 of a mesh import: read a lumen surface file, repair what is safe to repair, and
settle its units (see `importer`)."""

from __future__ import annotations

import pathlib
from typing import List, Optional

import numpy as np

from cathsim_dmc.anatomy.import_error import MeshImportError, format_point
from cathsim_dmc.anatomy.triangles import boundary_loops, fan_triangles


def read_lumen(path) -> "tuple[np.ndarray, np.ndarray]":
    """Vertices and faces of a mesh file, or MeshImportError."""
    import trimesh

    path = pathlib.Path(path)
    if not path.is_file():
        raise MeshImportError(f"{path}: no such file")
    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # noqa: BLE001 - any reader failure is a bad file
        detail = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise MeshImportError(f"{path}: cannot be read as a mesh ({detail})") from None
    faces = getattr(loaded, "faces", None)
    if not isinstance(loaded, trimesh.Trimesh) or faces is None or len(faces) == 0:
        raise MeshImportError(f"{path}: contains no triangles (is it an STL or OBJ surface mesh?)")
    v = np.asarray(loaded.vertices, dtype=np.float64)
    f = np.asarray(loaded.faces, dtype=np.int64)
    if not np.all(np.isfinite(v)):
        raise MeshImportError(f"{path}: has non-finite vertex coordinates")
    return v, f


def check_encloses_volume(v, f, path) -> None:
    """MeshImportError when the triangles cannot be a vessel's closed surface, whatever the
    repairs: fewer than 4 triangles with an area, or every vertex in one plane (no volume).
    Checked before the costly steps, whose own errors would blame the entry or the sites."""
    v, f = np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    usable = int(np.count_nonzero(area > 0))
    if usable < 4:
        raise MeshImportError(
            f"{path}: not a closed vessel surface: {usable} triangle{'s' * (usable != 1)} with an area, "
            "and a closed surface needs at least 4 enclosing a volume (is it the lumen's whole surface?)"
        )
    used = v[np.unique(f)]
    spread = np.sqrt(np.maximum(np.linalg.eigvalsh(np.cov(used.T)), 0.0))  # along its principal axes
    if spread[0] <= 1e-9 * spread[-1]:
        raise MeshImportError(
            f"{path}: not a closed vessel surface: all its vertices lie in one plane, so it encloses no volume"
        )


def repair_lumen(v, f, path, units_label="units", shown=np.asarray) -> "tuple[np.ndarray, np.ndarray, List[str]]":
    """Safe repairs; MeshImportError when the surface cannot be made a closed 2-manifold. Its
    messages show a point `p` as `shown(p)` (the importer's map back into the mesh's frame)."""
    import trimesh

    repairs = []
    mesh = trimesh.Trimesh(v, f, process=False)
    n_v = len(mesh.vertices)
    mesh.merge_vertices()
    bad = ~mesh.nondegenerate_faces()
    if bad.any():
        mesh.update_faces(~bad)
        repairs.append(f"dropped {int(bad.sum())} degenerate triangles")
    uniq = mesh.unique_faces()
    if len(uniq) < len(mesh.faces):
        keep = np.zeros(len(mesh.faces), dtype=bool)
        keep[uniq] = True
        repairs.append(f"dropped {int((~keep).sum())} duplicate triangles")
        mesh.update_faces(keep)
    mesh.remove_unreferenced_vertices()
    merged = n_v - len(mesh.vertices)
    if merged and path.suffix.lower() != ".stl":  # STL always repeats shared vertices
        repairs.append(f"merged {merged} duplicate vertices")
    if len(mesh.faces) < 4:
        raise MeshImportError(f"{path}: has fewer than 4 usable triangles")
    # Non-manifold edges (three or more triangles on one edge): not safely repairable.
    edges = np.sort(mesh.edges, axis=1)
    uniq_e, counts = np.unique(edges, axis=0, return_counts=True)
    if np.any(counts > 2):
        where = shown(mesh.vertices[uniq_e[counts > 2][0, 0]])
        raise MeshImportError(
            f"{path}: non-manifold surface: {int(np.sum(counts > 2))} edges are shared by more than two "
            f"triangles (first at {format_point(where, digits=3)} {units_label}); a lumen must be one closed surface"
        )
    # Loose pieces: keep the largest (by area).
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))
    if labels.max() > 0:
        area = np.bincount(labels, weights=mesh.area_faces)
        keep = labels == int(np.argmax(area))
        repairs.append(
            f"dropped {int(labels.max())} loose pieces ({100 * (1 - area.max() / area.sum()):.1f}% of the area)"
        )
        mesh.update_faces(keep)
        mesh.remove_unreferenced_vertices()
    # Holes: trimesh fills 3-4 edge holes; flat loops (vessel ends) get a fan cap.
    if not mesh.is_watertight:
        before = len(mesh.faces)
        trimesh.repair.fill_holes(mesh)
        if len(mesh.faces) > before:
            repairs.append(f"filled small holes with {len(mesh.faces) - before} triangles")
    if not mesh.is_watertight:
        vv, ff = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        loops = boundary_loops(ff)
        if loops is None:
            raise MeshImportError(f"{path}: not watertight, and its holes touch each other; cannot close them safely")
        caps, added = [], []
        for loop in loops:
            p = vv[loop]
            c = p.mean(axis=0)
            _, sv, vt = np.linalg.svd(p - c)
            normal = vt[2]
            size = float(np.max(np.linalg.norm(p - c, axis=1)))
            off = float(np.max(np.abs((p - c) @ normal)))
            # A flat loop whose points all see its centroid: a vessel end cut by the segmentation.
            if len(loop) < 5 or off > 0.05 * size:
                raise MeshImportError(
                    f"{path}: not watertight: a hole of {len(loop)} edges around {format_point(shown(c), digits=3)} "
                    f"{units_label} is not a flat vessel end ({off / max(size, 1e-12) * 100:.0f}% out of plane); "
                    f"cannot close it safely"
                )
            ci = len(vv) + len(added)
            added.append(c)
            caps.append(fan_triangles(loop, ci))
        mesh = trimesh.Trimesh(np.concatenate([vv, np.array(added)]), np.concatenate([ff] + caps), process=False)
        repairs.append(f"closed {len(loops)} flat open vessel end{'s' * (len(loops) > 1)}")
    if not mesh.is_winding_consistent:
        trimesh.repair.fix_winding(mesh)
        if not mesh.is_winding_consistent:
            raise MeshImportError(
                f"{path}: triangle orientations are inconsistent and cannot be fixed "
                f"(a one-sided or self-overlapping surface?)"
            )
        repairs.append("made the triangle winding consistent")
    if not mesh.is_watertight:
        raise MeshImportError(f"{path}: not watertight after repair")
    if mesh.volume < 0:
        mesh.invert()
        repairs.append("turned the inside-out surface the right way round")
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    import manifold3d

    status = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=v, tri_verts=f.astype(np.uint64))).status()
    if status != manifold3d.Error.NoError:
        raise MeshImportError(f"{path}: not a valid closed 2-manifold ({status.name})")
    return v, f, repairs


def detect_units(v, units: str, path) -> "tuple[float, str, Optional[str]]":
    """(scale to metres, units used, note) for `units` in auto|mm|m."""
    extent = float(np.max(np.ptp(v, axis=0)))
    if units == "auto":
        if extent > 2.0:
            return (
                1e-3,
                "mm",
                (f"{path}: spans {extent:.1f} units, assuming millimetres (pass units=m if it is in metres)"),
            )
        return 1.0, "m", f"{path}: spans {extent:.3f} units, assuming metres (pass units=mm if it is in millimetres)"
    if units not in ("mm", "m"):
        raise ValueError(f"units={units!r} is not valid; choose one of ['auto', 'mm', 'm']")
    scale = 1e-3 if units == "mm" else 1.0
    note = None
    if not 0.005 < extent * scale < 2.0:
        note = f"{path}: spans {extent * scale:.3g} m in units={units}; is that the right unit?"
    return scale, units, note
