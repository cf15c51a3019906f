"""The CathSim paper's experiments, re-run: its tables and learning-curve figure.

    python scripts/paper_tables.py plan                  # every cell: state and cost; the multiruns `run` launches
    python scripts/paper_tables.py run --jobs 2          # the unfinished cells, as Hydra multiruns on this machine
    python scripts/paper_tables.py run --only main/enn   # cells whose name starts with this
    python scripts/paper_tables.py run --launcher submitit_slurm hydra.launcher.partition=<partition>   # on SLURM
    python scripts/paper_tables.py report --out docs/paper.md   # from ROOT and the record
    python scripts/paper_tables.py reselect              # best.zip chosen again where a tie was never broken

A cell is one tool run (cathsim-train, -collect, -bc or -force) in ROOT/<cell name>. `run`
hands the cells to Hydra: the cells of one tool whose overrides differ only in the task,
the observation preset or the seed are one `-m` sweep, and a Hydra launcher runs its jobs
(scripts/sweeps.py): `--launcher joblib` (the default) `--jobs` at a time on this machine,
`--launcher submitit_slurm` one SLURM job each. Sweeps run one after the other, in the
plan's order, each as soon as the cells it needs have finished; one `run` at a time per ROOT.

A cell is finished when the tool wrote its final file (a training's or a student's
eval/metrics.json, the force report, a dataset's manifest with every episode): `run` then
writes ROOT/<cell>/cell.json (the commit, the command, the job's wall time) and skips the
cell. The record (--record; for the full budget experiments/paper_results.json, in the
repository, so the results outlive the machine that ran them) keeps each finished cell's
numbers: its final report's metrics, its evaluation curve and its cost. Its files do not
outlive the machine: when a cell reads a finished cell's files (a dataset, the ENN agent's
checkpoints) and they are not in ROOT, that cell is run again first, and its record entry is
replaced by the new measurement. `report` reads a cell from ROOT when it is there and from
the record otherwise; `--record new.json` starts the experiments afresh. A training cell cut
short resumes from its last checkpoint (`cathsim-train resume=`); a collection continues its
dataset; a cloning or force cell starts again.

The cells:
  main/<obs>/<target>/seed<s>    the main table: the project's recipe on type I, 5 modalities x
                                 2 targets x 3 seeds, each best.zip scored on 50 episodes
                                 (seeds 10,000+) that did not choose it (seeds 20,000+)
  imitation/data/...             expert and ENN-agent datasets (cathsim-collect)
  imitation/bc/...               single-frame image students (cathsim-bc)
  force                          force prediction at 1K, 10K and 100K training images
  protocol/<obs>/<target>/seed0  the paper's protocol: the paper's SAC, Euclidean reward, no
                                 demonstrations, 100k steps

`report` writes the tables and the figure. With --out pointing at an existing markdown file,
it replaces only the text between `<!-- paper_tables:NAME -->` and `<!-- /paper_tables:NAME -->`
(NAME: main, protocol, imitation, force, curves), so the prose around the tables stays.
--budget tiny runs every cell on a few steps and episodes (tests); a root keeps the budget
it was started with.
"""

from __future__ import annotations

import argparse
import datetime
import json
import re
import shutil
import statistics
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a checkout without installing
sys.path.insert(0, str(Path(__file__).resolve().parent))

import sweeps  # noqa: E402
from sweeps import UsageError  # noqa: E402

TARGETS = ("bca", "lcca")
SEEDS = (0, 1, 2)
# The main table's rows: obs preset -> the paper's name.
MODALITIES = {
    "pixels": "Image",
    "pixels_mask": "Image+Mask",
    "internal": "Internal",
    "internal_pixels": "Internal+Image",
    "enn": "ENN",
}
# The project's recipe per modality: environment steps, and evaluations every 1,000 steps from
# the pre-trained actor on (eval_at_start). With the joints alone the online phase needs its
# 8k steps (docs/training.md); with an image the pre-trained actor already navigates (each of
# the ENN's six runs scored 10/10 before its first online step).
MAIN_STEPS = {"internal": 8000, "pixels": 3000, "pixels_mask": 3000, "internal_pixels": 3000, "enn": 3000}
FINAL_EPISODES = 50
# The paper's protocol: its SAC (on an image, the CPU variant: one shared encoder, batch 64),
# its Euclidean reward, no demonstrations.
PROTOCOL = {"internal": ["algo=sac"], "pixels": ["algo=sac_cpu"]}
PROTOCOL_STEPS = 100_000
# Its estimated wall minutes beside one other job: an update of the paper's SAC took about
# 48 ms with the joints and 140 ms of CPU with the image (2026-11-28, 1 torch thread).
PROTOCOL_MINUTES = {"internal": 100, "pixels": 270}
EXPERT_EPISODES = 300  # the students' datasets (per target)
MORE_EXPERT_EPISODES = 700  # more expert episodes: 1,000 per target for the 100K force subset
BC_EPOCHS = 20
BC_MINUTES = 25  # a 300-episode student: 9-21 min measured, beside one to three other jobs
# Starts drawn from pi to pi + 0.3 rad rather than pi +- 0.3 (task.start_rotation_*).
ONE_SIDED_START = ("task.start_rotation_rad=3.2916", "task.start_rotation_jitter_rad=0.15")

# The paper's numbers (Type-I phantom): success % / SPL %.
PAPER_MAIN = {
    ("pixels", "bca"): (65, 74),
    ("pixels", "lcca"): (33, 69),
    ("pixels_mask", "bca"): (100, 86),
    ("pixels_mask", "lcca"): (100, 96),
    ("internal", "bca"): (97, 80),
    ("internal", "lcca"): (83, 79),
    ("internal_pixels", "bca"): (33, 76),
    ("internal_pixels", "lcca"): (100, 100),
    ("enn", "bca"): (100, 99),
    ("enn", "lcca"): (100, 100),
}
# The paper's ENN: force N, path cm, episode length, safety %.
PAPER_ENN = {"bca": (2.33, 15.78, 36.88, 45), "lcca": (2.26, 14.85, 33.77, 45)}
PAPER_BC = {"bca": (100, 98), "lcca": (100, 100)}  # "Image w. ENN": success / SPL
PAPER_FORCE = {1000: 0.5047, 10000: 0.1828, 100000: 0.0898}
PAPER_FORCE_BASELINE = 5.0021

