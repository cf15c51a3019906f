"""Write a (task, aorta) scene as a self-contained MJCF folder: scene.xml + meshes/*.stl.

The environment compiles its scene from the composer MJCF plus the aorta's wall, which
`Aorta.add_geoms` puts into a `mujoco.MjSpec` (see `cathsim_dmc.sim.model_cache`). The
export repeats exactly that, so the exported model is the environment's model, and
then turns every in-memory mesh into an STL file before `MjSpec.to_xml`:

- dm_control's `mjcf.export_with_assets` on an `Aorta(hulls_in_mjcf=True)` scene would
  write each of the thousands of wall pieces as an inline `vertex=` list (they have no
  files), which MuJoCo reads but other importers (the Unity plug-in) do not, and that
  build alone takes seconds;
- a wall piece is a point cloud whose convex hull MuJoCo takes for collisions, so its
  STL holds that hull's triangles (outward facing): the same vertices, the same hull.

MuJoCo's XML writer keeps 6 significant digits, so `scene.xml` is dm_control's own
XML of the scene (17 digits) with the added meshes and geoms spliced in: the reloaded
model matches the environment's in every number, not only to 6 digits.

The wall is always exported as prisms, whatever the environment's physics setting: the
distance-field wall of `physics=fast` needs this package's compiled contact test.

The file also carries a keyframe `start`: the state after a seeded reset (wire at the
entry, robot retracted), which `simulate` loads from its "Key" panel.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np

SCENE_FILE = "scene.xml"
MESH_DIR = "meshes"
START_KEY = "start"


def write_stl(path, vertices, faces) -> None:
    """Binary STL of triangles `faces` (indices into `vertices`), normals from the winding."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    tri = v[np.asarray(faces, dtype=np.int64).reshape(-1, 3)]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    record = np.dtype([("normal", "<f4", 3), ("vertices", "<f4", (3, 3)), ("attribute", "<u2")])
    rows = np.zeros(len(tri), dtype=record)
    rows["normal"], rows["vertices"] = normals, tri
    with open(path, "wb") as f:
        f.write(b"cathsim-dmc export".ljust(80, b" "))
        f.write(np.uint32(len(rows)).tobytes())
        f.write(rows.tobytes())


def hull_faces(vertices) -> np.ndarray:
    """Triangles of the convex hull of `vertices`, wound so their normals point outwards."""
    from scipy.spatial import ConvexHull

    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    hull = ConvexHull(v)
    faces = hull.simplices.copy()
    normals = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    inward = np.einsum("ij,ij->i", normals, hull.equations[:, :3]) < 0
    faces[inward] = faces[inward][:, ::-1]
    return faces


def task_root(env):
    return env.task.root_entity.mjcf_model


def scene_spec(env) -> mujoco.MjSpec:
    """The spec the environment `env` (a NavigationEnvironment) compiles its model from."""
    task = env.task
    root = task_root(env)
    spec = mujoco.MjSpec.from_string(root.to_xml_string(), assets=root.get_assets())
    if not task.aorta.hulls_in_mjcf:
        # The prism wall: the distance-field wall (physics=fast) needs this package's
        # compiled contact test, which MuJoCo's simulate and other importers lack.
        task.aorta.add_geoms(spec, wall="prisms")
    return spec


def _file_name(name: str, used: set) -> str:
    stem = re.sub(r"[^A-Za-z0-9_.-]", "_", name) or "mesh"
    candidate, n = stem, 1
    while candidate in used:
        candidate, n = f"{stem}_{n}", n + 1
    used.add(candidate)
    return candidate + ".stl"


def export_scene(env, out_dir) -> Path:
    """Write `env`'s scene into `out_dir` (scene.xml, meshes/); returns the scene path.

    `env` is a reset `NavigationEnvironment`; its current state becomes the `start` key.
    """
    out_dir = Path(out_dir)
    mesh_dir = out_dir / MESH_DIR
    mesh_dir.mkdir(parents=True, exist_ok=True)
    spec = scene_spec(env)
    used: set = set()
    for mesh in spec.meshes:
        if mesh.file:  # a file asset of the MJCF (none today): keep its bytes
            raise NotImplementedError(f"mesh {mesh.name!r} comes from a file; export supports in-memory meshes")
        vertices = np.asarray(mesh.uservert, dtype=np.float64).reshape(-1, 3)
        faces = np.asarray(mesh.userface, dtype=np.int64)
        faces = hull_faces(vertices) if faces.size == 0 else faces.reshape(-1, 3)
        file_name = _file_name(mesh.name, used)
        write_stl(mesh_dir / file_name, vertices, faces)
        mesh.file = file_name
        mesh.uservert = []
        mesh.userface = []
    # to_xml compiles, which reads the STLs back: a file MuJoCo cannot load fails here.
    spec.meshdir = str(mesh_dir.resolve())
    added = ET.fromstring(spec.to_xml())
    # MuJoCo's XML writer keeps 6 significant digits (a wire segment's mass 0.1430035 ->
    # 0.143003), so the scene is dm_control's own XML (17 digits) with only the added
    # meshes and geoms, whose attributes are short decimals, taken from the spec's XML.
    scene_root = ET.fromstring(task_root(env).to_xml_string(precision=17))
    names = {mesh.name for mesh in spec.meshes}
    compiler = scene_root.find("compiler")
    if compiler is None:
        compiler = ET.Element("compiler")
        scene_root.insert(0, compiler)
    compiler.set("meshdir", MESH_DIR)
    asset = scene_root.find("asset")
    if asset is None:
        asset = ET.Element("asset")
        scene_root.insert(list(scene_root).index(scene_root.find("worldbody")), asset)
    asset.extend(m for m in added.iter("mesh") if m.get("name") in names)
    for parent in [added.find("worldbody"), *added.iter("body")]:  # where add_geoms put them
        geoms = [g for g in parent.findall("geom") if g.get("mesh") in names]
        if geoms:
            name = parent.get("name")
            body = scene_root.find(f".//body[@name='{name}']") if parent.tag == "body" else scene_root.find("worldbody")
            body.extend(geoms)
    physics = env.physics
    keyframe = ET.SubElement(scene_root, "keyframe")
    values = {"qpos": physics.data.qpos, "qvel": physics.data.qvel, "ctrl": physics.data.ctrl, "act": physics.data.act}
    ET.SubElement(
        keyframe, "key", name=START_KEY, **{k: " ".join(repr(float(x)) for x in v) for k, v in values.items() if v.size}
    )
    ET.indent(scene_root, space="  ")
    scene = out_dir / SCENE_FILE
    ET.ElementTree(scene_root).write(scene, encoding="unicode")
    return scene
