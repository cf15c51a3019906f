"""Collision study (issue 20, item 4): the vessel wall's representation, cost against fidelity.

    python experiments/collision_study.py                    # bca/type1, `fast` physics, all walls
    python experiments/collision_study.py --episodes 5 --repeats 5 --out /tmp/collision_study
    python experiments/collision_study.py --walls today coarse35 sdf   # a subset (the first is the baseline)

Walls compared (each under the `fast` physics settings, the scene otherwise the same):

- `today`: the shipped type1 wall, one convex prism per lumen triangle (7 mm edges,
  crease refinement at 25 degrees), moved out by the 1 mm contact margin.
- `coarse35`, `coarse45`: coarser walls built with the project's own pipeline
  (`anatomy.build_asset`) into a temporary asset folder: edges of 10 mm asked for
  (type1 folds a triangle at 10 mm, so `lumen.build_lumen` meshes it at 9 mm) and the
  crease refinement only where neighbouring triangles fold by more than 35 or 45
  degrees. `ArchParams.validate` refuses edges longer than the narrowest branch
  (8.3 mm), so the study relaxes that one check for its builds (a subclass here, no
  library change). Each build is validated with `anatomy.validate.validate_asset`
  (holes, intrusion, the probe along the centerlines); its lumen's deviation from the
  generator's exact surface (the arch SDF) is measured on points sampled over it.
- `sdf`, `sdf8`: the same wall as `today`, as ONE non-convex geom: the closed shell
  between the (moved) lumen surface and the prisms' outer faces, a mesh collided
  through MuJoCo's native mesh SDF (geom type `sdf` with a mesh: an octree of the
  distance field, default depth 6; `sdf8` asks for depth 8), with today's 1 mm margin.

Measured, for each wall:

1. Time: from the same saved states in the arch (the `today` environment driven by
   full insertion with slow rotation, states after `--at` control steps), `--steps`
   raw `mujoco.mj_step` calls per run, the walls interleaved and the order rotated,
   `--repeats` runs; the median time as a ratio to the baseline. Collision alone:
   `mujoco.mj_collision` timed on states of the untimed run (every 10th step, 20 calls
   each, interleaved), as a ratio and in microseconds.
2. Fidelity from the same states: the tip's distance after the steps from where the
   baseline's tip ended, the deepest wire-wall contact past the constraint surface
   (`includemargin - dist`), the mean total wall force and the mean contact count.
3. The scripted expert (`experts.CenterlineExpert`, `--episodes` seeds per target, BCA
   and LCCA; `--sdf-episodes` with an SDF wall, which runs at a few control steps per
   second): successes, escapes (`info["escaped"]`), divergences, mean steps.

Times are ratios: the machine may be shared. Writes a JSON of everything to `--out`.
Temporary builds and the compiled-model and lumen-field caches go under `--out` (no
shipped asset or user cache is touched).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import pathlib
import statistics
import sys
import time

DEFAULT_OUT = pathlib.Path("/tmp/collision_study")


def _early_out(argv) -> pathlib.Path:
    """--out before the library is imported: its caches are read from the environment."""
    argv = list(sys.argv[1:] if argv is None else argv)
    for i, a in enumerate(argv):
        if a == "--out" and i + 1 < len(argv):
            return pathlib.Path(argv[i + 1])
        if a.startswith("--out="):
            return pathlib.Path(a.split("=", 1)[1])
    return DEFAULT_OUT


ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "experiments"))  # physics_probe, beside this script

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

COARSE = {  # name: (edge length asked for, crease angle for refinement)
    "coarse35": (0.010, 35.0),
    "coarse45": (0.010, 45.0),
}
SDF_DEPTH = {"sdf": None, "sdf8": 8}  # None: MuJoCo's default octree depth
WALLS = ("today", *COARSE, *SDF_DEPTH)
TARGETS = ("bca", "lcca")


# ----------------------------------------------------------------------------
# Coarser walls through the project's pipeline


def study_params_class():
    from cathsim_dmc.anatomy import ArchParams

    @dataclasses.dataclass(frozen=True)
    class StudyParams(ArchParams):
        """ArchParams whose validation lets the base edge exceed the narrowest branch
        (the crease refinement still splits the branches' triangles)."""

        def validate(self) -> None:
            plain = ArchParams(**dataclasses.asdict(self))
            narrowest = min(plain.branch_diameter_m(b) for b in ("bca", "lcca", "lsa"))
            plain.replace(edge_length_m=min(self.edge_length_m, narrowest)).validate()

    return StudyParams


def build_coarse(name: str, root: pathlib.Path) -> pathlib.Path:
    from cathsim_dmc.anatomy import PRESETS, build_asset

    folder = root / "assets" / name
    if (folder / "meta.json").is_file():
        return folder
    edge, crease = COARSE[name]
    params = study_params_class()(**dataclasses.asdict(PRESETS["type1"])).replace(
        name=f"type1_{name}", edge_length_m=edge, max_dihedral_deg=crease
    )
    build_asset(params, folder)
    return folder


def surface_deviation(folder: pathlib.Path, samples: int = 200_000, seed: int = 0) -> dict:
    """The lumen's distance from the generator's exact surface (arch SDF, positive outside),
    on points sampled uniformly by area over its wall faces (mm)."""
    from cathsim_dmc.anatomy import PRESETS, load_asset
    from cathsim_dmc.anatomy.arch import build_arch
    from cathsim_dmc.anatomy.sdf import arch_sdf_grid
    from cathsim_dmc.anatomy.validate import cap_faces

    asset = load_asset(folder)
    grid = arch_sdf_grid(build_arch(PRESETS["type1"]))
    v = asset.visual_vertices.astype(np.float64)
    f = asset.visual_faces[~cap_faces(asset)]
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(f), samples, p=area / area.sum())
    bary = rng.dirichlet(np.ones(3), size=samples)
    d = grid(np.einsum("nk,nkj->nj", bary, tri[pick])) * 1e3
    return dict(
        mean_abs_mm=float(np.mean(np.abs(d))),
        p99_abs_mm=float(np.percentile(np.abs(d), 99)),
        max_inward_mm=float(max(0.0, -d.min())),
        max_outward_mm=float(max(0.0, d.max())),
    )