TINY = {  # --budget tiny: every cell on a few steps and short episodes
    "train": [
        "task.max_steps=30",
        "trainer.total_timesteps=20",
        "trainer.eval_every=10",
        "trainer.eval_episodes=1",
        "trainer.final_eval_episodes=1",
        "trainer.checkpoint_every=10",
    ],
    "train_demos": [
        "demos.episodes=1",
        "demos.pretrain_actor_steps=2",
        "demos.critic_warmup_steps=2",
        "demos.takeover_rounds=0",
    ],
    "collect": ["task.max_steps=30", "episodes=2"],
    "bc": ["task.max_steps=30", "bc.epochs=1", "eval_episodes=1"],
    "force": ["force.sizes=[20,40]", "force.epochs=1", "force.min_updates=2"],
}
CELL_FILE = "cell.json"
ATTEMPTS_FILE = "attempts.jsonl"
FULL_RECORD = ROOT / "experiments" / "paper_results.json"
# The keys a cell's name is made of, and what names their value in a job's config: a sweep
# over them puts each job in its cell's folder (hydra.sweep.subdir).
SWEPT = {"obs": "${obs.name}", "task": "${task.target}", "seed": "${seed}"}


@dataclass(eq=False)  # a cell is itself: `in` compares identity
class Cell:
    pattern: str  # its folder under ROOT, with {obs}, {task}, {seed} for the values in `sweep`
    tool: str  # train | collect | bc | force
    # The tool's other Hydra overrides, given ROOT; {task} (and the others) stand for the
    # cell's values, so that one sweep covers the cells that differ only in them.
    args: Callable[[Path], list]
    minutes: float  # estimated wall time on the 2-core machine beside one other job
    sweep: dict = field(default_factory=dict)  # obs, task, seed -> this cell's value
    needs: tuple = ()  # names of cells to finish first
    demos: bool = True  # a training cell that records demonstrations
    # The needs whose files it reads, given the plan (default: all of them). A need that
    # finished on another machine (only the record holds it) is run again here first.
    reads: Callable[["Plan"], tuple] | None = None

    @property
    def name(self) -> str:
        return self.pattern.format(**self.sweep)

    def inputs(self, plan: "Plan") -> tuple:
        return self.needs if self.reads is None else self.reads(plan)


@dataclass
class Plan:
    root: Path
    budget: str = "full"
    cells: list = field(default_factory=list)
    record: Path | None = None  # the finished cells' numbers (default: ROOT/results.json)

    def __post_init__(self):
        self.record = self.record or self.root / "results.json"

    def folder(self, cell: Cell) -> Path:
        return self.root / cell.name

    def recorded(self) -> dict:
        if not self.record.is_file():
            return {}
        stamp = self.record.stat()
        key = (stamp.st_mtime_ns, stamp.st_size)
        if getattr(self, "_cache", (None,))[0] != key:
            self._cache = (key, json.loads(self.record.read_text()))
        return self._cache[1]

    def done(self, cell: Cell) -> bool:
        return self.here(cell.name) or cell.name in self.recorded()

    def here(self, name: str) -> bool:
        """Finished on this machine: its files (checkpoints, datasets) are in ROOT."""
        return (self.root / name / CELL_FILE).is_file()

    def result(self, name: str) -> dict | None:
        """A finished cell's numbers: from ROOT when it is there, else from the record."""
        folder = self.root / name
        if (folder / CELL_FILE).is_file():
            return _result_from(folder)
        return self.recorded().get(name)

    def by_name(self, name: str) -> Cell:
        return next(c for c in self.cells if c.name == name)


def _fixed(*args):
    return lambda root: list(args)


def _train_args(extra=()):
    return _fixed("aorta=type1", *extra, "trainer.progress_bar=false", "trainer.video=false")


# Wall minutes of a main cell, two at a time: the medians measured 2026-11-27 to 2026-11-29
# (the cost table of `plan`). The LCCA records 300 demonstrations and three takeover rounds (the
# ENN takes the rounds on both targets); the ENN's two images cost most.
MAIN_MINUTES = {
    "internal": {"bca": 17, "lcca": 21},
    "enn": {"bca": 60, "lcca": 76},
    "pixels": {"bca": 22, "lcca": 27},
    "pixels_mask": {"bca": 36, "lcca": 48},
    "internal_pixels": {"bca": 18, "lcca": 26},
}


def main_cell(obs: str, target: str, seed: int) -> Cell:
    steps = MAIN_STEPS[obs]
    return Cell(
        "main/{obs}/{task}/seed{seed}",
        "train",
        _train_args(
            [
                f"trainer.total_timesteps={steps}",
                "trainer.eval_every=1000",
                "trainer.eval_episodes=10",
                "trainer.eval_at_start=true",
                f"trainer.final_eval_episodes={FINAL_EPISODES}",
            ]
        ),
        minutes=MAIN_MINUTES[obs][target],
        sweep={"obs": obs, "task": target, "seed": seed},
    )


def protocol_cell(obs: str, target: str) -> Cell:
    extra = [
        "seed=0",
        *PROTOCOL[obs],
        "reward=euclidean",
        "demos=none",
        f"trainer.total_timesteps={PROTOCOL_STEPS}",
        "trainer.eval_every=5000",
        "trainer.eval_episodes=10",
        f"trainer.final_eval_episodes={FINAL_EPISODES}",
        "trainer.checkpoint_every=5000",
        "trainer.save_replay_buffer=true",
    ]
    return Cell(
        "protocol/{obs}/{task}/seed0",
        "train",
        _train_args(extra),
        minutes=PROTOCOL_MINUTES[obs],
        sweep={"obs": obs, "task": target},
        demos=False,
    )


def best_enn_run(plan: Plan, target: str) -> Path:
    """The ENN seed whose final report scored best (success, then SPL; the lowest seed on a
    tie), among the seeds finished on this machine when there are any: on a new machine the
    record's best is trained again, and its checkpoints are used whatever it scores then."""
    names = {seed: f"main/enn/{target}/seed{seed}" for seed in SEEDS}
    scored = []
    for seed in [s for s in SEEDS if plan.here(names[s])] or SEEDS:
        summary = plan.result(names[seed])["summary"]
        scored.append((-summary["success_pct"]["mean"], -summary["spl_pct"]["mean"], seed))
    return plan.root / f"main/enn/{target}/seed{min(scored)[2]}"


