"""Physics settings against each other, from the same saved states in the arch.

    python experiments/physics_probe.py                   # type1, states after 60/100/150 steps
    python experiments/physics_probe.py --steps 200 --repeats 7 --variants accurate fast pgs10 wall_frame

Drives the BCA task with a fixed action (full insertion, slow rotation: the wire climbs
the descending aorta and works into the arch, then buckles there) under the `accurate`
settings and saves the state after each of `--at` control steps. From each saved state
every variant takes `--steps` raw ``mujoco.mj_step`` calls (the controls held), the
variants interleaved and the order rotated, `--repeats` times. It prints, per state and
variant, the median time as a ratio to the baseline (the first variant), the tip's
distance after the steps from where the baseline's tip ended, the deepest wall contact
past the lumen surface and the mean total wall contact force over the steps (both read
after each step, in an untimed run). Times are ratios only: absolute speeds depend on the
machine and its load.

Variants: `accurate`, `fast` and `fast_field` (`cathsim_dmc.sim.physics.PHYSICS_SETTINGS`,
compiled through `tasks.load`; `fast_field` has the distance-field wall), `accurate` with one
of fast's options (`pgs10`: PGS at 10 iterations, `dense`: dense Jacobian, `noslip0`: no noslip, `sleep`: sleep on), and
`wall_frame`: accurate with the wall in the aorta's attachment body, as before
(the plain MJCF build, slow to build).
"""

from __future__ import annotations

import argparse
import copy
import statistics
import time

import mujoco
import numpy as np

from cathsim_dmc import tasks
from cathsim_dmc.sim import physics as cs_physics

STATE = mujoco.mjtState.mjSTATE_INTEGRATION  # time, qpos, qvel, act, warm start, controls, ...
ONE_OPTION = {  # accurate with one of fast's settings
    "pgs10": dict(solver=mujoco.mjtSolver.mjSOL_PGS, iterations=10),
    "dense": dict(jacobian=mujoco.mjtJacobian.mjJAC_DENSE),
    "noslip0": dict(noslip_iterations=0),
    "sleep": dict(enableflags=int(mujoco.mjtEnableBit.mjENBL_SLEEP)),
}
FAST_BUT = {  # fast with one setting changed
    "fast_newton": dict(solver=mujoco.mjtSolver.mjSOL_NEWTON, iterations=100),
    "fast_pgs20": dict(iterations=20),
    "fast_pgs30": dict(iterations=30),
}
VARIANTS = ("accurate", "fast", "fast_field", *ONE_OPTION, *FAST_BUT, "wall_frame")


def masks(env) -> tuple:
    """(wire geoms, wall geoms, tip site) of `env`'s model: the field wall's model
    numbers its geoms differently from the prisms'."""
    physics, task = env.physics, env.task
    wire = np.zeros(physics.model.ngeom, dtype=bool)
    wire[physics.bind(task.guidewire.geoms).element_id] = True
    wall = np.zeros(physics.model.ngeom, dtype=bool)
    wall[task.aorta.wall_geom_ids(physics)] = True
    return wire, wall, int(physics.bind(task.guidewire.tip_site).element_id)


def build_variants(names, task: str, aorta: str) -> tuple:
    """({name: MjModel}, {name: masks}, the accurate environment, which saves the states)."""
    accurate = tasks.load(task, aorta, seed=0, physics="accurate")
    models, geoms = {}, {}
    for name in names:
        geoms[name] = masks(accurate)
        if name == "accurate":
            models[name] = accurate.physics.model.ptr
        elif name in ("fast", "fast_field"):
            env = tasks.load(task, aorta, physics=name)
            models[name] = copy.copy(env.physics.model.ptr)
            geoms[name] = masks(env)
        elif name in FAST_BUT:
            env = tasks.load(task, aorta, physics="fast")
            model = copy.copy(env.physics.model.ptr)
            for key, value in FAST_BUT[name].items():
                setattr(model.opt, key, value)
            models[name] = model
            geoms[name] = masks(env)
        elif name == "wall_frame":
            env = tasks.load(task, aorta, physics="accurate", aorta_options=dict(hulls_in_mjcf=True))
            models[name] = copy.copy(env.physics.model.ptr)
            geoms[name] = masks(env)
        else:
            model = copy.copy(accurate.physics.model.ptr)  # options set at run time act as compiled ones
            for key, value in ONE_OPTION[name].items():
                if key == "enableflags":
                    value |= model.opt.enableflags
                setattr(model.opt, key, value)
            models[name] = model
    return models, geoms, accurate


