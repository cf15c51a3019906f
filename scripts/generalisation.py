"""Generalisation benchmark: train on random arches, score on the shipped aortas and on
held-out random ones, beside a policy trained on one shipped aorta.

    python scripts/generalisation.py run --task bca --seed 0 --steps 6000 --root /work/generalisation
    python scripts/generalisation.py run --task bca --seed 0 --baseline /work/learning/demos_internal/bca-type1/seed0
    python scripts/generalisation.py report --root /work/generalisation --out docs/generalisation_table.md

`run` trains `cathsim-train task=<task> aorta=random` (the default recipe: internal
observations, demonstrations from the scripted expert on the training pool) and, unless
`--baseline` names an existing run, the same recipe on `--train-aorta` (type1). Each
run's best.zip is then scored with `cathsim-eval` on every shipped aorta without the
oblique variants and on a pool of random arches the training never saw
(`aorta.params.pool_seed=--heldout-seed`, visited in turn), `--episodes` episodes each on
seeds 10,000+. Every step that has its metrics.json already is skipped, so a run cut
short resumes where it stopped. `report` reads the scores into one table.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

SHIPPED = ("type1", "type2", "type3", "aneurysm", "low_tortuosity", "bovine")
HELDOUT = "random (held out)"
EVAL_SEED = 10_000


def _cli(tool: str, args: list) -> None:
    print(f"{tool} {' '.join(args)}", flush=True)
    subprocess.run([sys.executable, "-m", f"cathsim_dmc.cli.{tool}", *args], check=True)


def train(folder: Path, task: str, aorta: str, seed: int, steps: int) -> None:
    if (folder / "eval" / "metrics.json").is_file():
        return
    args = [f"task={task}", f"aorta={aorta}", f"seed={seed}", f"trainer.total_timesteps={steps}",
            "trainer.eval_every=1000", "trainer.eval_episodes=10", "trainer.final_eval_episodes=20",
            "trainer.progress_bar=false", "trainer.video=false", f"hydra.run.dir={folder}"]
    if (folder / "checkpoints" / "last.zip").is_file():
        args = [f"resume={folder}", f"trainer.total_timesteps={steps}", f"hydra.run.dir={folder}"]
    _cli("train", args)


def evaluate(run: Path, out: Path, task: str, episodes: int, heldout_seed: int) -> None:
    policy = run / "checkpoints" / "best.zip"
    if not policy.is_file():
        raise SystemExit(f"no best.zip in {run}: train it with periodic evaluations (trainer.eval_every > 0)")
    common = [f"policy={policy}", f"task={task}", f"episodes={episodes}", f"seed={EVAL_SEED}", "video=false"]
    for aorta in SHIPPED:
        folder = out / aorta
        if not (folder / "metrics.json").is_file():
            _cli("eval", [*common, f"aorta={aorta}", f"hydra.run.dir={folder}"])
    folder = out / "heldout"
    if not (folder / "metrics.json").is_file():
        _cli("eval", [*common, "aorta=random", f"aorta.params.pool_seed={heldout_seed}",
                      f"aorta.params.pool_size={episodes}", "aorta.params.order=cycle", f"hydra.run.dir={folder}"])


def _score(folder: Path) -> str:
    path = folder / "metrics.json"
    if not path.is_file():
        return "-"
    summary = json.loads(path.read_text())["summary"]
    return f"{summary['success_pct']['mean']:.0f}% ({summary['spl_pct']['mean']:.0f}%)"


def report(root: Path, out: Path | None) -> None:
    columns = [*SHIPPED, HELDOUT]
    lines = ["| task | trained on | seed | " + " | ".join(columns) + " |", "|---" * (len(columns) + 3) + "|"]
    for scores in sorted(root.glob("*/*/seed*/scores")):
        run = scores.parent
        task, trained_on = run.parent.parent.name, run.parent.name
        cells = [_score(scores / a) for a in SHIPPED] + [_score(scores / "heldout")]
        lines.append(f"| {task} | {trained_on} | {run.name[4:]} | " + " | ".join(cells) + " |")
    text = "\n".join(lines) + "\n"
    if out:
        out.write_text(text)
    print(text)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run")
    run.add_argument("--task", choices=("bca", "lcca"), default="bca")
    run.add_argument("--seed", type=int, default=0)
    run.add_argument("--steps", type=int, default=6000, help="training steps of each run")
    run.add_argument("--train-aorta", default="type1", help="the single aorta of the comparison run")
    run.add_argument("--baseline", type=Path, default=None,
                     help="an existing cathsim-train run on --train-aorta to score instead of training one")
    run.add_argument("--episodes", type=int, default=20, help="episodes per scored aorta")
    run.add_argument("--heldout-seed", type=int, default=1000, help="pool_seed of the held-out random arches")
    run.add_argument("--root", type=Path, default=Path("outputs/generalisation"))
    rep = sub.add_parser("report")
    rep.add_argument("--root", type=Path, default=Path("outputs/generalisation"))
    rep.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    if args.command == "report":
        report(args.root, args.out)
        return 0
    runs = {"random": args.root / args.task / "random" / f"seed{args.seed}"}
    runs[args.train_aorta] = args.root / args.task / args.train_aorta / f"seed{args.seed}"
    for aorta, folder in runs.items():
        if aorta == args.train_aorta and args.baseline:
            source = args.baseline  # evaluate() refuses a run without best.zip
        else:
            train(folder, args.task, aorta, args.seed, args.steps)
            source = folder
        evaluate(source, folder / "scores", args.task, args.episodes, args.heldout_seed)
    report(args.root, None)
    return 0


if __name__ == "__main__":
    sys.exit(main())