def build_plan(root: Path, budget: str = "full", record: Path | None = None) -> Plan:
    plan = Plan(root, budget, record=record)
    add = plan.cells.append
    data = lambda name: str(root / "imitation" / "data" / name)  # noqa: E731
    for obs in ("internal", "enn"):
        for seed in SEEDS:
            for target in TARGETS:
                add(main_cell(obs, target, seed))

    def dataset(kind, target, policy, *extra):  # 300 episodes of a scripted policy
        return Cell(
            f"imitation/data/{kind}_{{task}}",
            "collect",
            _fixed(
                "aorta=type1",
                f"policy={policy}",
                f"episodes={EXPERT_EPISODES}",
                "seed=0",
                *extra,
                "progress_bar=false",
            ),
            minutes=10,
            sweep={"task": target},
        )

    def student(kind, target, *extra):  # the single-frame image student of imitation/data/<kind>_<target>
        return Cell(
            f"imitation/bc/{kind}_{{task}}",
            "bc",
            _fixed(
                "aorta=type1",
                f"data={data(kind + '_{task}')}",
                *extra,
                f"bc.epochs={BC_EPOCHS}",
                f"eval_episodes={FINAL_EPISODES}",
                "seed=0",
                "video=false",
                "progress_bar=false",
            ),
            minutes=BC_MINUTES,
            sweep={"task": target},
            needs=(f"imitation/data/{kind}_{target}",),
        )

    for target in TARGETS:
        add(dataset("expert", target, "expert"))
        add(student("expert", target))
    # Why the single frame falls short (docs/paper.md#imitation). Students with every start on
    # one side of the view's mirror plane (rotation pi to pi + 0.3 rad, the default's spread),
    # where mirrored starts give identical images; then students of the steady expert, which
    # makes no turn on straight stretches, from the default starts.
    for target in TARGETS:
        add(dataset("expert_onesided", target, "expert", *ONE_SIDED_START))
        add(student("expert_onesided", target, *ONE_SIDED_START))
    for target in TARGETS:
        add(dataset("steady", target, "expert_steady"))
        add(student("steady", target))
    # The ENN agent's dataset as soon as its seeds finish: it needs their checkpoints, which
    # only the machine that trained them has.
    for target in TARGETS:
        enn_seeds = tuple(f"main/enn/{target}/seed{s}" for s in SEEDS)
        add(
            Cell(
                "imitation/data/enn_{task}",
                "collect",
                lambda root, t=target: [
                    "aorta=type1",
                    f"policy={best_enn_run(plan, t)}",
                    f"episodes={EXPERT_EPISODES}",
                    "seed=0",
                    "progress_bar=false",
                ],
                minutes=25,
                sweep={"task": target},
                needs=enn_seeds,
                reads=lambda plan, t=target: (str(best_enn_run(plan, t).relative_to(plan.root)),),
            )
        )
        add(student("enn", target))
    for obs in ("pixels_mask", "pixels", "internal_pixels"):
        for seed in SEEDS:
            for target in TARGETS:
                add(main_cell(obs, target, seed))
    for target in TARGETS:
        add(
            Cell(
                "imitation/data/expert_more_{task}",
                "collect",
                _fixed(
                    "aorta=type1",
                    "policy=expert",
                    f"episodes={MORE_EXPERT_EPISODES}",
                    f"seed={EXPERT_EPISODES}",
                    "progress_bar=false",
                ),
                minutes=20,
                sweep={"task": target},
            )
        )
    every = [f"expert_{t}" for t in TARGETS] + [f"expert_more_{t}" for t in TARGETS]
    add(
        Cell(
            "force",
            "force",
            _fixed(f"data=[{','.join(data(d) for d in every)}]", "force.epochs=8", "progress_bar=false"),
            minutes=60,
            needs=tuple(f"imitation/data/{d}" for d in every),
        )
    )
    # More data for the single-frame LCCA student: all 1,000 expert episodes.
    add(
        Cell(
            "imitation/bc/expert1000_lcca",
            "bc",
            _fixed(
                "task=lcca",
                "aorta=type1",
                f"data=[{data('expert_lcca')},{data('expert_more_lcca')}]",
                "bc.epochs=10",
                f"eval_episodes={FINAL_EPISODES}",
                "seed=0",
                "video=false",
                "progress_bar=false",
            ),
            minutes=60,
            needs=("imitation/data/expert_lcca", "imitation/data/expert_more_lcca"),
        )
    )
    for target in TARGETS:
        for obs in PROTOCOL:
            add(protocol_cell(obs, target))
    return plan


# -- running -------------------------------------------------------------------------------
def _override(args: list, changes: list) -> list:
    """`args` with each key=value of `changes` replacing the same key's (Hydra refuses a key twice)."""
    keys = {c.split("=", 1)[0] for c in changes}
    return [a for a in args if a.split("=", 1)[0] not in keys] + list(changes)


def templates(plan: Plan, cell: Cell) -> list:
    """The cell's overrides besides its swept keys, {task} and the others not yet filled in."""
    args = cell.args(plan.root)
    if plan.budget == "tiny":
        args = _override(args, TINY[cell.tool] + (TINY["train_demos"] if cell.tool == "train" and cell.demos else []))
    return args


def _resumes(plan: Plan, cell: Cell) -> bool:
    return cell.tool == "train" and (plan.folder(cell) / "checkpoints" / "last.zip").is_file()


def command(plan: Plan, cell: Cell) -> list:
    """The command that runs `cell` alone, now: a training cell with a checkpoint resumes from it."""
    folder = plan.folder(cell)
    if _resumes(plan, cell):
        return [sweeps.tool("train"), f"resume={folder}", f"hydra.run.dir={folder}"]
    args = [a.format(**cell.sweep) for a in templates(plan, cell)]
    return [sweeps.tool(cell.tool), *args, *[f"{k}={v}" for k, v in cell.sweep.items()], f"hydra.run.dir={folder}"]


@dataclass
class Launch:
    """One multirun: `tool` with the `fixed` overrides, swept over `sweep` (key -> values), each
    job in the folder `subdir` names (absolute, with interpolations); the cells it runs."""

    tool: str
    fixed: list
    sweep: dict
    subdir: str
    cells: list

    def command(self, sweep_dir: Path, launcher: list) -> list:
        return sweeps.sweep_command(self.tool, self.fixed, self.sweep, sweep_dir, self.subdir, launcher)

    def minutes(self) -> float:
        return sum(c.minutes for c in self.cells)


