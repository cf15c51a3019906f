"""What an observation preset costs per control step: the whole step (physics, task and
observations) and the enabled observables alone, for presets side by side and the `fluoro`
preset at several image sizes.

    .venv/bin/python scripts/observation_cost.py                      # roadmap, tracking_2d, fluoro at 64-192 px
    .venv/bin/python scripts/observation_cost.py --presets roadmap fluoro --sizes 128 --repeats 7

"beyond raw mj_step" is the step's time less raw MuJoCo's for the same physics steps and
controls (the task's, the observations' and dm_control's share); "observables alone" times
the enabled observables (with their noise) on the final state. Every measurement runs in a
fresh process; the settings are measured in turn within each
repeat (so a machine shared with other work treats them alike), and the median over
repeats is printed. The scenario is cathsim-bench's: bca/type1 reset with seed 0, then
full insertion with a slow rotation for `--steps` control steps (the wire climbs the
descending aorta and works into the arch).
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import platform
import statistics
import time

import numpy as np

SCENARIO_ACTION = (1.0, 0.2)  # cathsim-bench's


def measure(obs: str, image_size: int | None, steps: int) -> dict:
    import mujoco

    import cathsim_dmc  # noqa: F401  (GL backend)
    from cathsim_dmc import tasks

    options = {} if image_size is None else dict(image_size=image_size)
    env = tasks.load("bca", "type1", obs=obs, seed=0, **options)
    env.reset()
    model, data = env.physics.model.ptr, env.physics.data.ptr
    initial = mujoco.MjData(model)
    mujoco.mj_copyData(initial, model, data)
    action = np.array(SCENARIO_ACTION)
    times, controls = [], []
    for _ in range(steps):
        start = time.perf_counter()
        timestep = env.step(action)
        times.append(time.perf_counter() - start)
        controls.append(data.ctrl.copy())
        if timestep.last():
            break
    # Raw MuJoCo on the same model, state and controls: what the step costs beyond it is
    # the task's and the observations' (and dm_control's).
    substeps = env.task.physics_steps_per_control_step
    start = time.perf_counter()
    for ctrl in controls:
        initial.ctrl[:] = ctrl
        mujoco.mj_step(model, initial, substeps)
    raw_ms = 1e3 * (time.perf_counter() - start) / len(controls)
    # The enabled observables alone (with their corruptors), on the final state.
    physics, random_state = env.physics, np.random.RandomState(0)
    callables = [
        item.observation_callable(physics, random_state) for item in env.task.task_observables.values() if item.enabled
    ]
    observe = []
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(20):
            for call in callables:
                call()
        observe.append((time.perf_counter() - start) / 20)
    env.close()
    step_ms = 1e3 * float(np.mean(times))
    return {
        "step_ms": step_ms,
        "beyond_ms": step_ms - raw_ms,
        "observe_ms": 1e3 * statistics.median(observe),
        "steps": len(times),
    }


def _measure(args):
    return measure(*args)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", default=["roadmap", "tracking_2d", "fluoro"])
    parser.add_argument("--sizes", nargs="+", type=int, default=[64, 80, 96, 128, 160, 192], help="fluoro image sizes")
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    settings = [(p, size) for p in args.presets for size in (args.sizes if p == "fluoro" else [None])]
    context = multiprocessing.get_context("spawn")
    runs = {s: [] for s in settings}
    for _ in range(args.repeats):
        for obs, size in settings:
            with context.Pool(1) as pool:
                runs[obs, size].append(pool.apply(_measure, ((obs, size, args.steps),)))
    print(
        f"{time.strftime('%Y-%m-%d')}, {platform.machine()}, {os.cpu_count()} cores; bca/type1, "
        f"{args.steps} control steps of action {SCENARIO_ACTION}, median of {args.repeats} processes"
    )
    print("| obs | image size | ms per control step | beyond raw mj_step, ms | observables alone, ms | steps |")
    print("|---|---|---|---|---|---|")
    for obs, size in settings:
        found = runs[obs, size]
        cells = [f"{statistics.median(r[key] for r in found):.2f}" for key in ("step_ms", "beyond_ms", "observe_ms")]
        print(f"| {obs} | {size or '-'} | {' | '.join(cells)} | {found[0]['steps']} |")


if __name__ == "__main__":
    main()