def validation(folder: pathlib.Path) -> dict:
    from cathsim_dmc.anatomy.validate import validate_asset

    r = validate_asset(folder)
    return dict(
        pieces=r.hulls,
        holes=r.holes,
        shell_samples=r.shell_samples,
        max_intrusion_mm=max(0.0, r.max_intrusion_m) * 1e3,
        min_clearance_mm=r.min_clearance_m * 1e3,
        ok=r.ok,
        problems=r.problems,
        summary=r.summary(),
    )


# ----------------------------------------------------------------------------
# The wall as one SDF geom


def shell_mesh(pieces) -> tuple:
    """(vertices, faces) of the closed shell that the prisms fill: the lumen faces turned
    to face the lumen, the outer faces, and side quads along the open end's rim."""
    import trimesh

    prisms = np.asarray(pieces, dtype=np.float64)
    if prisms.ndim != 3 or prisms.shape[1] != 6:
        raise ValueError("the SDF shell needs 6-point prisms")
    vertices, inverse = np.unique(prisms.reshape(-1, 3).round(10), axis=0, return_inverse=True)
    ids = inverse.reshape(-1, 6)
    outer_of = dict(zip(ids[:, :3].ravel().tolist(), ids[:, 3:].ravel().tolist()))
    edges = np.concatenate([ids[:, [0, 1]], ids[:, [1, 2]], ids[:, [2, 0]]])
    _, first, counts = np.unique(np.sort(edges, axis=1), axis=0, return_index=True, return_counts=True)
    rim = edges[first[counts == 1]]
    sides = [[a, b, outer_of[b]] for a, b in rim] + [[a, outer_of[b], outer_of[a]] for a, b in rim]
    faces = np.concatenate([ids[:, [0, 2, 1]], ids[:, 3:], np.asarray(sides, dtype=np.int64).reshape(-1, 3)])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    trimesh.repair.fix_normals(mesh)
    if not mesh.is_watertight or mesh.volume <= 0:
        raise RuntimeError("the wall shell is not a closed, outward-oriented surface")
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