def launches(plan: Plan, cells: list) -> list:
    """The multiruns that run `cells`, in the plan's order: the training cells with a
    checkpoint resume together (`cathsim-train -m resume=...`); the others are grouped by tool
    and overrides, and each group swept over the keys its names differ in."""
    order = {c.name: i for i, c in enumerate(plan.cells)}
    found = []
    resumed = [c for c in cells if _resumes(plan, c)]
    if resumed:
        folders = [str(plan.folder(c).resolve()) for c in resumed]
        found.append(Launch("train", [], {"resume": folders}, "${resume}", resumed))
    groups: dict = {}
    for cell in cells:
        if cell not in resumed:
            key = (cell.tool, cell.pattern, tuple(templates(plan, cell)), tuple(cell.sweep))
            groups.setdefault(key, []).append(cell)
    for (tool, pattern, args, keys), members in groups.items():
        filled = {k: SWEPT[k] for k in keys}
        by_values = {tuple(c.sweep.values()): c for c in members}
        for block in sweeps.blocks([c.sweep for c in members]):
            chosen = [c for values, c in by_values.items() if all(v in block[k] for k, v in zip(keys, values))]
            subdir = str(plan.root.resolve() / pattern.format(**filled))
            found.append(Launch(tool, [a.format(**filled) for a in args], block, subdir, chosen))
    return sorted(found, key=lambda job: min(order[c.name] for c in job.cells))


def final_file(plan: Plan, cell: Cell) -> Path | None:
    """The file a tool writes last, once the cell's run has finished: the final report of a
    training or a student (not one a Ctrl-C left partial), the force report, the manifest of a
    dataset with all its episodes."""
    folder = plan.folder(cell)
    if cell.tool in ("train", "bc"):
        path = folder / "eval" / "metrics.json"
        return path if sweeps.finished_report(path) else None
    if cell.tool == "force":
        path = folder / "force.json"
        return path if path.is_file() else None
    path = folder / "manifest.json"
    if not path.is_file():
        return None
    wanted = next(int(a.split("=", 1)[1]) for a in templates(plan, cell) if a.startswith("episodes="))
    return path if json.loads(path.read_text())["episodes"] >= wanted else None


def _attempts(folder: Path) -> list:
    path = folder / ATTEMPTS_FILE
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.is_file() else []


def record_finished(plan: Plan, cell: Cell) -> bool:
    """Whether the cell has finished on this machine; the first time its tool's final file is
    seen, cell.json (the commit and command of its last attempt, the job's wall time) and the
    record get it."""
    if plan.here(cell.name):
        return True
    final = final_file(plan, cell)
    if final is None:
        return False
    folder = plan.folder(cell)
    attempts = _attempts(folder)
    last = attempts[-1] if attempts else {"command": command(plan, cell), "commit": sweeps.commit()}
    seconds = sweeps.job_seconds(folder, final) or 0.0
    info = {
        "cell": cell.name,
        "tool": cell.tool,
        "command": " ".join([Path(last["command"][0]).name, *last["command"][1:]]),
        "commit": last["commit"],
        "budget": plan.budget,
        "seconds": round(seconds, 1),
        "attempts": max(1, len(attempts)),
        "finished": _time(final.stat().st_mtime),
    }
    (folder / CELL_FILE).write_text(json.dumps(info, indent=1))
    save_record(plan, cell.name)
    print(f"[{cell.name}] finished in {seconds / 60:.1f} min", flush=True)
    return True


def _time(stamp: float | None = None) -> str:
    moment = datetime.datetime.fromtimestamp(stamp) if stamp is not None else datetime.datetime.now()
    return moment.isoformat(timespec="seconds")


def prepare(plan: Plan, cell: Cell, commit: str, **attempt) -> None:
    """Before a cell's job: a cloning or force cell starts again (what a killed attempt left
    goes), and the attempt is appended to attempts.jsonl."""
    folder = plan.folder(cell)
    if cell.tool in ("bc", "force") and folder.is_dir():
        for item in folder.iterdir():
            shutil.rmtree(item) if item.is_dir() else item.unlink()
    folder.mkdir(parents=True, exist_ok=True)
    with (folder / ATTEMPTS_FILE).open("a") as f:
        f.write(json.dumps({"started": _time(), "command": command(plan, cell), "commit": commit, **attempt}) + "\n")


def _sweep_dir(plan: Plan, tool: str) -> Path:
    """Where a multirun keeps its own files (multirun.yaml): ROOT/multirun/<time>_<tool>."""
    return plan.root.resolve() / "multirun" / f"{datetime.datetime.now():%Y-%m-%d_%H-%M-%S-%f}_{tool}"


def ready(plan: Plan, chosen: list, failed: set = frozenset(), say=print) -> list:
    """The cells `run` can launch now: each unfinished cell of `chosen` whose needs are done
    and whose inputs are here, or else the inputs that finished on another machine (only the
    record holds them), to be run again here first."""
    found = []
    for cell in chosen:
        if plan.done(cell) or cell.name in failed:
            continue
        if not all(plan.done(plan.by_name(n)) for n in cell.needs):
            continue
        missing = [plan.by_name(n) for n in cell.inputs(plan) if not plan.here(n)]
        for pick in missing or [cell]:
            if pick.name not in failed and pick not in found:
                if pick is not cell:
                    say(f"[{pick.name}] run again on this machine: {cell.name} reads its files")
                found.append(pick)
    return found


def run(plan: Plan, only: list | None, launcher: list) -> int:
    """Run every unfinished cell (matching `only`) whose needs are met, one multirun at a
    time: the first in the plan's order of those that can start, until none can."""
    chosen = [c for c in plan.cells if not only or any(c.name.startswith(o) for o in only)]
    for cell in plan.cells:  # finished while no `run` was there to see it
        record_finished(plan, cell)
    failed: set = set()
    while cells := ready(plan, chosen, failed):
        job = launches(plan, cells)[0]
        commit = sweeps.commit()  # the code the tools start with (a checkout may move on meanwhile)
        for cell in job.cells:
            prepare(plan, cell, commit)
        sweeps.launch(job.command(_sweep_dir(plan, job.tool), launcher))
        for cell in job.cells:
            if not record_finished(plan, cell):
                failed.add(cell.name)
                print(f"[{cell.name}] not finished: see {plan.folder(cell)}", flush=True)
    for cell in chosen:
        if plan.done(cell) or cell.name in failed:
            continue
        needed = [n for n in cell.needs if not plan.done(plan.by_name(n))]
        needed += [f"{n} (on this machine)" for n in (() if needed else cell.inputs(plan)) if not plan.here(n)]
        print(f"[{cell.name}] waiting for {', '.join(needed)}")
    return 1 if failed else 0


