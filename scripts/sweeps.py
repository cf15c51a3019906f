"""Hydra multiruns for scripts/paper_tables.py and scripts/generalisation.py.

A script describes each job as one tool's Hydra overrides. The jobs of a tool whose
overrides differ only in a few keys (task, obs, seed, policy, ...) become one `-m` sweep
over those keys, and a Hydra launcher runs its jobs:

    joblib          this machine, hydra.launcher.n_jobs jobs at once (hydra-joblib-launcher)
    submitit_slurm  one SLURM job per run (hydra-submitit-launcher: pip install -e ".[cluster]")
    submitit_local  submitit's executor on this machine, each run in its own process
    slurm, local    the same two, sized in conf/hydra/launcher/ (slurm: one 600k-step ENN run on a GPU)

Any `hydra.launcher.<key>=<value>` passes on to the launcher (partition, timeout_min, ...).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LAUNCHERS = ("joblib", "submitit_slurm", "submitit_local", "slurm", "local")


class UsageError(Exception):
    """Bad input: the scripts print it as one line and exit with status 2."""


def add_launcher_options(parser) -> None:
    parser.add_argument(
        "--launcher", default="joblib", help=f"Hydra launcher: {', '.join(LAUNCHERS)} (default joblib, this machine)"
    )
    parser.add_argument("--jobs", type=int, default=None, help="runs at once with --launcher joblib (default 1)")


def launcher_overrides(launcher: str, jobs: int | None, extra=()) -> list:
    """The overrides that choose and size the launcher; `extra`: hydra.launcher.<key>=<value>."""
    if launcher not in LAUNCHERS:
        raise UsageError(f"--launcher {launcher}: choose one of {', '.join(LAUNCHERS)}")
    if jobs is not None and jobs < 1:
        raise UsageError(f"--jobs {jobs}: give 1 or more")
    if jobs is not None and launcher != "joblib":
        raise UsageError(
            f"--jobs {jobs}: only with --launcher joblib; {launcher} runs every job of a sweep at once "
            "(hydra.launcher.array_parallelism=<n> limits it)"
        )
    for option in extra:
        if not option.startswith("hydra.launcher.") or "=" not in option:
            raise UsageError(f"{option}: give launcher options as hydra.launcher.<key>=<value>")
    sized = [f"hydra.launcher.n_jobs={jobs or 1}"] if launcher == "joblib" else []
    return [f"hydra/launcher={launcher}", *sized, *extra]


def blocks(points: list) -> list:
    """Jobs as few sweeps as merging finds: each point (key -> value, the same keys in every
    point) starts as a sweep of one (key -> [value]), and two sweeps that differ in the
    values of one key only become one. Every point is in exactly one sweep."""
    merged = [{key: [value] for key, value in point.items()} for point in points]
    while True:
        pair = next(
            (
                (i, j, differ[0])
                for i, a in enumerate(merged)
                for j in range(i + 1, len(merged))
                if len(differ := [k for k in a if set(a[k]) != set(merged[j][k])]) == 1
            ),
            None,
        )
        if pair is None:
            return merged
        i, j, key = pair
        merged[i][key] += merged.pop(j)[key]


def tool(name: str) -> str:
    """The cathsim-<name> command of this Python's environment."""
    return str(Path(sys.executable).with_name(f"cathsim-{name}"))


def sweep_command(name: str, fixed: list, sweep: dict, sweep_dir: Path, subdir: str, launcher: list) -> list:
    """`cathsim-<name> -m`: the fixed overrides, a sweep over each key of `sweep` (key -> values),
    every job in sweep_dir/subdir (subdir: an absolute path with interpolations such as
    ${task.target} puts each job in a folder of its own choosing)."""
    swept = [f"{key}={','.join(str(v) for v in values)}" for key, values in sweep.items()]
    return [
        tool(name),
        "-m",
        *launcher,
        *fixed,
        *swept,
        f"hydra.sweep.dir={sweep_dir}",
        f"hydra.sweep.subdir={subdir}",
        # unused by a multirun; named so that `resume=` (cathsim-train) does not set it to the sweep's values
        f"hydra.run.dir={sweep_dir}",
    ]


def launch(command: list) -> int:
    """Run one multirun, its output on this terminal; its exit status."""
    print(" ".join([Path(command[0]).name, *command[1:]]), flush=True)
    return subprocess.run(command).returncode


def commit() -> str:
    out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT)
    return out.stdout.strip() or "unknown"


def job_seconds(folder: Path, final: Path) -> float | None:
    """Wall seconds of the job that wrote `final` in its run folder: from the job's start (Hydra
    writes .hydra/overrides.yaml as a job starts) to `final`."""
    start = Path(folder) / ".hydra" / "overrides.yaml"
    if not (start.is_file() and final.is_file()):
        return None
    return max(0.0, final.stat().st_mtime - start.stat().st_mtime)


def finished_report(path: Path) -> bool:
    """Whether `path` is a final report (metrics.json) of a whole run: one that a Ctrl-C cut
    short is labelled partial."""
    return Path(path).is_file() and not json.loads(Path(path).read_text()).get("partial")


def job_overrides(folder: Path) -> dict:
    """key -> value of the overrides a job of a multirun ran with (.hydra/overrides.yaml)."""
    import yaml

    path = Path(folder) / ".hydra" / "overrides.yaml"
    lines = yaml.safe_load(path.read_text()) if path.is_file() else []
    return dict(line.split("=", 1) for line in lines or [] if "=" in line)