@contextlib.contextmanager
def sdf_wall(octree_depth):
    """While active, `Aorta.add_geoms` adds the wall as one SDF geom (named like the
    first prism, so that `wall_geom_ids` and the reset check find it) and the visual
    mesh as before; `geoms_key` says so (no compiled model of the prisms is reused)."""
    from cathsim_dmc.entities.aorta import Aorta

    def add_geoms(self, spec):
        prefix = self._prefix()
        body = spec.body(prefix) if prefix else spec.worldbody
        body = body or spec.worldbody
        if body.name != spec.worldbody.name and (np.any(body.pos != 0) or np.any(body.quat != [1, 0, 0, 0])):
            raise ValueError("the study's SDF wall expects the aorta at the world origin")
        v, f = shell_mesh(self.wall_pieces)
        mesh = spec.add_mesh(name=prefix + "wallsdf")
        mesh.uservert, mesh.userface = v.ravel(), f.ravel()
        if octree_depth is not None:
            mesh.octree_maxdepth = int(octree_depth)
        geom = spec.worldbody.add_geom(
            name=prefix + "hull0", type=mujoco.mjtGeom.mjGEOM_SDF, meshname=prefix + "wallsdf"
        )
        for key, value in self._wall.items():
            setattr(geom, key, value)
        vis = spec.add_mesh(name=prefix + "lumen")
        vis.uservert = self._asset.visual_vertices.astype(float).ravel()
        vis.userface = self._asset.visual_faces.ravel()
        geom = body.add_geom(name=prefix + "lumen", type=mujoco.mjtGeom.mjGEOM_MESH, meshname=prefix + "lumen")
        for key, value in {**self._wall, **self._visual}.items():
            setattr(geom, key, value)

    saved = Aorta.add_geoms, Aorta.geoms_key
    Aorta.add_geoms = add_geoms
    Aorta.geoms_key = property(lambda self: b"collision study sdf %r" % (octree_depth,) + saved[1].fget(self))
    try:
        yield
    finally:
        Aorta.add_geoms, Aorta.geoms_key = saved


# ----------------------------------------------------------------------------
# Environments and the probe


def wall_context(name):
    return sdf_wall(SDF_DEPTH[name]) if name in SDF_DEPTH else contextlib.nullcontext()


def aorta_of(name, folders) -> str:
    return str(folders[name]) if name in folders else "type1"


def load_env(name, folders, gym: bool = False, task: str = "bca"):
    from cathsim_dmc import tasks

    with wall_context(name):
        if gym:
            from cathsim_dmc.suite.gym import CathSimEnv

            return CathSimEnv(task, aorta_of(name, folders), physics="fast")
        return tasks.load(task, aorta_of(name, folders), seed=0, physics="fast")


def collision_states(model, data, state, steps, every=10) -> list:
    from physics_probe import STATE, start

    start(model, data, state)
    out = []
    for i in range(steps):
        mujoco.mj_step(model, data)
        if i % every == every - 1:
            s = np.empty(mujoco.mj_stateSize(model, STATE))
            mujoco.mj_getState(model, data, s, STATE)
            out.append(s)
    return out


