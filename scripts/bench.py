"""Control steps per second of the navigation task, per observation preset.

    python scripts/bench.py [--aorta type1] [--obs internal enn] [--steps 200] [--repeats 3]

Forward insertion with a slow rotation from reset, so the wire climbs the descending
aorta and reaches the arch: contacts included. Prints the median of the repeats.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import numpy as np


def measure(task: str, aorta: str, obs: str, steps: int) -> dict:
    from cathsim_dmc import tasks

    start = time.perf_counter()
    env = tasks.load(task, aorta, obs=obs, seed=0)
    env.reset()
    build_s = time.perf_counter() - start
    action = np.array([1.0, 0.2])
    start = time.perf_counter()
    for _ in range(steps):
        if env.step(action).last():
            env.reset()
    wall = time.perf_counter() - start
    control_dt = env.control_timestep()
    env.close()
    return {"steps_per_s": steps / wall, "realtime": steps * control_dt / wall, "build_s": build_s}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="bca")
    parser.add_argument("--aorta", default="type1")
    parser.add_argument("--obs", nargs="+", default=["internal", "enn"])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(f"{time.strftime('%Y-%m-%d')} {platform.processor() or platform.machine()} "
          f"{__import__('os').cpu_count()} cores; {args.task}/{args.aorta}, {args.steps} control steps, "
          f"median of {args.repeats}")
    print("| obs | control steps/s | simulated s per wall s | env build s |")
    print("|---|---|---|---|")
    for obs in args.obs:
        runs = [measure(args.task, args.aorta, obs, args.steps) for _ in range(args.repeats)]
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        print(f"| {obs} | {med['steps_per_s']:.1f} | {med['realtime']:.2f} | {med['build_s']:.2f} |")


if __name__ == "__main__":
    main()
