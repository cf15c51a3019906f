"""Two collision levers measured from saved arch states (issue 20): culling and threads.

    python experiments/contact_culling_probe.py        # type1, states after 60/100/150 steps

Drives the BCA task (`fast` physics) with full insertion and slow rotation, as
`experiments/physics_probe.py` does, and at each of `--at` control steps measures:

* **Culling wire segments far from the wall.** Each wire capsule's clearance from the
  lumen (the closest of 15 points along its axis to the asset's lumen mesh, exact
  point-to-triangle distance, minus the wire radius), then the time of ``mj_collision``
  with the capsules beyond a clearance taken out of collision (their contype and
  conaffinity set to 0, the body-level bits too), and with the "oracle" cull: every
  capsule that has no contact in this state (no real test can know that without
  running the collision). Median of `--repeats` runs of 30 calls each.
* **MuJoCo's thread pool** (``mujoco.mju_threadpool``: collision and island solving
  across worker threads): raw ``mj_step`` from the state with 0, 1 and 2 workers, and
  whether the states after `--steps` steps match the single-threaded run.

Times depend on the machine and its load: compare the rows of one run.
"""

from __future__ import annotations

import argparse
import statistics
import time

import mujoco
import numpy as np
import trimesh

from cathsim_dmc import tasks

CLEARANCES_M = (0.5e-3, 1e-3, 2e-3)


def lumen_mesh(model, data, geom_name: str) -> trimesh.Trimesh:
    """The lumen's mesh geom in world coordinates."""
    geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, geom_name)
    mesh = model.geom_dataid[geom]
    vert0, face0 = model.mesh_vertadr[mesh], model.mesh_faceadr[mesh]
    vertices = model.mesh_vert[vert0 : vert0 + model.mesh_vertnum[mesh]].astype(float)
    faces = model.mesh_face[face0 : face0 + model.mesh_facenum[mesh]]
    vertices = vertices @ data.geom_xmat[geom].reshape(3, 3).T + data.geom_xpos[geom]
    return trimesh.Trimesh(vertices, faces, process=False)


def median_time_s(function, calls: int, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            function()
        times.append((time.perf_counter() - start) / calls)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--aorta", default="type1")
    parser.add_argument("--at", type=int, nargs="+", default=[60, 100, 150])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--steps", type=int, default=200, help="raw mj_step calls per thread-pool run")
    args = parser.parse_args()

    env = tasks.load("bca", args.aorta, seed=0, physics="fast")
    env.reset()
    model, data = env.physics.model.ptr, env.physics.data.ptr
    mesh = lumen_mesh(model, data, f"{env.task.aorta.mjcf_model.model}/lumen")
    wire = np.flatnonzero(
        np.isin(model.geom_bodyid, env.physics.bind(env.task.guidewire.segments).element_id) & (model.geom_contype > 0)
    )
    wire_bodies = model.geom_bodyid[wire]
    half_length, radius = model.geom_size[wire, 1], model.geom_size[wire, 0]
    along = np.linspace(-1.0, 1.0, 15)
    bits = [
        getattr(model, name).copy() for name in ("geom_contype", "geom_conaffinity", "body_contype", "body_conaffinity")
    ]

    def collide_without(cull: np.ndarray) -> tuple[float, int]:
        for name, ids in (
            ("geom_contype", wire),
            ("geom_conaffinity", wire),
            ("body_contype", wire_bodies),
            ("body_conaffinity", wire_bodies),
        ):
            getattr(model, name)[ids[cull]] = 0
        seconds = median_time_s(lambda: mujoco.mj_collision(model, data), 30, args.repeats)
        contacts = data.ncon
        for name, saved in zip(("geom_contype", "geom_conaffinity", "body_contype", "body_conaffinity"), bits):
            getattr(model, name)[:] = saved
        return seconds, contacts

    step = 0
    state_kind = mujoco.mjtState.mjSTATE_INTEGRATION
    for at in args.at:
        while step < at:
            env.step(np.array([1.0, 0.2]))
            step += 1
        mujoco.mj_forward(model, data)
        touching = np.isin(wire, data.contact.geom[: data.ncon].ravel())
        points = (
            data.geom_xpos[wire][:, None, :]
            + along[None, :, None] * half_length[:, None, None] * data.geom_xmat[wire][:, None, 6:9]
        ).reshape(-1, 3)
        _, distance, _ = trimesh.proximity.closest_point(mesh, points)
        clearance = distance.reshape(len(wire), -1).min(axis=1) - radius
        print(
            f"state after {at} control steps: {data.ncon} contacts, {touching.sum()} of {len(wire)} wire "
            f"capsules in contact, clearance <= 0.3 mm for {(clearance <= 0.3e-3).sum()}"
        )
        base, _ = collide_without(np.zeros(len(wire), dtype=bool))
        rows = [("oracle: every capsule without a contact", ~touching)]
        rows += [(f"clearance > {c * 1e3:.1f} mm", clearance > c) for c in CLEARANCES_M]
        print(f"  mj_collision, all capsules: {base * 1e6:.0f} us")
        for label, cull in rows:
            seconds, contacts = collide_without(cull)
            print(f"  {label}: {cull.sum()} culled, {seconds * 1e6:.0f} us ({seconds / base:.2f}), {contacts} contacts")

        state = np.empty(mujoco.mj_stateSize(model, state_kind))
        mujoco.mj_getState(model, data, state, state_kind)
        end_states = {}
        for workers in (0, 1, 2):
            threaded = mujoco.MjData(model)
            if workers:
                mujoco.mju_threadpool(threaded, workers)

            def run(threaded=threaded):
                mujoco.mj_setState(model, threaded, state, state_kind)
                for _ in range(args.steps):
                    mujoco.mj_step(model, threaded)

            seconds = median_time_s(run, 1, args.repeats) / args.steps
            end_states[workers] = threaded.qpos.copy()
            same = np.array_equal(end_states[workers], end_states[0])
            print(
                f"  mj_step with {workers} worker threads: {seconds * 1e6:.0f} us per step, "
                f"end state {'identical to' if same else 'differs from'} the single-threaded run"
            )


if __name__ == "__main__":
    main()