def probe(names, folders, args) -> list:
    from physics_probe import masks, observe, save_states, start

    entries = {}
    for name in names:
        t0 = time.perf_counter()
        env = load_env(name, folders)
        build_s = time.perf_counter() - t0
        model = env.physics.model.ptr
        entries[name] = dict(
            env=env,
            model=model,
            data=mujoco.MjData(model),
            masks=masks(env),
            build_s=build_s,
            ngeom_wall=int(masks(env)[1].sum()),
            noct=int(model.noct),
            oct_depth=int(model.oct_depth.max()) if model.noct else None,
        )
        print(
            f"built {name}: {entries[name]['ngeom_wall']} wall geoms, {build_s:.1f} s"
            + (f", octree {model.noct} nodes, depth {entries[name]['oct_depth']}" if model.noct else ""),
            flush=True,
        )
    baseline = names[0]
    states = save_states(entries[baseline]["env"], args.at, np.array(args.action))
    rows = []
    for at, state in states:
        seen, coll_states = {}, {}
        for name in names:
            e = entries[name]
            wire, wall, tip = e["masks"]
            seen[name] = observe(e["model"], e["data"], state, args.steps, wire, wall, tip)
            coll_states[name] = collision_states(e["model"], e["data"], state, args.steps)
        times = {name: [] for name in names}
        coll = {name: [] for name in names}
        for repeat in range(args.repeats):
            shift = repeat % len(names)
            for name in names[shift:] + names[:shift]:
                model, data = entries[name]["model"], entries[name]["data"]
                start(model, data, state)
                begin = time.perf_counter()
                mujoco.mj_step(model, data, args.steps)
                times[name].append(time.perf_counter() - begin)
                spent = 0.0
                for s in coll_states[name]:
                    start(model, data, s)  # mj_forward: positions current
                    begin = time.perf_counter()
                    for _ in range(20):
                        mujoco.mj_collision(model, data)
                    spent += time.perf_counter() - begin
                coll[name].append(spent / (20 * len(coll_states[name])))
        base_t, base_c = statistics.median(times[baseline]), statistics.median(coll[baseline])
        for name in names:
            s = seen[name]
            row = dict(
                state=at,
                wall=name,
                time_ratio=statistics.median(times[name]) / base_t,
                step_ms=1e3 * statistics.median(times[name]) / args.steps,
                collision_ratio=statistics.median(coll[name]) / base_c,
                collision_us=1e6 * statistics.median(coll[name]),
                tip_off_mm=1e3 * float(np.linalg.norm(s["tip"] - seen[baseline]["tip"])),
                deepest_mm=1e3 * s["depth_m"],
                force_n=s["force_n"],
                contacts=s["contacts"],
                finite=s["finite"],
            )
            rows.append(row)
            print(
                f"| {at} | {name} | {row['time_ratio']:.2f} | {row['collision_ratio']:.2f} "
                f"({row['collision_us']:.0f} us) | {row['tip_off_mm']:.2f} | {row['deepest_mm']:.2f} | "
                f"{row['force_n']:.3f} | {row['contacts']:.1f} |" + ("" if row["finite"] else " diverged"),
                flush=True,
            )
    builds = {
        name: dict(
            build_s=e["build_s"], wall_geoms=e["ngeom_wall"], octree_nodes=e["noct"], octree_depth=e["oct_depth"]
        )
        for name, e in entries.items()
    }
    for e in entries.values():
        e["env"].close()
    return rows, builds


def expert_runs(names, folders, episodes: int, seed: int, sdf_episodes: int) -> dict:
    from cathsim_dmc.control.expert import CenterlineExpert

    out = {}
    for name in names:
        n = sdf_episodes if name in SDF_DEPTH else episodes
        for target in TARGETS if n else ():
            env = load_env(name, folders, gym=True, task=target)
            expert = CenterlineExpert()
            runs, begin = [], time.perf_counter()
            for episode in range(n):
                observation, info = env.reset(seed=seed + episode)
                done, escaped, peak = False, False, 0.0
                while not done:
                    observation, _, terminated, truncated, info = env.step(expert(observation, env))
                    done = terminated or truncated
                    escaped |= bool(info["escaped"])
                    peak = max(peak, float(info["mean_contact_force_n"]))
                runs.append(
                    dict(
                        seed=seed + episode,
                        success=bool(info["success"]),
                        escaped=escaped,
                        diverged=bool(info["diverged"]),
                        steps=int(info["step"]),
                        peak_mean_force_n=peak,
                    )
                )
            seconds = time.perf_counter() - begin
            env.close()
            out[f"{name}/{target}"] = dict(
                successes=sum(r["success"] for r in runs),
                escapes=sum(r["escaped"] for r in runs),
                divergences=sum(r["diverged"] for r in runs),
                episodes=len(runs),
                mean_steps=float(np.mean([r["steps"] for r in runs])),
                control_steps_per_s=sum(r["steps"] for r in runs) / seconds,
                runs=runs,
            )
            o = out[f"{name}/{target}"]
            print(
                f"expert {name} {target}: {o['successes']}/{o['episodes']} reached, {o['escapes']} escaped, "
                f"{o['divergences']} diverged, {o['mean_steps']:.0f} steps, {o['control_steps_per_s']:.0f} "
                f"control steps/s",
                flush=True,
            )
    return out