def reselect(plan: Plan, only: list | None, launcher: list) -> int:
    """Choose best.zip again, and score it again, in each finished training cell whose tied
    periodic evaluations were never broken on more episodes (cells finished before
    trainer.tie_break_episodes existed). The training is not repeated: `cathsim-train
    resume=<cell>` of a finished run does only that. cell.json keeps the training's commit
    and cost, and gains `selected` (commit, wall seconds, date)."""
    from cathsim_dmc.learning.rl.callbacks import has_unbroken_tie

    cells = [
        c
        for c in plan.cells
        if c.tool == "train"
        and (not only or any(c.name.startswith(o) for o in only))
        and plan.here(c.name)
        and has_unbroken_tie(plan.folder(c))
    ]
    if not cells:
        print("no finished training cell has an unbroken tie")
        return 0
    commit = sweeps.commit()
    for cell in cells:
        prepare(plan, cell, commit, reselect=True)
    job = Launch("train", [], {"resume": [str(plan.folder(c).resolve()) for c in cells]}, "${resume}", cells)
    sweeps.launch(job.command(_sweep_dir(plan, "train"), launcher))
    failed = 0
    for cell in cells:
        folder = plan.folder(cell)
        report = folder / "eval" / "metrics.json"
        if has_unbroken_tie(folder) or not report.is_file():
            print(f"[{cell.name}] best.zip not chosen again: see {folder}", flush=True)
            failed += 1
            continue
        seconds = sweeps.job_seconds(folder, report) or 0.0
        info = json.loads((folder / CELL_FILE).read_text())
        info["selected"] = {"commit": commit, "seconds": round(seconds, 1), "finished": _time(report.stat().st_mtime)}
        (folder / CELL_FILE).write_text(json.dumps(info, indent=1))
        save_record(plan, cell.name)
        print(f"[{cell.name}] best.zip chosen again in {seconds / 60:.1f} min", flush=True)
    return 1 if failed else 0


def state(plan: Plan, cell: Cell) -> str:
    folder = plan.folder(cell)
    if plan.done(cell):
        return "done" if plan.here(cell.name) else "recorded"  # recorded: its files are on another machine
    if folder.is_dir() and any(folder.iterdir()):
        return "partial"  # killed, or running now: `run` resumes or restarts it
    if not all(plan.done(plan.by_name(n)) for n in cell.needs):
        return "waiting"
    return "to do"


def print_plan(plan: Plan, only: list | None, launcher: list) -> None:
    total = 0.0
    print(f"{'cell':40s} {'tool':8s} {'state':8s} estimated  measured")
    for cell in plan.cells:
        info = _cell_info(plan, cell.name)
        measured = f"{info['seconds'] / 60:.0f} min" if info else ""
        if not info:
            total += cell.minutes
        print(f"{cell.name:40s} {cell.tool:8s} {state(plan, cell):8s} {cell.minutes:5.0f} min  {measured}")
    print(f"left: about {total / 60:.1f} h of job time (two jobs share the 2 cores)\n")
    print(cost_table(plan), end="")
    chosen = [c for c in plan.cells if not only or any(c.name.startswith(o) for o in only)]
    jobs = launches(plan, ready(plan, chosen))
    if jobs:
        print("\n`run` launches these multiruns now, one after the other (then those they make ready):")
    for job in jobs:
        command = job.command(plan.root.resolve() / "multirun" / f"<time>_{job.tool}", launcher)
        print(f"\n{len(job.cells)} run(s), about {job.minutes():.0f} min of job time:")
        print(" ".join([Path(command[0]).name, *command[1:]]))


def open_plan(root: Path, budget: str | None, record: Path | None = None) -> Plan:
    """The plan of `root`; the first run records its budget, and a different one is refused.
    The record defaults to experiments/paper_results.json for the full budget, and to
    ROOT/results.json for another."""
    root = Path(root).resolve()  # every path a job is given is absolute: a cluster job's folder may differ
    started = root / "plan.json"
    if started.is_file():
        recorded = json.loads(started.read_text())["budget"]
        if budget and budget != recorded:
            raise UsageError(f"--budget {budget}: {root} was started with --budget {recorded} (choose another --root)")
        budget = recorded
    budget = budget or "full"
    return build_plan(root, budget, record or (FULL_RECORD if budget == "full" else None))


# -- the record ----------------------------------------------------------------------------
def _result_from(folder: Path) -> dict:
    """A finished cell's numbers, as the record keeps them: the cell's info, its final report's
    summary and per-episode metrics, its evaluation curve, and the force report."""
    from cathsim_dmc.evaluation.metrics import METRIC_COLUMNS
    from cathsim_dmc.learning.rl.checkpoints import read_evaluations

    result = {"info": json.loads((folder / CELL_FILE).read_text())}
    for path in (folder / "eval" / "metrics.json", folder / "metrics.json"):
        if path.is_file():
            report = json.loads(path.read_text())
            result["summary"] = report["summary"]
            result["per_episode"] = [{k: e[k] for k in METRIC_COLUMNS} for e in report["per_episode"]]
            break
    curve = [
        {k: e[k] for k in ("step", "success_rate", "mean_episode_length", "mean_return")}
        for e in read_evaluations(folder)
    ]
    if curve:
        result["evaluations"] = curve
    if (folder / "force.json").is_file():
        result["force"] = json.loads((folder / "force.json").read_text())
    return result


def save_record(plan: Plan, name: str) -> None:
    """Add a finished cell to the record (one JSON file, rewritten whole: a reader never sees
    half of it)."""
    plan.record.parent.mkdir(parents=True, exist_ok=True)
    recorded = dict(plan.recorded())
    recorded[name] = _result_from(plan.root / name)
    tmp = plan.record.with_suffix(".tmp")
    # one line per cell: a new cell is one new line in the repository's history
    lines = [f"{json.dumps(k)}: {json.dumps(v)}" for k, v in sorted(recorded.items())]
    tmp.write_text("{\n" + ",\n".join(lines) + "\n}\n")
    tmp.replace(plan.record)