def save_states(env, at_steps, action) -> list:
    """Integration states after each of `at_steps` control steps of `action` from reset."""
    env.reset()
    model, data = env.physics.model.ptr, env.physics.data.ptr
    states, step = [], 0
    for target in sorted(at_steps):
        while step < target:
            env.step(action)
            step += 1
        state = np.empty(mujoco.mj_stateSize(model, STATE))
        mujoco.mj_getState(model, data, state, STATE)
        states.append((target, state))
    return states


def start(model, data, state) -> None:
    """`data` in the saved `state`, everything awake (sleep is not part of a state)."""
    mujoco.mj_resetData(model, data)
    mujoco.mj_setState(model, data, state, STATE)
    mujoco.mj_forward(model, data)


def observe(model, data, state, steps: int, wire, wall, tip_site: int) -> dict:
    """Untimed run: tip after `steps`, deepest wall contact and mean wall force over them."""
    start(model, data, state)
    reader = cs_physics.WallForceTotal(wire, wall)
    forces, depths, contacts = [], [], []
    for _ in range(steps):
        mujoco.mj_step(model, data)
        # After mj_step, contacts and forces are those of the state before integration.
        forces.append(reader.total_n(data))
        n = data.ncon
        keep = wire[data.contact.geom[:n]].any(axis=1) & wall[data.contact.geom[:n]].any(axis=1)
        inside = data.contact.includemargin[:n][keep] - data.contact.dist[:n][keep]
        depths.append(float(inside.max()) if keep.any() else 0.0)
        contacts.append(int(keep.sum()))
    mujoco.mj_kinematics(model, data)
    return dict(
        tip=data.site_xpos[tip_site].copy(),
        force_n=float(np.mean(forces)),
        depth_m=max(depths),
        contacts=float(np.mean(contacts)),
        finite=bool(np.isfinite(data.qpos).all()),
    )


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="bca")
    parser.add_argument("--aorta", default="type1")
    parser.add_argument("--at", type=int, nargs="+", default=[60, 100, 150], help="control steps before each state")
    parser.add_argument("--action", type=float, nargs=2, default=[1.0, 0.2], help="insertion, rotation in [-1, 1]")
    parser.add_argument("--steps", type=int, default=100, help="raw mj_step calls per run (5 ms each)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument(
        "--variants",
        nargs="+",
        default=["accurate", "fast", *ONE_OPTION],
        choices=VARIANTS,
        help="the first is the baseline",
    )
    args = parser.parse_args(argv)

    models, geoms, env = build_variants(args.variants, args.task, args.aorta)
    states = save_states(env, args.at, np.array(args.action))
    datas = {name: mujoco.MjData(model) for name, model in models.items()}
    baseline = args.variants[0]

    print(
        f"{args.task}/{args.aorta}, action {args.action}, {args.steps} raw mj_step per run, median of "
        f"{args.repeats} interleaved runs; baseline {baseline}"
    )
    print(
        "| state (control steps) | variant | time / baseline | tip off baseline (mm) | deepest contact (mm) "
        "| mean wall force (N) | wall contacts |"
    )
    print("|---|---|---|---|---|---|---|")
    for at, state in states:
        seen = {name: observe(models[name], datas[name], state, args.steps, *geoms[name]) for name in args.variants}
        times = {name: [] for name in args.variants}
        for repeat in range(args.repeats):
            shift = repeat % len(args.variants)
            for name in args.variants[shift:] + args.variants[:shift]:
                model, data = models[name], datas[name]
                start(model, data, state)
                begin = time.perf_counter()
                mujoco.mj_step(model, data, args.steps)
                times[name].append(time.perf_counter() - begin)
        base_time = statistics.median(times[baseline])
        for name in args.variants:
            s = seen[name]
            off_mm = 1e3 * float(np.linalg.norm(s["tip"] - seen[baseline]["tip"]))
            print(
                f"| {at} | {name} | {statistics.median(times[name]) / base_time:.2f} | {off_mm:.3f} | "
                f"{1e3 * s['depth_m']:.2f} | {s['force_n']:.3f} | {s['contacts']:.1f} |"
                + ("" if s["finite"] else " diverged"),
                flush=True,
            )


if __name__ == "__main__":
    main()