def main(argv=None) -> None:
    out_dir = _early_out(argv)
    os.environ["CATHSIM_DMC_CACHE"] = str(out_dir / "cache")  # compiled models and lumen fields under --out
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--walls", nargs="+", default=list(WALLS), choices=WALLS, help="the first is the baseline")
    parser.add_argument("--at", type=int, nargs="+", default=[60, 100, 150], help="control steps before each state")
    parser.add_argument("--action", type=float, nargs=2, default=[1.0, 0.2], help="insertion, rotation in [-1, 1]")
    parser.add_argument("--steps", type=int, default=100, help="raw mj_step calls per run (5 ms each)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=5, help="expert episodes per target (0: none)")
    parser.add_argument(
        "--sdf-episodes",
        type=int,
        default=1,
        help="expert episodes per target with an SDF wall (about 2-4 control steps/s)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=pathlib.Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    names = list(dict.fromkeys(args.walls))

    from cathsim_dmc.core.shipped import resolve_asset

    folders, walls = {}, {}
    for name in names:
        if name in COARSE:
            begin = time.perf_counter()
            folders[name] = build_coarse(name, args.out)
            walls[name] = dict(build_asset_s=time.perf_counter() - begin)
        folder = folders.get(name, resolve_asset("type1"))
        if name in SDF_DEPTH:
            walls[name] = dict(same_surface_as="today")
            continue
        walls.setdefault(name, {}).update(validation=validation(folder), deviation=surface_deviation(folder))
        v, d = walls[name]["validation"], walls[name]["deviation"]
        print(
            f"{name}: {v['pieces']} pieces, {v['holes']} holes of {v['shell_samples']}, intrusion "
            f"{v['max_intrusion_mm']:.3f} mm, clearance {v['min_clearance_mm']:.2f} mm, "
            f"{'valid' if v['ok'] else 'INVALID: ' + '; '.join(v['problems'])}; lumen off the exact surface: "
            f"mean {d['mean_abs_mm']:.3f}, p99 {d['p99_abs_mm']:.3f} mm, {d['max_inward_mm']:.2f} mm inward at "
            f"most",
            flush=True,
        )

    print(
        f"bca/type1, fast, action {args.action}, {args.steps} raw mj_step per run, median of {args.repeats} "
        f"interleaved runs; baseline {names[0]}"
    )
    print(
        "| state | wall | step time / baseline | collision / baseline | tip off baseline (mm) | deepest (mm) "
        "| mean wall force (N) | wall contacts |"
    )
    print("|---|---|---|---|---|---|---|---|")
    rows, builds = probe(names, folders, args)
    experts = expert_runs(names, folders, args.episodes, args.seed, args.sdf_episodes)
    result = dict(
        date=time.strftime("%Y-%m-%d"),
        mujoco=mujoco.__version__,
        args=vars(args) | {"out": str(args.out)},
        walls=walls,
        builds=builds,
        probe=rows,
        expert=experts,
    )
    path = args.out / "collision_study.json"
    path.write_text(json.dumps(result, indent=1, default=str))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