# -- report --------------------------------------------------------------------------------
def _cell_info(plan: Plan, name: str) -> dict | None:
    result = plan.result(name)
    return result["info"] if result else None


def _finished(plan: Plan, name: str) -> dict | None:
    """The final report (summary and per-episode metrics) of a finished cell."""
    result = plan.result(name)
    return result if result and "summary" in result else None


def _pooled(reports: list) -> dict:
    """{metric: (mean, std)} over every episode of the reports."""
    from cathsim_dmc.evaluation.metrics import METRIC_COLUMNS

    episodes = [e for r in reports for e in r["per_episode"]]
    return {
        k: (statistics.fmean(e[k] for e in episodes), statistics.pstdev(e[k] for e in episodes)) for k in METRIC_COLUMNS
    }


def _metric_cells(pooled: dict) -> list:
    from cathsim_dmc.evaluation.metrics import METRIC_COLUMNS

    return [f"{fmt.format(pooled[k][0])} ± {fmt.format(pooled[k][1])}" for k, (_, fmt) in METRIC_COLUMNS.items()]


def _metric_header() -> list:
    from cathsim_dmc.evaluation.metrics import METRIC_COLUMNS

    return [h for h, _ in METRIC_COLUMNS.values()]


def _table(header: list, rows: list) -> str:
    return (
        "\n".join(
            ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
            + ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
        )
        + "\n"
    )


def _provenance(plan: Plan, names: list, only: str) -> str:
    infos = [i for i in (_cell_info(plan, n) for n in names) if i]
    if not infos:
        return ""
    commits = sorted({i["commit"] for i in infos})
    dates = sorted(i["finished"][:10] for i in infos)
    span = dates[0] if dates[0] == dates[-1] else f"{dates[0]} to {dates[-1]}"
    budget = "" if plan.budget == "full" else f", budget {plan.budget}"
    selected = [i["selected"] for i in infos if "selected" in i]
    again = ""
    if selected:
        at = sorted({s["commit"] for s in selected})
        again = f"; best.zip of {len(selected)} chosen again on more episodes at {', '.join(at)} (`reselect`)"
    return (
        f"\n{len(infos)} of {len(names)} cells finished, {span}, at commit{'s' if len(commits) > 1 else ''} "
        f"{', '.join(commits)}{budget}{again}; `python scripts/paper_tables.py run --only {only}`, then "
        f"`report`.\n"
    )


def main_table(plan: Plan) -> str:
    rows, names = [], []
    for target in TARGETS:
        for obs, label in MODALITIES.items():
            cells = [f"main/{obs}/{target}/seed{s}" for s in SEEDS]
            names += cells
            reports = [r for r in (_finished(plan, n) for n in cells) if r]
            paper = "{} / {}".format(*PAPER_MAIN[(obs, target)])
            if not reports:
                rows.append([label, target.upper(), 0, *["not run"] * 6, "-", paper])
                continue
            per_seed = ", ".join(f"{r['summary']['success_pct']['mean']:.0f}" for r in reports)
            rows.append([label, target.upper(), len(reports), *_metric_cells(_pooled(reports)), per_seed, paper])
    header = ["Modality", "Target", "Seeds", *_metric_header(), "Success per seed (%)", "Paper: Success / SPL (%)"]
    enn = "; ".join(f"{t.upper()} {f} N, {p} cm, {n} steps, safety {s}%" for t, (f, p, n, s) in PAPER_ENN.items())
    budgets = ", ".join(f"{obs} {steps:,}" for obs, steps in MAIN_STEPS.items())
    return (
        _table(header, rows) + f"\nThe paper's ENN row, force / path length / episode length / safety: {enn}.\n"
        f"Steps per run: {budgets}; each seed's best.zip scored on {FINAL_EPISODES} episodes (seeds 10,000+); "
        f"the metrics pool every episode of the seeds.\n" + _provenance(plan, names, "main")
    )


def _evaluations(plan: Plan, name: str) -> list:
    """A cell's evaluation curve: live from ROOT (a running cell's too), else from the record."""
    from cathsim_dmc.learning.rl.checkpoints import read_evaluations

    live = read_evaluations(plan.root / name)
    return live or (plan.recorded().get(name) or {}).get("evaluations", [])


def protocol_table(plan: Plan) -> str:
    rows, names = [], []
    for target in TARGETS:
        for obs in PROTOCOL:
            name = f"protocol/{obs}/{target}/seed0"
            names.append(name)
            evals = _evaluations(plan, name)
            curve = ", ".join(f"{e['success_rate'] * 100:.0f}" for e in evals) or "-"
            last = f"{evals[-1]['step']:,}" if evals else "0"
            report = _finished(plan, name)
            ours = [_finished(plan, f"main/{obs}/{target}/seed{s}") for s in SEEDS]
            ours = [r for r in ours if r]
            recipe = f"{statistics.median(r['summary']['success_pct']['mean'] for r in ours):.0f}" if ours else "-"
            if report:
                s = report["summary"]
                result = f"{s['success_pct']['mean']:.0f} / {s['spl_pct']['mean']:.0f}"
            else:
                result = "unfinished" if evals else "not run"
            rows.append(
                [
                    MODALITIES[obs],
                    target.upper(),
                    last,
                    curve,
                    result,
                    recipe,
                    "{} / {}".format(*PAPER_MAIN[(obs, target)]),
                ]
            )
    header = [
        "Modality",
        "Target",
        "Steps",
        "Success every 5k steps (%, 10 episodes)",
        f"best.zip: Success / SPL (%, {FINAL_EPISODES} episodes)",
        "The project's recipe: median success (%)",
        "Paper: Success / SPL (%)",
    ]
    return _table(header, rows) + _provenance(plan, names, "protocol")


def _imitation_row(target: str, label: str, report: dict | None, paper: tuple | None) -> list:
    paper_cell = "{} / {}".format(*paper) if paper else "-"
    if report is None:
        return [target.upper(), label, *["not run"] * 6, 0, paper_cell]
    return [target.upper(), label, *_metric_cells(_pooled([report])), len(report["per_episode"]), paper_cell]


