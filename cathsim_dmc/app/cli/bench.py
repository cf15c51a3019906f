"""cathsim-bench: speed of the navigation environments on this machine.

    cathsim-bench                                   # bca/type1, obs internal and enn
    cathsim-bench aortas=[type1,type2] presets=[internal] steps=300
    cathsim-bench presets=[enn] renderers=[raster,gl] styles=[camera,fluoro]
    cathsim-bench physics_settings=[fast]           # one solver setting (default: both, side by side)

For each (aorta, observation preset), in a fresh process: env build time (construct +
first reset, which compiles), reset time without recompilation, control steps/s and
simulated seconds per wall second for a standard scenario (full insertion with a slow
rotation from reset: the wire climbs the descending aorta and works into the arch), the
time raw ``mujoco.mj_step`` needs for the same physics steps and controls (so the
overhead of dm_control, observations and the task is visible), and peak RSS. Presets
with images are measured once per renderer and style; "image ms" is the time of the
image observables alone (pixels and mask, as enabled) on the final state.
"""

from __future__ import annotations

import logging
import multiprocessing
import platform
import statistics
import time

import numpy as np

log = logging.getLogger("cathsim-bench")

SCENARIO_ACTION = (1.0, 0.2)  # insertion, rotation


def measure(
    task: str, aorta: str, obs: str, steps: int, renderer: str = "-", style: str = "-", physics: str | None = None
) -> dict:
    """One measurement, meant to run in its own process (for a clean peak RSS)."""
    import resource

    import mujoco

    import cathsim_dmc  # noqa: F401  (GL backend)
    from cathsim_dmc import tasks

    image_options = {} if renderer == "-" else dict(renderer=renderer, style=style)
    start = time.perf_counter()
    physics_options = {} if physics is None else dict(physics=physics)
    env = tasks.load(task, aorta, obs=obs, seed=0, **physics_options, **image_options)
    env.reset()
    build_s = time.perf_counter() - start
    resets = []
    for _ in range(5):
        start = time.perf_counter()
        env.reset()
        resets.append(time.perf_counter() - start)

    env.reset()
    physics = env.physics
    model, data = physics.model.ptr, physics.data.ptr
    initial = mujoco.MjData(model)
    mujoco.mj_copyData(initial, model, data)
    action = np.array(SCENARIO_ACTION)
    controls, contacts = [], []
    start = time.perf_counter()
    for _ in range(steps):
        timestep = env.step(action)
        controls.append(data.ctrl.copy())
        contacts.append(data.ncon)
        if timestep.last():
            break
    wall = time.perf_counter() - start
    done = len(controls)
    n_sub = env.task.physics_steps_per_control_step

    # Raw MuJoCo on the same model, state and controls.
    raw = initial
    start = time.perf_counter()
    for ctrl in controls:
        raw.ctrl[:] = ctrl
        mujoco.mj_step(model, raw, n_sub)
    raw_wall = time.perf_counter() - start
    control_dt = env.control_timestep()
    image_ms = _image_ms(env, style) if image_options else 0.0
    env.close()
    return {
        "aorta": aorta,
        "obs": obs,
        "renderer": renderer,
        "style": style,
        "steps": done,
        "steps_per_s": done / wall,
        "realtime": done * control_dt / wall,
        "raw_steps_per_s": done / raw_wall,
        "overhead": wall / raw_wall,
        "mean_contacts": float(np.mean(contacts)),
        "build_s": build_s,
        "reset_ms": 1e3 * statistics.median(resets),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "image_ms": image_ms,
    }


def _image_ms(env, style: str, calls: int = 20, rounds: int = 5) -> float:
    """Milliseconds for the enabled image observables of one step (median of rounds)."""
    view, physics = env.task.top_view, env.physics
    enabled = env.task.observation_settings.enabled
    renders = []
    if "pixels" in enabled:
        renders.append(lambda: view.image(physics, style))
    if "guidewire_mask" in enabled:
        renders.append(lambda: view.mask(physics))
    times = []
    for _ in range(rounds):
        start = time.perf_counter()
        for _ in range(calls):
            for render in renders:
                render()
        times.append((time.perf_counter() - start) / calls)
    return 1e3 * statistics.median(times)


def _measure_in_subprocess(args):
    return measure(*args)


def run(cfg) -> list:
    import os

    from cathsim_dmc import tasks
    from cathsim_dmc.sim.render import IMAGE_STYLES, RENDERERS
    from cathsim_dmc.tasks.presets import OBSERVATION_PRESETS

    settings = list(cfg.physics_settings)
    for physics in settings:
        tasks.check_options(physics=physics)
    for aorta in cfg.aortas:
        tasks.validate(cfg.task.target, aorta)
    for obs in cfg.presets:
        tasks.validate(cfg.task.target, cfg.aortas[0], obs)
    for name, values, valid in (("renderers", cfg.renderers, RENDERERS), ("styles", cfg.styles, IMAGE_STYLES)):
        for value in values:
            if value not in valid:
                raise ValueError(f"{name}: {value!r} is not one of {list(valid)}")
    context = multiprocessing.get_context("spawn")
    print(
        f"{time.strftime('%Y-%m-%d')}, {platform.machine()}, {os.cpu_count()} cores; task {cfg.task.target}, "
        f"{cfg.steps} control steps of 0.1 s (action {SCENARIO_ACTION}), median of {cfg.repeats}; the physics "
        f"settings of one row group are measured in turn, repeat by repeat, so a noisy machine treats them alike"
    )
    header = (
        "| aorta | obs | renderer | style | physics | control steps/s | x real time | raw mj_step steps/s | overhead "
        "| contacts | build s | reset ms | peak RSS MB | image ms |"
    )
    print(header)
    print("|---" * (header.count("|") - 1) + "|")
    rows = []
    for aorta in cfg.aortas:
        for obs in cfg.presets:
            has_images = bool(OBSERVATION_PRESETS[obs].enabled & {"pixels", "guidewire_mask"})
            image_settings = [(r, s) for r in cfg.renderers for s in cfg.styles] if has_images else [("-", "-")]
            for renderer, style in image_settings:
                runs = {physics: [] for physics in settings}
                for _ in range(cfg.repeats):
                    for physics in settings:
                        with context.Pool(1) as pool:
                            runs[physics].append(
                                pool.apply(
                                    _measure_in_subprocess,
                                    ((cfg.task.target, aorta, obs, cfg.steps, renderer, style, physics),),
                                )
                            )
                for physics in settings:
                    found = runs[physics]
                    med = {
                        k: (statistics.median(r[k] for r in found) if isinstance(found[0][k], float) else found[0][k])
                        for k in found[0]
                    }
                    med["physics"] = physics
                    rows.append(med)
                    print(
                        f"| {aorta} | {obs} | {renderer} | {style} | {physics} | {med['steps_per_s']:.1f} | "
                        f"{med['realtime']:.2f} | {med['raw_steps_per_s']:.1f} | {med['overhead']:.2f} | "
                        f"{med['mean_contacts']:.0f} | {med['build_s']:.2f} | {med['reset_ms']:.1f} | "
                        f"{med['peak_rss_mb']:.0f} | {med['image_ms']:.2f} |",
                        flush=True,
                    )
    return rows


def main():
    from cathsim_dmc.app.cli._common import run_hydra

    run_hydra(run, "bench")


if __name__ == "__main__":
    main()
