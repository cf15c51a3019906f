"""The fidelity gate of the physics settings: every check, each setting side by side.

    python experiments/fidelity_gate.py                  # all six aortas, both targets, 20 seeds
    python experiments/fidelity_gate.py --aortas type1 --seeds 5 --json gate.json

A solver setting (`cathsim_dmc.sim.physics.PHYSICS_SETTINGS`) may become the default only
if, measured in the same run as the others:

* the wire's physical checks hold (`cathsim_dmc.evaluation.fidelity`: cantilever against
  Euler-Bernoulli, tip rest angles, the 1 N push read by the wall, the tip following the
  carriage into the arch and back);
* the scripted expert reaches at least as many targets over `--seeds` seeds on every
  aorta and target, with no escape and no divergence;
* its wall forces (step mean and each control step's physics-step peak, over all those
  expert episodes) and path lengths stay close.

The checks are interleaved setting by setting for each aorta, so a loaded machine slows
them alike; the wall times are printed but are not the speed benchmark (`cathsim-bench`).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from cathsim_dmc.control.policies import make_policy
from cathsim_dmc.core.shipped import available_aortas
from cathsim_dmc.evaluation import fidelity
from cathsim_dmc.evaluation.metrics import polyline_length_m
from cathsim_dmc.sim.physics import PHYSICS_SETTINGS
from cathsim_dmc.suite.gym import CathSimEnv


def wire_checks(setting: str) -> dict:
    out = {}
    for n in (10, 40):
        measured, analytic, at_rest = fidelity.cantilever_deflection(n, setting)
        out[f"cantilever error, {n} segments (%)"] = 100 * (measured / analytic - 1) if at_rest else float("nan")
    for shape, angle in (("angled", 45.0), ("angled", 70.0), ("j", 180.0)):
        out[f"tip angle, {shape} {angle:.0f} deg (deg)"] = fidelity.tip_rest_angle(shape, angle, setting)[0]
    for margin in (0.0, 1e-3):
        push = fidelity.wall_push(margin, setting, push_n=1.0)
        out[f"1 N push read by the wall, margin {1e3 * margin:.0f} mm (N)"] = push.total_n
        out[f"tip end past the wall face, margin {1e3 * margin:.0f} mm (mm)"] = 1e3 * (
            push.tip_end_m - fidelity.WALL_FACE_M
        )
    response = fidelity.insertion_response(setting)
    out["insertion: tip/carriage advance inserting"] = response.insert_ratio
    out["insertion: tip/carriage advance retracting"] = response.retract_ratio
    out["insertion: largest slack (mm)"] = 1e3 * response.max_slack_m
    out["insertion: escaped or diverged"] = float(response.escaped or response.diverged)
    out["_insertion_tip_m"] = response.tip_m.tolist()
    return out


def expert_episodes(setting: str, aorta: str, target: str, seeds: int) -> dict:
    env = CathSimEnv(task=target, aorta=aorta, obs="internal", physics=setting)
    successes, escapes, divergences, lengths, paths, means, peaks = 0, 0, 0, [], [], [], []
    for seed in range(seeds):
        observation, info = env.reset(seed=seed)
        policy = make_policy("expert", seed=seed)
        tips, done = [info["tip_position_m"]], False
        while not done:
            observation, _, terminated, truncated, info = env.step(policy(observation, env))
            tips.append(info["tip_position_m"])
            means.append(info["mean_contact_force_n"])
            peaks.append(info["peak_contact_force_n"])
            done = terminated or truncated
        successes += int(info["success"])
        escapes += int(info["escaped"])
        divergences += int(info["diverged"])
        lengths.append(info["step"])
        paths.append(polyline_length_m(tips))
    env.close()
    return dict(
        successes=successes,
        episodes=seeds,
        escapes=escapes,
        divergences=divergences,
        steps=lengths,
        path_m=paths,
        mean_n=means,
        peak_n=peaks,
    )


def percentiles(values, qs=(50, 99, 100)) -> str:
    return " / ".join(f"{v:.2f}" for v in np.percentile(np.asarray(values, dtype=float), qs))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--settings", nargs="+", default=list(PHYSICS_SETTINGS), choices=list(PHYSICS_SETTINGS))
    parser.add_argument("--aortas", nargs="+", default=available_aortas())
    parser.add_argument("--targets", nargs="+", default=["bca", "lcca"])
    parser.add_argument("--seeds", type=int, default=20, help="expert episodes per aorta and target (seeds 0..N-1)")
    parser.add_argument("--json", help="write every measurement to this file")
    args = parser.parse_args(argv)
    unknown = sorted(set(args.aortas) - set(available_aortas()))
    if unknown:
        print(f"unknown aorta {unknown[0]!r}; choose from {available_aortas()}", file=sys.stderr)
        return 2

    started = time.time()
    wire = {s: wire_checks(s) for s in args.settings}
    expert = {s: {} for s in args.settings}
    seconds = {s: 0.0 for s in args.settings}
    for aorta in args.aortas:
        for target in args.targets:
            for s in args.settings:  # interleaved: a loaded machine slows every setting alike
                t0 = time.time()
                expert[s][f"{target}/{aorta}"] = expert_episodes(s, aorta, target, args.seeds)
                seconds[s] += time.time() - t0
                row = expert[s][f"{target}/{aorta}"]
                print(f"{target}/{aorta} {s}: {row['successes']}/{row['episodes']}", file=sys.stderr, flush=True)

    header = "| check | " + " | ".join(f"`{s}`" for s in args.settings) + " |"
    rule = "|---|" + "---|" * len(args.settings)
    print(header, rule, sep="\n")
    for key in wire[args.settings[0]]:
        if not key.startswith("_"):
            print(f"| {key} | " + " | ".join(f"{wire[s][key]:.4g}" for s in args.settings) + " |")
    first = np.asarray(wire[args.settings[0]]["_insertion_tip_m"])
    print(
        "| insertion: tip's distance from the first setting's (mm) | "
        + " | ".join(
            f"{1e3 * np.linalg.norm(np.asarray(wire[s]['_insertion_tip_m']) - first):.2f}" for s in args.settings
        )
        + " |"
    )

    print("\n| target/aorta | " + " | ".join(f"`{s}` success" for s in args.settings) + " |")
    print("|---|" + "---|" * len(args.settings))
    for key in expert[args.settings[0]]:
        print(
            f"| {key} | "
            + " | ".join(f"{expert[s][key]['successes']}/{expert[s][key]['episodes']}" for s in args.settings)
            + " |"
        )

    def pooled(s, field):
        return [v for row in expert[s].values() for v in (row[field] if isinstance(row[field], list) else [row[field]])]

    print("\n| all expert episodes | " + " | ".join(f"`{s}`" for s in args.settings) + " |")
    print(rule)
    rows = {
        "success": lambda s: f"{sum(pooled(s, 'successes'))}/{sum(pooled(s, 'episodes'))}",
        "escaped / diverged episodes": lambda s: f"{sum(pooled(s, 'escapes'))} / {sum(pooled(s, 'divergences'))}",
        "step-mean wall force p50 / p99 / max (N)": lambda s: percentiles(pooled(s, "mean_n")),
        "mean of the step-mean wall force (N)": lambda s: f"{np.mean(pooled(s, 'mean_n')):.4f}",
        "physics-step peak p50 / p99 / max (N)": lambda s: percentiles(pooled(s, "peak_n")),
        "p99.9 of the physics-step peak (N)": lambda s: f"{np.percentile(pooled(s, 'peak_n'), 99.9):.2f}",
        "path length, mean (cm)": lambda s: f"{100 * np.mean(pooled(s, 'path_m')):.1f}",
        "episode length, mean (steps)": lambda s: f"{np.mean(pooled(s, 'steps')):.1f}",
        "control steps/s in this run (not a benchmark)": lambda s: f"{sum(pooled(s, 'steps')) / seconds[s]:.1f}",
    }
    for name, cell in rows.items():
        print(f"| {name} | " + " | ".join(cell(s) for s in args.settings) + " |")
    print(f"\n{time.time() - started:.0f} s", file=sys.stderr)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dict(wire=wire, expert=expert, seconds=seconds), f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