def imitation_table(plan: Plan) -> str:
    rows, names = [], []
    for target in TARGETS:
        enn_done = all(plan.done(plan.by_name(f"main/enn/{target}/seed{s}")) for s in SEEDS)
        # (label, cell name or None, the paper's success / SPL or None)
        enn = best_enn_run(plan, target).relative_to(plan.root).as_posix() if enn_done else None
        sources = [
            (f"ENN ({enn.rsplit('/', 1)[1] if enn else 'the best seed'} of 3)", enn, PAPER_MAIN[("enn", target)]),
            (
                "Image w/o expert (the paper's protocol)",
                f"protocol/pixels/{target}/seed0",
                PAPER_MAIN[("pixels", target)],
            ),
            ("Image w. ENN agent", f"imitation/bc/enn_{target}", PAPER_BC[target]),
            ("Image w. scripted expert", f"imitation/bc/expert_{target}", None),
            (
                "Image w. scripted expert, starts on one side (π to π+0.3 rad)",
                f"imitation/bc/expert_onesided_{target}",
                None,
            ),
            ("Image w. steady expert (no turns on straight stretches)", f"imitation/bc/steady_{target}", None),
        ]
        if target == "lcca":
            sources.append(("Image w. scripted expert, 1,000 episodes", "imitation/bc/expert1000_lcca", None))
        for label, name, paper in sources:
            if name is not None:
                names.append(name)
            rows.append(_imitation_row(target, label, _finished(plan, name) if name else None, paper))
        human = plan.root / "human" / target / "metrics.json"
        rows.append(
            _imitation_row(
                target, "Human (cathsim-teleop)", json.loads(human.read_text()) if human.is_file() else None, None
            )
        )
    header = ["Target", "Method", *_metric_header(), "Episodes", "Paper: Success / SPL (%)"]
    note = ""
    if not any((plan.root / "human" / t / "metrics.json").is_file() for t in TARGETS):
        note = (
            "\nNo human data was recorded. To add the Human row, drive `cathsim-teleop task=bca aorta=type1` "
            "(it needs a display) and copy its run folder to ROOT/human/bca (and lcca), ROOT being the --root "
            "of `paper_tables.py` (default outputs/paper).\n"
        )
    return _table(header, rows) + note + _provenance(plan, names, "imitation protocol/pixels main/enn")


def force_table(plan: Plan) -> str:
    result = plan.result("force")
    if not result:
        return "Not run yet: `python scripts/paper_tables.py run --only force`.\n"
    report = result["force"]
    header = ["Test MSE (N²)", *[f"{r['train_samples']:,} samples" for r in report["sizes"]]]
    rows = [
        ["Force network", *[f"{r['model']['mse_n2']:.4f}" for r in report["sizes"]]],
        ["Train-set mean", *[f"{r['train_mean']['mse_n2']:.4f}" for r in report["sizes"]]],
    ]
    paper = [PAPER_FORCE.get(r["size_requested"]) for r in report["sizes"]]
    rows.append(["Paper: force network", *[f"{p:.4f}" if p is not None else "-" for p in paper]])
    rows.append(["Paper: baseline", *[f"{PAPER_FORCE_BASELINE:.4f}"] * len(report["sizes"])])
    if all("without_outliers" in r for r in report["sizes"]):
        rows.append(
            [
                f"Force network, without the {report['test_outliers']} test sample(s) above {report['outlier_n']:g} N",
                *[f"{r['without_outliers']['model']['mse_n2']:.4f}" for r in report["sizes"]],
            ]
        )
    text = _table(header, rows)
    text += (
        f"\nTest set: {report['test_samples']:,} samples of {report['test_episodes']} episodes, mean force "
        f"{report['test_force_mean_n']:.3f} N (std {report['test_force_std_n']:.3f} N).\n"
    )
    return text + _provenance(plan, ["force"], "force")


def curves_figure(plan: Plan, path: Path) -> str:
    """Episode length against training steps per modality (median over seeds, min-max band)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(TARGETS), figsize=(4.6 * len(TARGETS), 6.4), squeeze=False)
    colours = dict(zip(MODALITIES, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    drawn, with_return = 0, False
    for col, target in enumerate(TARGETS):
        top, bottom = axes[0][col], axes[1][col]
        returns = None  # the protocol's mean return: it still shows learning while every episode fails
        for obs, label in MODALITIES.items():
            # Finished seeds only, as in the main table: a running seed's curve stops short.
            names = [f"main/{obs}/{target}/seed{s}" for s in SEEDS]
            runs = [r for r in (_evaluations(plan, n) for n in names if _finished(plan, n)) if r]
            if runs:
                steps = sorted({e["step"] for r in runs for e in r})
                values = [[e["mean_episode_length"] for r in runs for e in r if e["step"] == s] for s in steps]
                top.plot(
                    steps,
                    [statistics.median(v) for v in values],
                    color=colours[obs],
                    label=f"{label} ({len(runs)} seed{'s' if len(runs) > 1 else ''})",
                )
                top.fill_between(
                    steps, [min(v) for v in values], [max(v) for v in values], color=colours[obs], alpha=0.15
                )
                drawn += 1
            if obs in PROTOCOL:
                name = f"protocol/{obs}/{target}/seed0"
                evals = _evaluations(plan, name)
                if evals:  # a protocol cell runs for hours: its curve so far is drawn, and says so
                    running = "" if _finished(plan, name) else f", unfinished: {evals[-1]['step']:,} steps"
                    bottom.plot(
                        [e["step"] for e in evals],
                        [e["mean_episode_length"] for e in evals],
                        color=colours[obs],
                        label=f"{label} (seed 0{running})",
                    )
                    if all("mean_return" in e for e in evals):  # records before 2026-11-28 did not keep it
                        returns = returns or bottom.twinx()
                        returns.plot(
                            [e["step"] for e in evals], [e["mean_return"] for e in evals], color=colours[obs], ls=":"
                        )
                    drawn += 1
        if returns is not None:
            with_return = True
            returns.set_ylabel("mean return, Euclidean reward (dotted)")
            returns.set_ylim(
                top=max(0.0, returns.get_ylim()[1])
            )  # 0 at the top: a flat return sits below the 300-step line
        human = plan.root / "human" / target / "metrics.json"
        for ax in (top, bottom):
            if human.is_file():
                length = json.loads(human.read_text())["summary"]["episode_length"]["mean"]
                ax.axhline(length, color="k", ls="--", lw=1, label="Human")
            ax.set_ylim(0, 310)
            ax.grid(alpha=0.3)
            ax.set_xlabel("environment steps")
        top.set_title(f"{target.upper()}, type I: the project's recipe")
        bottom.set_title(f"{target.upper()}, type I: the paper's protocol")
        top.set_ylabel("episode length (steps, 10 episodes)")
        bottom.set_ylabel("episode length (steps, 10 episodes)")
        for ax, where in ((top, "best"), (bottom, "lower right")):  # the return starts low on the left
            if ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=7, loc=where)
    if not any((plan.root / "human" / t / "metrics.json").is_file() for t in TARGETS):
        fig.text(0.5, 0.005, "No human data recorded (cathsim-teleop; see docs/paper.md)", ha="center", fontsize=8)
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return (
        f"![episode length against training steps]({path.name})\n\n"
        f"Median over the seeds with their range; 300 steps is the episode limit (a failure). "
        + ("Dotted, right axis: the protocol's mean return. " if with_return else "")
        + f"{drawn} curves drawn.\n"
    )


def _cost_group(name: str) -> tuple:
    """(row, target) of a cell in the cost table: a cell's seeds share a row, and so do its
    targets, except in the main table, where the LCCA's demonstrations cost more."""
    key = re.sub(r"/seed\d+$", "", name)
    match = None if key.startswith("main/") else re.fullmatch(r"(.*[_/])(bca|lcca)", key)
    return (match.group(1), match.group(2)) if match else (key, "")


