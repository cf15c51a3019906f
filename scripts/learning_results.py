"""Learning curves of cathsim-train variants, and the results tables of docs/training.md.

    python scripts/learning_results.py run  --variants demos_internal --tasks bca-type1 --seeds 0 1 2
    python scripts/learning_results.py report --out table.md --plot curves.png

`run` trains each (variant, task, seed) that has no finished run under --root (a run is
finished when its eval/metrics.json exists and it took --steps; an interrupted one, or a
finished one given a larger --steps, is resumed from its last checkpoint), one after the
other. Every run evaluates its policy deterministically every --eval-every steps on 10
episodes (evaluations.jsonl; the best one is kept as best.zip) and ends with a 50-episode
report of best.zip on seeds it was not chosen on.
`report` reads every run under --root and writes, per (variant, task): steps and wall
time to the first periodic evaluation at >= 90% success, and the final success over 50
episodes, for each seed and as the median over seeds; and a plot of the curves.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from cathsim_dmc.learning.rl.checkpoints import checkpoint_step

DEMOS = ["demos=expert"]
# demos=expert is the training default: the variants without demonstrations must say so.
NO_DEMOS = ["demos=none"]
# name -> (Hydra overrides, step budget). Each variant produces a results table of docs/training.md.
VARIANTS = {
    # The default recipe (conf/train.yaml's defaults, spelled out) at its default budget:
    # the current results table.
    "demos_internal": (["obs=internal", "algo=sac_tuned", "reward=progress", *DEMOS], 8_000),
    # The same recipe on the image observations (the ENN).
    "demos_enn": (
        [
            "obs=enn",
            "algo=sac_tuned",
            "reward=progress",
            "algo.batch_size=64",
            "algo.share_features_extractor=true",
            *DEMOS,
        ],
        50_000,
    ),
    # SAC without demonstrations, which needs about 100k steps to learn the task.
    "tuned_internal": (["obs=internal", "algo=sac_tuned", "reward=progress", *NO_DEMOS], 100_000),
}
TASKS = ("bca-type1", "lcca-type1", "bca-type2")
SUCCESS_AIM = 0.9
FINAL_EPISODES = 50


def run_dir(root: Path, variant: str, task: str, seed: int) -> Path:
    return root / variant / task / f"seed{seed}"


def new_run_overrides(
    variant: str, task: str, seed: int, eval_every: int, budget: int, save_replay_buffer: bool = False
) -> list:
    """The cathsim-train overrides of a fresh run of `variant` on `task` ("bca-type1")."""
    overrides, _ = VARIANTS[variant]
    target, aorta = task.split("-", 1)
    common = [
        f"trainer.total_timesteps={budget}",
        f"trainer.eval_every={eval_every}",
        "trainer.eval_episodes=10",
        f"trainer.final_eval_episodes={FINAL_EPISODES}",
        "trainer.checkpoint_every=5000",
        "trainer.progress_bar=false",
        "trainer.video=false",
    ]
    if save_replay_buffer:
        # With each checkpoint, so a run cut short resumes with the transitions it had.
        common.append("trainer.save_replay_buffer=true")
    return [f"task={target}", f"aorta={aorta}", f"seed={seed}", *overrides, *common]


def train(
    root: Path, variant: str, task: str, seed: int, eval_every: int, steps: int | None, save_replay_buffer: bool = False
) -> None:
    folder = run_dir(root, variant, task, seed)
    budget = steps or VARIANTS[variant][1]
    last = folder / "checkpoints" / "last.zip"
    # A finished run is continued when asked for more steps than it took.
    if (folder / "eval" / "metrics.json").is_file() and not (last.is_file() and checkpoint_step(last) < budget):
        print(f"done already: {folder}")
        return
    if last.is_file():
        args = [f"resume={folder}", f"trainer.total_timesteps={budget}", f"hydra.run.dir={folder}"]
    else:
        args = [
            *new_run_overrides(variant, task, seed, eval_every, budget, save_replay_buffer),
            f"hydra.run.dir={folder}",
        ]
    print(f"training {variant} {task} seed {seed}: {' '.join(args)}", flush=True)
    t0 = time.time()
    subprocess.run([sys.executable, "-m", "cathsim_dmc.app.cli.train", *args], check=True)
    print(f"finished in {time.time() - t0:.0f} s", flush=True)


def evaluations(folder: Path) -> list:
    path = folder / "evaluations.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.is_file() else []


def summarise(folder: Path) -> dict:
    evals = evaluations(folder)
    first = next((e for e in evals if e["success_rate"] >= SUCCESS_AIM), None)
    final_file = folder / "eval" / "metrics.json"
    final = None
    if final_file.is_file():
        summary = json.loads(final_file.read_text())["summary"]
        final = summary["success_pct"]["mean"] / 100
    return {
        "steps_to_aim": first["step"] if first else None,
        "wall_s_to_aim": first["wall_s"] if first else None,
        "final_success": final,
        "evaluations": evals,
        "last_step": evals[-1]["step"] if evals else 0,
    }


def _median(values):
    values = sorted(v for v in values if v is not None)
    if not values:
        return None
    middle = len(values) // 2
    return values[middle] if len(values) % 2 else (values[middle - 1] + values[middle]) / 2


def report(root: Path, out: Path, plot: Path | None) -> None:
    rows = []
    curves = {}
    for variant in VARIANTS:
        for task in TASKS:
            seeds = sorted((root / variant / task).glob("seed*"))
            if not seeds:
                continue
            runs = {int(s.name[4:]): summarise(s) for s in seeds}
            curves[(variant, task)] = {seed: r["evaluations"] for seed, r in runs.items()}
            fmt_steps = lambda r: f"{r['steps_to_aim']:,}" if r["steps_to_aim"] else f"not by {r['last_step']:,}"  # noqa: E731
            fmt_wall = lambda r: f"{r['wall_s_to_aim'] / 60:.0f} min" if r["wall_s_to_aim"] else "-"  # noqa: E731
            fmt_final = lambda r: (
                f"{100 * r['final_success']:.0f}%"
                if r["final_success"] is not None  # noqa: E731
                else f"no report (stopped at {r['last_step']:,})"
            )
            per_seed = "; ".join(
                f"seed {s}: {fmt_steps(r)}, {fmt_wall(r)}, final {fmt_final(r)}" for s, r in sorted(runs.items())
            )
            finals = [r["final_success"] for r in runs.values()]
            median_final = _median(finals)
            rows.append(
                f"| {variant} | {task} | {len(runs)} | "
                f"{_fmt_int(_median([r['steps_to_aim'] or float('inf') for r in runs.values()]))} | "
                f"{'-' if median_final is None else f'{100 * median_final:.0f}%'} | {per_seed} |"
            )
    lines = [
        "| variant | task | seeds | median steps to 90% | median final success (50 episodes) "
        "| per seed: steps to 90%, wall time to 90%, final |",
        "|---|---|---|---|---|---|",
        *rows,
    ]
    text = "\n".join(lines) + "\n"
    out.write_text(text) if out else None
    print(text)
    if plot and curves:
        _plot(curves, plot)


def _fmt_int(value):
    """A step count; a seed that never reached the aim counts as infinitely many steps."""
    if value is None or value == float("inf"):
        return "not reached"
    return f"{value:,.0f}"


def _plot(curves: dict, path: Path) -> None:
    """Success against steps per task, each variant's median over seeds with the seeds' spread."""
    from cathsim_dmc.evaluation.plots import learning_curves_plot

    panels: dict = {}
    for (variant, task), seeds in curves.items():
        panels.setdefault(task, {})[variant] = list(seeds.values())
    learning_curves_plot(
        dict(sorted(panels.items())), path, aim=SUCCESS_AIM, ylabel="deterministic success (10 episodes)"
    )
    print(f"wrote {path}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run")
    run.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    run.add_argument("--tasks", nargs="+", default=list(TASKS), choices=list(TASKS))
    run.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    run.add_argument("--eval-every", type=int, default=1000, help="steps between evaluations (the trainer's default)")
    run.add_argument("--steps", type=int, default=None, help="override every variant's step budget")
    run.add_argument("--root", type=Path, default=Path("outputs/learning"))
    run.add_argument(
        "--save-replay-buffer",
        action="store_true",
        help="checkpoint the replay buffer too, so an interrupted run resumes faithfully",
    )
    rep = sub.add_parser("report")
    rep.add_argument("--root", type=Path, default=Path("outputs/learning"))
    rep.add_argument("--out", type=Path, default=None)
    rep.add_argument("--plot", type=Path, default=None)
    args = parser.parse_args(argv)
    if args.command == "run":
        for variant in args.variants:
            for task in args.tasks:
                for seed in args.seeds:
                    train(args.root, variant, task, seed, args.eval_every, args.steps, args.save_replay_buffer)
    else:
        report(args.root, args.out, args.plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