def cost_table(plan: Plan) -> str:
    groups: dict = {}
    for cell in plan.cells:
        key, target = _cost_group(cell.name)
        info = _cell_info(plan, cell.name)
        g = groups.setdefault(
            key, {"estimated": cell.minutes, "measured": [], "cells": 0, "finished": 0, "targets": []}
        )
        g["cells"] += 1
        if target and target not in g["targets"]:
            g["targets"].append(target)
        if info:
            g["finished"] += 1
            if info.get("attempts", 1) == 1:  # a resumed cell's killed attempts were not timed
                g["measured"].append(info["seconds"] / 60)
    rows = [
        [
            k + ", ".join(g["targets"]),
            g["cells"],
            g["finished"],
            f"{g['estimated']:.0f}",
            f"{statistics.median(g['measured']):.1f} ({len(g['measured'])})" if g["measured"] else "-",
        ]
        for k, g in groups.items()
    ]
    return _table(
        [
            "Cell",
            "Cells",
            "Finished",
            "Estimated min per cell",
            "Measured min per cell (median of the cells finished in one attempt)",
        ],
        rows,
    )


SECTIONS = {
    "main": main_table,
    "protocol": protocol_table,
    "imitation": imitation_table,
    "force": force_table,
}


def report(plan: Plan, out: Path) -> str:
    blocks = {name: writer(plan) for name, writer in SECTIONS.items()}
    figure = out.with_name(f"{out.stem}_learning_curves.png")
    blocks["curves"] = curves_figure(plan, figure)
    if out.is_file():
        text = out.read_text()
        for name, block in blocks.items():
            pattern = re.compile(rf"(<!-- paper_tables:{name} -->\n).*?(<!-- /paper_tables:{name} -->)", re.S)
            text = pattern.sub(lambda m, b=block: m.group(1) + b + m.group(2), text)
    else:
        text = "# The paper's experiments\n\n" + "".join(
            f"## {name}\n\n<!-- paper_tables:{name} -->\n{block}<!-- /paper_tables:{name} -->\n\n"
            for name, block in blocks.items()
        )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    return text


def _only(args) -> tuple:
    """(--only prefixes, launcher options): a hydra.launcher.* option after --only is the launcher's."""
    only = [o for o in getattr(args, "only", None) or [] if "=" not in o]
    extra = [o for o in getattr(args, "only", None) or [] if "=" in o] + getattr(args, "overrides", [])
    return only, extra


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path("outputs/paper"))
    parser.add_argument(
        "--record",
        type=Path,
        default=None,
        help="the finished cells' numbers (default: experiments/paper_results.json for the full "
        "budget, ROOT/results.json for tiny); cells it holds are not run again",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("plan", help="every cell, its state and its cost; the multiruns `run` launches now")
    r = sub.add_parser("run", help="run the unfinished cells as Hydra multiruns")
    r.add_argument("--budget", choices=("full", "tiny"), default=None, help="tiny: a few steps per cell (tests)")
    sel = sub.add_parser("reselect", help="choose best.zip again in finished training cells with an unbroken tie")
    for command in (p, r, sel):
        command.add_argument("--only", nargs="*", help="cells whose name starts with one of these")
        sweeps.add_launcher_options(command)
        command.add_argument("overrides", nargs="*", help="launcher options: hydra.launcher.<key>=<value>")
    rep = sub.add_parser("report", help="the tables and the figure")
    rep.add_argument("--out", type=Path, default=None, help="markdown file (default ROOT/paper.md)")
    args = parser.parse_args(argv)
    only, extra = _only(args)
    try:
        plan = open_plan(args.root, getattr(args, "budget", None), args.record)
        names = [c.name for c in plan.cells]
        for prefix in only:
            if not any(n.startswith(prefix) for n in names):
                raise UsageError(
                    f"--only {prefix}: no cell starts with it; cells: main/<obs>/<target>/seed<s>, "
                    f"imitation/data/..., imitation/bc/..., force, protocol/<obs>/<target>/seed0"
                )
        if args.command != "report":
            launcher = sweeps.launcher_overrides(args.launcher, args.jobs, extra)
    except UsageError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    try:
        if args.command == "plan":
            print_plan(plan, only, launcher)
            return 0
        if args.command == "reselect":
            return reselect(plan, only, launcher)
        if args.command == "run":
            args.root.mkdir(parents=True, exist_ok=True)
            (args.root / "plan.json").write_text(json.dumps({"budget": plan.budget}))
            return run(plan, only, launcher)
    except KeyboardInterrupt:
        print("stopped; `run` again resumes the cells where they stopped", file=sys.stderr)
        return 130
    out = args.out or args.root / "paper.md"
    report(plan, out)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
