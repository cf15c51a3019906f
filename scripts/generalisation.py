"""The generalisation table: navigators trained on random arches, scored on anatomies they never saw.

    python scripts/generalisation.py train --task bca --seed 0 1 2    # cathsim-train -m +experiment=navigator
    python scripts/generalisation.py train --task bca --specialist    # the default recipe on type I, for comparison
    python scripts/generalisation.py evaluate --task bca --jobs 2     # every policy on every anatomy below
    python scripts/generalisation.py train --task bca lcca --seed 0 1 2 --launcher submitit_slurm \
        hydra.launcher.partition=<partition>                          # on a SLURM cluster
    python scripts/generalisation.py report
    python scripts/generalisation.py ship --task bca                  # the seed best on the tuning pool
    python scripts/generalisation.py curves --out docs/navigator_curves.png

`train` runs `cathsim-train -m +experiment=navigator task=<tasks> seed=<seeds>`, each run in
ROOT/runs/<task>/seed<seed>; `--specialist` runs the default recipe on type I into
ROOT/runs/<task>/type1. A run with its final report (eval/metrics.json) is skipped, and
one cut short resumes from its last checkpoint (`cathsim-train -m resume=<run>,...`).

`evaluate` scores, with `cathsim-eval` on the same episodes (episode i seeded 10,000 + i):

- policies: each navigator seed's best.zip and, beside it, its last policy (last.zip);
  the scripted expert; the type I specialist; the shipped navigator (`policy=pretrained`);
- anatomies: the held-out pool (`pool_seed=heldout`: 100 arches of aorta=random's
  "morphometry" distribution, each visited once), the same pool with the roadmap's
  tracking and registration noise (navigators only), the same pool in the AP view and in
  LAO 40, the arch's working view (`heldout_ap`, `heldout_lao40`: navigators that see the
  C-arm, trained on views drawn per episode), the
  same pool with the wire found in the fluoroscopic frame (`heldout_fluoro_image`:
  navigators of the image tracker's observations), the nine shipped aortas and the
  segmentation corpus of the tests (cathsim_dmc/anatomy/corpus.py), imported with
  `cathsim-aorta import` and default options, the close-ostia meshes in the sim, LPS and
  RAS frames with their sites found.

Each (policy, anatomy) gets a cathsim-eval report in ROOT/scores/<task>/<policy>/<anatomy>/
(metrics.json). A finished one is skipped, so a run cut short resumes where it stopped.
The rest run as `cathsim-eval -m` sweeps over the policies (and the shipped aortas) that
share an anatomy's settings; each job's folder moves to its place when the sweep ends.

Both run their sweeps through a Hydra launcher (scripts/sweeps.py): `--launcher joblib`
(the default) `--jobs` at a time on this machine, `--launcher submitit_slurm` one SLURM job
each; `hydra.launcher.<key>=<value>` among the arguments passes on to it.

`report` reads the scores into the tables of docs/training.md#unseen-anatomy: success, SPL,
force and episode length on the held-out pool (the navigators' median over seeds with each
seed's score), success by arch type and by branching variant, and success on each shipped
aorta and corpus mesh. `curves` draws each target's periodic evaluations on the training
pool (evaluations.jsonl) against steps: the median over seeds and the seeds' spread.
"""

from __future__ import annotations

import argparse
import datetime
import json
import shutil
import statistics
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

import sweeps  # noqa: E402
from sweeps import UsageError  # noqa: E402

SHIPPED = (
    "type1",
    "type1_oblique",
    "type2",
    "type2_oblique",
    "type3",
    "type3_oblique",
    "aneurysm",
    "low_tortuosity",
    "bovine",
)
# The named pools of aorta=random's "morphometry" distribution (tasks/randomized.py POOL_SEEDS).
HELDOUT = dict(pool_size=100, pool_seed="heldout", order="cycle")
HELDOUT_NAME = "heldout"
# The pool the recipe was tuned on and the shipped seed is chosen on (never the held-out one).
TUNING = dict(pool_size=50, pool_seed="tuning", order="cycle")
TUNING_NAME = "tuning"
# The held-out pool again, with a real system's measurement errors in the roadmap preset: an
# EM-tracked tip (about 1 mm) and a CTA-to-fluoroscopy registration (about 2 mm).
NOISE = dict(tracking_noise_m=0.001, registration_error_m=0.002)
NOISY_NAME = "heldout_noise"
# The held-out pool again in the AP view, for a policy that sees the C-arm (trained on views
# drawn per episode, scored on them under HELDOUT_NAME).
AP_VIEW = dict(lao_deg=0, view_deg_range=None, cranial_deg_range=None)
AP_NAME = "heldout_ap"
# ... and in LAO 40, the arch's working view: the mean obliquity of the arch on CTA
# (anatomy/parameters.py ARCH_OBLIQUITY_DEG, 39.7 +- 13.8 degrees), the angle that shows the
# arch open, its BCA-LSA ostia line square to the view, as a clinic sets the C-arm for it.
WORKING_VIEW = dict(lao_deg=40, view_deg_range=None, cranial_deg_range=None)
WORKING_NAME = "heldout_lao40"
FIXED_VIEWS = {AP_NAME: AP_VIEW, WORKING_NAME: WORKING_VIEW}
# The held-out pool again with the wire of the image-plane observations found in each step's
# fluoroscopic frame instead of projected (obs.tracking_source=fluoro_image), for a policy
# that reads them.
FLUORO_TRACKING = dict(tracking_source="fluoro_image")
FLUORO_TRACKING_NAME = "heldout_fluoro_image"
CORPUS = ("noisy", "decimated", "pinched", "stump", "wall_shell")
# The close-ostia corpus meshes, each written in the simulator's frame and in the two patient
# frames with a scanner's origin far from the anatomy, imported with defaults (sites found).
CLOSE_OSTIA_FRAMES = ("sim", "LPS", "RAS")
SCANNER_ORIGIN_LPS_MM = (-123.4, 56.7, -890.1)
CLOSE_OSTIA = tuple(f"{n}_{f}" for n in ("close_ostia", "shared_trunk") for f in CLOSE_OSTIA_FRAMES)
ANATOMIES = (*SHIPPED, *[f"corpus_{c}" for c in (*CORPUS, *CLOSE_OSTIA)])  # the table beside the held-out pool
EVAL_SEED = 10_000
TARGETS = ("bca", "lcca")


def _run(command: list) -> None:
    print(" ".join(str(c) for c in command), flush=True)
    subprocess.run([str(c) for c in command], check=True)


def _tool(name: str) -> Path:
    return Path(sys.executable).with_name(f"cathsim-{name}")


def _sweep_dir(root: Path, tool: str) -> Path:
    """Where a multirun keeps its own files: ROOT/multirun/<time>_<tool>."""
    return root / "multirun" / f"{datetime.datetime.now():%Y-%m-%d_%H-%M-%S-%f}_{tool}"


def run_folder(root: Path, task: str, seed, specialist: bool) -> Path:
    """ROOT/runs/<task>/seed<seed>, or ROOT/runs/<task>/type1 for the specialist."""
    return root / "runs" / task / ("type1" if specialist else f"seed{seed}")


def train_launches(root: Path, tasks: list, seeds: list, specialist: bool, overrides: list) -> list:
    """(fixed overrides, sweep, subdir) of the `cathsim-train -m` runs that train what is not
    finished: the runs cut short resume (a sweep over resume=); the others start, a sweep
    over task and seed, each job in its run folder (subdir)."""
    root = root.resolve()
    fresh, resumed = [], []
    for task in tasks:
        for seed in seeds:
            folder = run_folder(root, task, seed, specialist)
            if sweeps.finished_report(folder / "eval" / "metrics.json"):
                print(f"{folder}: finished", flush=True)
            elif (folder / "checkpoints" / "last.zip").is_file():
                resumed.append(str(folder))
            else:
                fresh.append({"task": task, "seed": seed})
    found = [([], {"resume": resumed}, "${resume}")] if resumed else []
    recipe = ["aorta=type1"] if specialist else ["+experiment=navigator"]
    fixed = [*recipe, "trainer.progress_bar=false", "trainer.video=false", *overrides]
    subdir = str(run_folder(root, "${task.target}", "${seed}", specialist))
    return found + [(fixed, block, subdir) for block in sweeps.blocks(fresh)]


def train(root: Path, tasks: list, seeds: list, specialist: bool, overrides: list, launcher: list) -> int:
    """Train the runs of `tasks` x `seeds` that are not finished; a new run's folder gets
    commit.txt, the commit it started at."""
    if specialist and len(seeds) > 1:
        raise UsageError(f"--seed {' '.join(map(str, seeds))}: the specialist is one run per task; give one seed")
    root, commit, failed = root.resolve(), sweeps.commit(), 0
    for fixed, sweep, subdir in train_launches(root, tasks, seeds, specialist, overrides):
        for task in sweep.get("task", []):
            for seed in sweep["seed"]:
                folder = run_folder(root, task, seed, specialist)
                folder.mkdir(parents=True, exist_ok=True)
                (folder / "commit.txt").write_text(commit + "\n")
        failed += (
            sweeps.launch(sweeps.sweep_command("train", fixed, sweep, _sweep_dir(root, "train"), subdir, launcher)) != 0
        )
    return 1 if failed else 0


def import_corpus(root: Path) -> dict:
    """name -> asset folder of each segmentation-corpus mesh, imported with default options."""
    from cathsim_dmc.anatomy.corpus import make_variant

    assets = {}
    for name in CORPUS:
        out = root / "corpus" / name
        if not (out / "meta.json").is_file():
            work = root / "corpus" / "meshes"
            work.mkdir(parents=True, exist_ok=True)
            path, entry, sites = make_variant(name, work)
            vec = lambda p: "[" + ",".join(f"{x:.4f}" for x in p) + "]"  # noqa: E731
            _run(
                [
                    _tool("aorta"),
                    "import",
                    f"mesh={path}",
                    f"entry={vec(entry)}",
                    f"out={out}",
                    *[f"sites.{k}={vec(p)}" for k, p in sorted(sites.items())],
                ]
            )
        assets[f"corpus_{name}"] = out
    for name in CLOSE_OSTIA:
        out = root / "corpus" / name
        if not (out / "meta.json").is_file():
            variant, frame = name.rsplit("_", 1)
            mesh = _close_ostia_mesh(root / "corpus" / "meshes", variant, frame)
            _run([_tool("aorta"), "import", f"mesh={mesh}", "units=mm", f"frame={frame}", f"out={out}"])
        assets[f"corpus_{name}"] = out
    return assets


def _close_ostia_mesh(work: Path, variant: str, frame: str) -> Path:
    """The close-ostia corpus mesh `variant` (millimetres) written in `frame`; the patient
    frames are moved to a scanner's origin, as a CT segmentation comes."""
    import numpy as np
    import trimesh

    from cathsim_dmc.anatomy.corpus import make_variant
    from cathsim_dmc.anatomy.frames import from_sim, to_sim

    work.mkdir(parents=True, exist_ok=True)
    path = work / f"{variant}.stl"
    if not path.is_file():
        path = make_variant(variant, work)[0]
    if frame == "sim":
        return path
    origin = from_sim(to_sim(np.array(SCANNER_ORIGIN_LPS_MM), "LPS"), frame)
    mesh = trimesh.load(path, process=False)
    out = work / f"{variant}_{frame}.stl"
    trimesh.Trimesh(from_sim(np.asarray(mesh.vertices), frame) + origin, mesh.faces, process=False).export(out)
    return out


def policies(root: Path, task: str, unfinished: bool = False) -> dict:
    """name -> what make_policy takes, for every policy that exists (a navigator run once it
    has its final report, or with `unfinished` as soon as it has checkpoints)."""
    found = {"expert": "expert"}
    from cathsim_dmc.agents.trained import PRETRAINED_KINDS, shipped_targets

    for kind in PRETRAINED_KINDS:
        if task in shipped_targets(kind=kind):
            found[kind] = kind
    specialist = root / "runs" / task / "type1" / "checkpoints" / "best.zip"
    if specialist.is_file():
        found["specialist_type1"] = str(specialist)
    steps = recipe_steps()
    for run in sorted((root / "runs" / task).glob("seed*")):
        for kind in ("best", "last"):
            checkpoint = run / "checkpoints" / f"{kind}.zip"
            # The last policy is the one at the recipe's budget (a run trained with a longer
            # budget has its checkpoint), so that every seed's last policy is the same recipe's.
            at_budget = run / "checkpoints" / f"step_{steps}.zip"
            if kind == "last" and at_budget.is_file():
                checkpoint = at_budget
            finished = (run / "eval" / "metrics.json").is_file() or at_budget.is_file()
            if checkpoint.is_file() and (unfinished or finished):
                found[f"navigator_{run.name}_{kind}"] = str(checkpoint)
    return found


def _recipe() -> dict:
    import yaml

    return yaml.safe_load((ROOT / "conf" / "experiment" / "navigator.yaml").read_text())


def recipe_steps() -> int:
    """The navigator recipe's online steps (conf/experiment/navigator.yaml)."""
    return int(_recipe()["trainer"]["total_timesteps"])


def recipe_obs() -> str:
    """The navigator recipe's observation preset (conf/experiment/navigator.yaml)."""
    for entry in _recipe()["defaults"]:
        if isinstance(entry, dict) and "override /obs" in entry:
            return entry["override /obs"]
    raise ValueError("conf/experiment/navigator.yaml sets no observation preset")


def recipe_catheter() -> str | None:
    """The catheter the navigator recipe trains with (conf/experiment/navigator.yaml), or None."""
    return (_recipe().get("task") or {}).get("catheter")


# What each navigator preset observes, for the model card.
PRESET_CARD = {
    "roadmap": "the registered roadmap around the tracked tip, in the tip's frame, and the robot's encoders",
    "roadmap_timed": "the registered roadmap around the tracked tip, in the tip's frame, the robot's encoders, "
    "and the steps the tip has stayed at the target's depth",
    "roadmap_memory_carriage": "the registered roadmap around the tracked tip, in the tip's frame, the robot's "
    "encoders, the heading of a wrong branch the tip has entered while it passes its ostium, whether the catheter "
    "has been called, and the carriage's speed",
}


def _pool(params: dict) -> list:
    return ["aorta=random", *[f"aorta.params.{k}={v}".replace(" ", "") for k, v in params.items()]]


def _obs_overrides(options: dict) -> list:
    return [f"obs.{k}={'null' if v is None else v}" for k, v in options.items()]


def anatomy_overrides(root: Path, episodes: int, shipped_episodes: int, only_anatomies: list | None = None) -> dict:
    """anatomy name -> (its cathsim-eval overrides, the key of them a sweep over anatomies
    varies, or None)."""
    anatomies = {
        HELDOUT_NAME: ([*_pool(HELDOUT), f"episodes={episodes}"], None),
        TUNING_NAME: ([*_pool(TUNING), f"episodes={TUNING['pool_size']}"], None),
        NOISY_NAME: ([*_pool(HELDOUT), *[f"obs.{k}={v}" for k, v in NOISE.items()], f"episodes={episodes}"], None),
        **{
            name: ([*_pool(HELDOUT), *_obs_overrides(view), f"episodes={episodes}"], None)
            for name, view in FIXED_VIEWS.items()
        },
        FLUORO_TRACKING_NAME: ([*_pool(HELDOUT), *_obs_overrides(FLUORO_TRACKING), f"episodes={episodes}"], None),
    }
    anatomies.update({name: ([f"aorta={name}", f"episodes={shipped_episodes}"], "aorta") for name in SHIPPED})
    if not only_anatomies or any(a.startswith("corpus_") for a in only_anatomies):
        for name, folder in import_corpus(root).items():
            # an asset folder as cathsim-eval's aorta=DIR becomes; the label only names Hydra's folders
            overrides = ["aorta=folder", f"aorta.name={folder.resolve()}", "aorta.label=corpus"]
            anatomies[name] = ([*overrides, f"episodes={shipped_episodes}"], "aorta.name")
    if only_anatomies:
        anatomies = {k: v for k, v in anatomies.items() if k in only_anatomies}
    return anatomies


def anatomy_of(overrides: dict) -> str:
    """The anatomy a cathsim-eval job of `evaluate` scored, from its overrides."""
    if overrides.get("aorta") == "random":
        if str(overrides["aorta.params.pool_seed"]) == str(TUNING["pool_seed"]):
            return TUNING_NAME
        if "obs.view_deg_range" in overrides:
            return next(n for n, v in FIXED_VIEWS.items() if float(overrides["obs.lao_deg"]) == v["lao_deg"])
        if "obs.tracking_source" in overrides:
            return FLUORO_TRACKING_NAME
        return NOISY_NAME if "obs.tracking_noise_m" in overrides else HELDOUT_NAME
    if overrides.get("aorta") == "folder":
        return f"corpus_{Path(overrides['aorta.name']).name}"
    return overrides["aorta"]


def evaluation_jobs(
    root: Path,
    task: str,
    episodes: int,
    shipped_episodes: int,
    only: list | None,
    unfinished: bool = False,
    only_anatomies: list | None = None,
) -> list:
    """(fixed overrides, sweep) of the `cathsim-eval -m` runs that score each (policy,
    anatomy) without its report yet: a sweep over the policies, and over the shipped aortas
    or the corpus meshes, that share the rest."""
    from cathsim_dmc.agents.trained import CheckpointPolicy, make_policy
    from cathsim_dmc.tasks.presets import IMAGE_PLANE_OBSERVABLES, OBSERVATION_PRESETS

    # what the tracking and registration noise of NOISY_NAME moves: the 3-D roadmap, the overlay
    # drawn on the fluoroscopic image, and the image tracker's readings
    tracked_observables = IMAGE_PLANE_OBSERVABLES | {"roadmap", "roadmap_overlay"}
    anatomies = anatomy_overrides(root, episodes, shipped_episodes, only_anatomies)
    catheter = recipe_catheter()  # read once: the recipe's YAML
    groups: dict = {}
    for policy_name, source in policies(root, task, unfinished).items():
        if only and policy_name not in only:
            continue
        policy = make_policy(source, seed=0, task=task)
        checkpoint = isinstance(policy, CheckpointPolicy)
        for anatomy, (overrides, varied) in anatomies.items():
            if anatomy == TUNING_NAME and not policy_name.startswith("navigator_"):
                continue  # the tuning pool chooses the seed to ship
            if anatomy == NOISY_NAME and not (
                checkpoint and OBSERVATION_PRESETS[policy.obs_preset].enabled & tracked_observables
            ):
                continue  # the noise is the tracking's and the roadmap's: the expert and the specialist do not read it
            if anatomy in FIXED_VIEWS and not (
                checkpoint and "carm_view" in OBSERVATION_PRESETS[policy.obs_preset].enabled
            ):
                continue  # only a policy that sees the C-arm has a view to fix
            if anatomy == FLUORO_TRACKING_NAME and not (
                checkpoint
                and OBSERVATION_PRESETS[policy.obs_preset].enabled & IMAGE_PLANE_OBSERVABLES
                and policy.image_options.get("tracking_source") != FLUORO_TRACKING["tracking_source"]
            ):
                # only the image tracker's observables have a wire to find in the frame; a policy
                # trained on the found wire reads it on every anatomy, the held-out pool included
                continue
            if sweeps.finished_report(root / "scores" / task / policy_name / anatomy / "metrics.json"):
                continue
            point = {"policy": source}
            fixed = [o for o in overrides if o.split("=", 1)[0] != varied]
            if varied:
                point[varied] = next(o.split("=", 1)[1] for o in overrides if o.split("=", 1)[0] == varied)
            fixed += [
                f"task={task}",
                f"seed={EVAL_SEED}",
                "video=false",
                # A trained agent brings its own observations (named where their noise is set); the
                # expert's do not change what it does.
                *(
                    [f"obs={policy.obs_preset}"]
                    if anatomy in (NOISY_NAME, *FIXED_VIEWS, FLUORO_TRACKING_NAME)
                    else []
                    if checkpoint
                    else ["obs=roadmap"]
                ),
                # The scripted expert drives the catheter the navigators are trained with; a
                # checkpoint brings its own (policy.json's env_options).
                *([f"task.catheter={catheter}"] if policy_name == "expert" and catheter else []),
            ]
            groups.setdefault((tuple(fixed), tuple(point)), []).append(point)
    return [(list(fixed), block) for (fixed, _), points in groups.items() for block in sweeps.blocks(points)]


def file_scores(root: Path, task: str, sweep_dir: Path, names: dict) -> int:
    """Move each finished job of the multirun in `sweep_dir` to ROOT/scores/<task>/<policy>/<anatomy>
    (`names`: what cathsim-eval's policy= was -> the policy's name); the sweep's own folder
    goes. Returns how many jobs did not finish."""
    unfinished = 0
    for job in sorted(p for p in sweep_dir.iterdir() if p.is_dir()) if sweep_dir.is_dir() else []:
        overrides = sweeps.job_overrides(job)
        if "policy" not in overrides:
            continue
        if not sweeps.finished_report(job / "metrics.json"):
            unfinished += 1
            continue
        out = root / "scores" / task / names[overrides["policy"]] / anatomy_of(overrides)
        shutil.rmtree(out, ignore_errors=True)
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.move(str(job), str(out))
    shutil.rmtree(sweep_dir, ignore_errors=True)
    return unfinished


def evaluate(
    root: Path,
    task: str,
    episodes: int,
    shipped_episodes: int,
    only: list | None,
    unfinished: bool = False,
    only_anatomies: list | None = None,
    launcher: list = (),
) -> int:
    root = root.resolve()
    names = {source: name for name, source in policies(root, task, unfinished).items()}
    failed = 0
    for fixed, sweep in evaluation_jobs(root, task, episodes, shipped_episodes, only, unfinished, only_anatomies):
        sweep_dir = _sweep_dir(root, "eval")
        status = sweeps.launch(
            sweeps.sweep_command("eval", fixed, sweep, sweep_dir, "${hydra.job.num}", list(launcher))
        )
        failed += file_scores(root, task, sweep_dir, names) + (status != 0)
    return 1 if failed else 0


# -- report ------------------------------------------------------------------------------
def _metrics(folder: Path) -> dict | None:
    path = folder / "metrics.json"
    return json.loads(path.read_text()) if path.is_file() else None


# A septum between two neighbouring ostia (BCA-LCCA or LCCA-LSA) thinner than this (the
# wall's 2 mm) makes the "close ostia" variant of the report.
CLOSE_OSTIA_GAP_M = 0.002
VARIANTS = ("separate", "close ostia", "bovine")


def variant_of(params: dict) -> str:
    """An arch's branching variant from its generator parameters (meta.json's params)."""
    if params.get("bovine"):
        return "bovine"
    gap = min(params["bca_lcca_gap_m"], params["lcca_lsa_gap_m"])
    return "close ostia" if gap < CLOSE_OSTIA_GAP_M else "separate"


def _pool_labels() -> tuple:
    """(arch name -> type I/II/III, arch name -> variant) of the held-out pool's assets."""
    from cathsim_dmc.tasks.randomized import anatomy_pool

    params = {k: v for k, v in HELDOUT.items() if k != "order"}
    metas = [json.loads((a / "meta.json").read_text()) for a in anatomy_pool(**params)]
    return {m["name"]: m["params"]["arch_type"] for m in metas}, {m["name"]: variant_of(m["params"]) for m in metas}


def _cell(values: list, fmt: str = "{:.0f}") -> str:
    if not values:
        return "-"
    if len(values) == 1:
        return fmt.format(values[0])
    return f"{fmt.format(statistics.median(values))} ({', '.join(fmt.format(v) for v in values)})"


def _groups(scores: Path) -> dict:
    """Row label -> the policy folders it summarises (navigator seeds grouped, best and last apart)."""
    groups: dict = {}
    for folder in sorted(p for p in scores.iterdir() if p.is_dir()):
        name = folder.name
        if name.startswith("navigator_seed"):
            kind = name.rsplit("_", 1)[1]
            groups.setdefault(f"navigator, {kind}.zip", []).append(folder)
        else:
            groups[name.replace("_", " ")] = [folder]
    order = ["navigator, best.zip", "navigator, last.zip", "pretrained", "expert", "specialist type1"]
    return dict(sorted(groups.items(), key=lambda kv: order.index(kv[0]) if kv[0] in order else len(order)))


def report(root: Path, out: Path | None, arch_types: dict | None = None, variants: dict | None = None) -> str:
    """The tables (markdown) from ROOT/scores; `arch_types` (held-out arch name -> I, II,
    III) and `variants` (-> one of VARIANTS) default to the pool's own."""
    types = arch_types
    lines, shipped = [], {}
    for task in TARGETS:
        scores = root / "scores" / task
        if not scores.is_dir():
            continue
        groups = _groups(scores)
        lines += [
            f"### {task.upper()}: {HELDOUT['pool_size']} held-out arches",
            "",
            "| policy | seeds | success % | safe success % | SPL % | force N | episode length | type I | type II "
            "| type III | separate ostia | close ostia | bovine | success % with noise | success % AP view "
            "| success % LAO 40 view | success % wire found in the fluoro frame |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for label, folders in groups.items():
            reports = [m for m in (_metrics(f / HELDOUT_NAME) for f in folders) if m]
            if not reports:
                continue
            if types is None or variants is None:
                pool_types, pool_variants = _pool_labels()
                types, variants = types or pool_types, variants or pool_variants
            mean = lambda m, key: m["summary"][key]["mean"]  # noqa: E731
            by_type = []
            for labels, label_values in ((types, ("I", "II", "III")), (variants, VARIANTS)):
                for value in label_values:
                    rates = []
                    for m in reports:
                        hits = [e["success"] for e in m["episodes"] if labels.get(e.get("aorta")) == value]
                        if hits:
                            rates.append(100.0 * sum(hits) / len(hits))
                    by_type.append(_cell(rates))
            lines.append(
                f"| {label} | {len(reports)} | {_cell([mean(m, 'success_pct') for m in reports])} | "
                # reports from before safe success have no such column: "-"
                f"{_cell([mean(m, 'safe_success_pct') for m in reports if 'safe_success_pct' in m['summary']])} | "
                f"{_cell([mean(m, 'spl_pct') for m in reports])} | "
                f"{_cell([mean(m, 'force_n') for m in reports], '{:.2f}')} | "
                f"{_cell([mean(m, 'episode_length') for m in reports])} | "
                + " | ".join(by_type)
                + " | "
                + " | ".join(
                    _cell([mean(m, "success_pct") for m in (_metrics(f / name) for f in folders) if m])
                    for name in (NOISY_NAME, *FIXED_VIEWS, FLUORO_TRACKING_NAME)
                )
                + " |"
            )
        # One row per anatomy, one column per (target, policy) scored on any of them.
        for label, folders in groups.items():
            cells = [
                _cell([m["summary"]["success_pct"]["mean"] for m in (_metrics(f / a) for f in folders) if m])
                for a in ANATOMIES
            ]
            if any(c != "-" for c in cells):
                shipped[f"{task.upper()}: {label}"] = cells
        lines.append("")
    if shipped:
        lines += [
            "### Success % on the shipped aortas and the imported corpus",
            "",
            "| anatomy | " + " | ".join(shipped) + " |",
            "|---" * (len(shipped) + 1) + "|",
        ]
        for i, anatomy in enumerate(ANATOMIES):
            lines.append(
                f"| {anatomy.replace('corpus_', 'corpus: ')} | "
                + " | ".join(cells[i] for cells in shipped.values())
                + " |"
            )
        lines.append("")
    text = "\n".join(lines)
    if out:
        out.write_text(text)
    print(text)
    return text


def _summary(folder: Path) -> str:
    m = _metrics(folder)
    if not m:
        return "-"
    mean = lambda key: m["summary"][key]["mean"]  # noqa: E731
    return (
        f"{mean('success_pct'):.0f}% success, SPL {mean('spl_pct'):.0f}%, force {mean('force_n'):.2f} N, "
        f"{mean('episode_length'):.0f} steps"
    )


VIEW_BINS_DEG = ((-45, -30), (-30, -15), (-15, 15), (15, 30), (30, 45))


def _success_by_view(metrics: dict | None) -> str:
    """'reached/episodes' per bin of the episodes' drawn LAO angle ('' without drawn views)."""
    episodes = (metrics or {}).get("episodes", [])
    if not episodes or "carm_view_deg" not in episodes[0]:
        return ""
    cells = []
    for low, high in VIEW_BINS_DEG:
        last = high == VIEW_BINS_DEG[-1][1]  # the widest view belongs to the last bin
        inside = [e for e in episodes if low <= (lao := e["carm_view_deg"][0]) < high or (last and lao == high)]
        cells.append(f"{low:+d} to {high:+d}: {sum(bool(e['success']) for e in inside)}/{len(inside)}")
    return "; ".join(cells)


WIDE_BRANCH_LIMIT = """- In the wide BCA (12.5 mm in the shipped arches) the tip can come to rest on the wall 4-8.5 mm
  from the target, outside the 4 mm zone. The policy strokes the wire past the target and back to
  get it off the wall, as the scripted expert does, timed by the depth clock; in the failures
  traced, it then cut short the retreat out of the branch that follows the expert's unsuccessful
  strokes (docs/training.md#unseen-anatomy). Of the seeds' {failed} failed episodes on the held-out and
  shipped arches, {near} ended within 8.5 mm of the target.
"""


def _failures_near_target(scores: Path, within_m: float = 0.0085) -> tuple:
    """(failed episodes, those that ended within `within_m` of the target) over every
    navigator seed's best.zip on the held-out pool and the shipped aortas."""
    final = [
        e["final_distance_m"]
        for folder in scores.glob("navigator_seed*_best")
        for anatomy in (HELDOUT_NAME, *SHIPPED)
        if (m := _metrics(folder / anatomy))
        for e in m["episodes"]
        if not e["success"]
    ]
    return len(final), sum(d < within_m for d in final)


def ship(root: Path, task: str, seed: int | None = None, why: str | None = None, fluoro: bool = False) -> Path:
    """Export the navigator seed that scores best on the tuning pool (never the held-out one)
    as the shipped `policy=pretrained` for `task`, with its model card; or seed `seed`, with
    `why` (how it was chosen) on the card. With `fluoro`, as `policy=pretrained_fluoro`: the
    runs under ROOT must read only what a C-arm suite measures."""
    from cathsim_dmc.agents.pretrained import export_actor
    from cathsim_dmc.agents.trained import PRETRAINED, PRETRAINED_FLUORO, PRETRAINED_KINDS
    from cathsim_dmc.tasks.presets import C_ARM_OBSERVABLES, OBSERVATION_PRESETS

    kind = PRETRAINED_FLUORO if fluoro else PRETRAINED

    scores = root / "scores" / task
    seeds = sorted(scores.glob("navigator_seed*_best"))
    if seed is not None:
        chosen = scores / f"navigator_seed{seed}_best"
        if not (root / "runs" / task / f"seed{seed}" / "checkpoints" / "best.json").is_file():
            raise UsageError(f"--seed {seed}: no finished run of {task} seed {seed} in {root / 'runs' / task}")
    else:
        candidates = {}
        for folder in seeds:
            m = _metrics(folder / TUNING_NAME)
            if m:
                candidates[folder] = (m["summary"]["success_pct"]["mean"], m["summary"]["spl_pct"]["mean"])
        if not candidates and len(seeds) == 1:
            candidates = {seeds[0]: (0.0, 0.0)}  # one seed: nothing to choose between
        if not candidates:
            raise SystemExit(f"no navigator of {task} scored on the tuning pool in {scores}: run evaluate first")
        chosen = max(candidates, key=candidates.get)
    run_name = chosen.name.split("_")[1]  # "seed2": the run's folder under ROOT/runs/<task>
    run = root / "runs" / task / run_name
    commit = (run / "commit.txt").read_text().strip() if (run / "commit.txt").is_file() else "unknown"
    best = json.loads((run / "checkpoints" / "best.json").read_text())
    from omegaconf import OmegaConf

    config = OmegaConf.load(run / "config.yaml")
    found_wire = config.obs.get("tracking_source") == FLUORO_TRACKING["tracking_source"]
    views = (*FIXED_VIEWS, *(() if found_wire else (FLUORO_TRACKING_NAME,))) if fluoro else ()
    anatomies = (HELDOUT_NAME, *views, NOISY_NAME, TUNING_NAME, *ANATOMIES)
    names = {
        AP_NAME: "held out, in the AP view",
        WORKING_NAME: "held out, in LAO 40 (the arch's working view)",
        FLUORO_TRACKING_NAME: "held out, the wire found in each fluoroscopic frame",
        HELDOUT_NAME: f"held out: pool {HELDOUT['pool_seed']}, {HELDOUT['pool_size']} arches"
        + (", the C-arm's view drawn per episode" if fluoro else "")
        + (", the wire found in each fluoroscopic frame" if found_wire else ""),
        NOISY_NAME: f"held out, with {NOISE['tracking_noise_m'] * 1e3:g} mm tracking and "
        f"{NOISE['registration_error_m'] * 1e3:g} mm registration noise",
        TUNING_NAME: f"tuning: pool {TUNING['pool_seed']}, {TUNING['pool_size']} arches",
    }
    rows = "\n".join(
        f"| {names.get(anatomy, anatomy)} | {_summary(chosen / anatomy)} |"
        for anatomy in anatomies
        if _metrics(chosen / anatomy)
    )
    by_view = _success_by_view(_metrics(chosen / HELDOUT_NAME))
    if by_view:
        rows += f"\n\nHeld out, reached by the view drawn (LAO positive, RAO negative, degrees): {by_view}."
    missing = [anatomy for anatomy in anatomies if not _metrics(chosen / anatomy)]
    if missing:
        rows += f"\n\nNot scored yet: {', '.join(missing)}."
    obs = config.obs.name
    beyond_c_arm = sorted(OBSERVATION_PRESETS[obs].enabled - C_ARM_OBSERVABLES)
    if fluoro and beyond_c_arm:
        raise UsageError(f"--fluoro: {run} reads obs={obs}, which a C-arm does not give ({', '.join(beyond_c_arm)})")
    stem = f"{PRETRAINED_KINDS[kind]}_{task}"
    command = f"cathsim-train +experiment=navigator task={task} {run_name.replace('seed', 'seed=')}"
    if obs != recipe_obs():  # trained before the recipe's preset changed: its own
        command += f" obs={obs}"
    for key in ("view_deg_range", "cranial_deg_range"):  # the C-arm's views, drawn per episode
        if config.obs.get(key) is not None:
            command += f" 'obs.{key}=[{','.join(f'{v:g}' for v in config.obs[key])}]'"
    if found_wire:
        command += f" obs.tracking_source={FLUORO_TRACKING['tracking_source']}"
    steps = [json.loads(line)["step"] for line in (run / "evaluations.jsonl").read_text().splitlines()]
    budget = int(config.trainer.total_timesteps)
    stopped = "" if max(steps) >= budget else f" (stopped at step {max(steps):,} of its {budget:,})"
    failed, near = _failures_near_target(scores)
    wide_branch = WIDE_BRANCH_LIMIT.format(failed=failed, near=near) if task == "bca" else ""
    if why:
        chosen_by = why
    elif len(seeds) > 1:
        chosen_by = f"chosen among {len(seeds)} seeds by the tuning pool"
    else:
        chosen_by = "the only seed trained so far"
    what = f"{PRESET_CARD[obs]}; " if obs in PRESET_CARD else ""
    catheter = config.task.get("catheter")
    actions = (
        f"[insertion, rotation, catheter carriage] in [-1, 1], with the `{catheter}` catheter over the wire."
        if catheter
        else "[insertion, rotation] in [-1, 1]; the wire alone, no catheter."
    )
    from cathsim_dmc.anatomy.generate import MORPHOMETRY

    # A run from before aorta=random had a `distribution` drew the fixed_branches arches, never bovine.
    distribution = config.aorta.get("params", {}).get("distribution", "fixed_branches")
    bovine_share = MORPHOMETRY.bovine_fraction if distribution == "morphometry" else 0.0
    if not bovine_share:
        bovine = (
            "- Bovine arches: trained on none; the reverse-angle LCCA of a bovine trunk needs a catheter,\n"
            "  which this policy does not drive."
        )
    else:
        bovine = f"- Bovine arches: drawn with probability {bovine_share:.0%} in the distribution it was trained on"
        bovine += (
            ";\n  it drives the catheter as the expert it learned from does (docs/benchmarks.md#with-a-catheter)."
            if catheter
            else "."
        )
    drawn_views = ""
    if config.obs.get("view_deg_range") is not None:
        low, high = config.obs.view_deg_range
        drawn_views = f", on a C-arm view drawn per episode (LAO {high:g} to RAO {-low:g} degrees)"
    page = "docs/observations.md#fluoro" if fluoro else "docs/observations.md#roadmap"
    noise = (
        "on the wire found in each fluoroscopic frame, without registration noise" if found_wire else "without noise"
    )
    preset = textwrap.fill(
        f"- **Observation preset**: `{obs}` ({what}{page}), trained {noise}{drawn_views}.",
        width=96,
        subsequent_indent="  ",
    )
    if fluoro:
        title = f"Pretrained navigator from the fluoroscope: {task.upper()}"
        load = f"load_pretrained('{task}', kind='{kind}')"
        needs = (
            (
                "- It finds the wire in each fluoroscopic frame (cathsim_dmc/sim/wire_finder.py), as it was\n"
                "  trained; `obs.tracking_source=projection` gives it the wire projected from the simulator\n"
                "  instead. It needs a roadmap registered to the C-arm and the C-arm's angles. The table gives\n"
                "  its score in the AP view, in LAO 40, and with registration noise where scored."
            )
            if found_wire
            else (
                "- It needs the wire tracked in the image plane (projected from the simulator's wire, or found in\n"
                "  each fluoroscopic frame with `obs.tracking_source=fluoro_image`), a roadmap registered to the\n"
                "  C-arm and the C-arm's angles. The table gives its score in the AP view, with the wire found in\n"
                "  the frame, and with registration noise where scored."
            )
        )
    else:
        title = f"Pretrained navigator: {task.upper()}"
        load = f"load_pretrained('{task}')"
        needs = (
            "- It needs the roadmap: a centerline from the access to the target with its lumen radius, and the\n"
            "  tip tracked in 3-D. It was trained without tracking or registration noise; the table gives its\n"
            "  score with both."
        )
    card = f"""# {title}

The actor of a SAC agent that steers the angled guidewire from the descending aorta into the
{task.upper()} of aortic arches it has never seen (docs/training.md#unseen-anatomy).

    cathsim-eval policy={kind} task={task} aorta=type3        # any shipped name or asset folder
    python -c "from cathsim_dmc.agents.trained import load_pretrained; policy = {load}"

{preset}
- **Actions**: {actions}
- **Training**: `{command}` at commit {commit}, on a 2-core x86_64 CPU without a GPU;
  `best.zip` of the run{stopped}: step {best["step"]}, {100 * best["success_rate"]:.0f}% of its periodic
  evaluation on 20 training arches; {chosen_by}.
- **Data**: 64 random arches (`pool_seed=training`, aorta=random's "morphometry" distribution:
  types I-III, branching variants, origins, take-off and tortuosity as published morphometry
  reports; docs/anatomy.md), 200 scripted-expert demonstrations, 4 DAgger rounds of 50
  episodes labelled by the expert, then SAC with the cloning term.
- **Files**: {stem}.pt (the actor's weights), {stem}.json (its shapes and options).

## Results

Episode i seeded 10,000 + i; `python scripts/generalisation.py evaluate --task {task}`:

| anatomy | this policy |
|---|---|
{rows}

## Known limits

{needs}
{wide_branch}{bovine}
- It was trained and scored in this simulator only (its wire, wall contact and anatomy
  generator); nothing here is validated on a phantom or a patient.
"""
    trained = {"command": command, "commit": commit, "best_step": best["step"]}
    weights = export_actor(run / "checkpoints" / "best.zip", task, card, trained=trained, kind=kind)
    print(f"shipped {run} as {weights}")
    return weights


def curves(root: Path, out: Path) -> Path:
    """The navigators' learning curves: success of the periodic evaluations (20 training
    arches each) against online steps, per target, over the seeds under ROOT/runs."""
    from cathsim_dmc.evaluation.plots import learning_curves_plot

    panels = {}
    for task in TARGETS:
        seeds = [
            [json.loads(line) for line in (run / "evaluations.jsonl").read_text().splitlines()]
            for run in sorted((root / "runs" / task).glob("seed*"))
            if (run / "evaluations.jsonl").is_file()
        ]
        if seeds:
            panels[task.upper()] = {"navigator": seeds}
    if not panels:
        raise UsageError(f"no navigator run with evaluations.jsonl under {root / 'runs'}")
    return learning_curves_plot(panels, out, ylabel="success on 20 training arches")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path("outputs/generalisation"))
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("train")
    run.add_argument("--task", nargs="+", choices=TARGETS, default=["bca"])
    run.add_argument("--seed", nargs="+", type=int, default=[0])
    run.add_argument("--specialist", action="store_true", help="the default recipe on type I instead")
    run.add_argument(
        "overrides", nargs="*", help="more cathsim-train overrides (key=value), and hydra.launcher.<key>=<value>"
    )
    ev = sub.add_parser("evaluate")
    ev.add_argument("--task", choices=TARGETS, default="bca")
    ev.add_argument("--episodes", type=int, default=HELDOUT["pool_size"], help="episodes on the held-out pool")
    ev.add_argument("--shipped-episodes", type=int, default=20, help="episodes on each shipped aorta and corpus mesh")
    ev.add_argument("--only", nargs="*", help="score only these policies (names as in ROOT/scores)")
    ev.add_argument("--unfinished", action="store_true", help="also score runs without their final report")
    ev.add_argument("--anatomies", nargs="*", help="score only these anatomies (heldout, tuning, type1, ...)")
    ev.add_argument("overrides", nargs="*", help="launcher options: hydra.launcher.<key>=<value>")
    for command in (run, ev):
        sweeps.add_launcher_options(command)
    rep = sub.add_parser("report")
    rep.add_argument("--out", type=Path, default=None)
    shp = sub.add_parser("ship", help="export the tuning pool's best seed (or --seed) as policy=pretrained")
    shp.add_argument("--task", choices=TARGETS, default="bca")
    shp.add_argument("--seed", type=int, help="ship this seed instead of the tuning pool's best (needs --why)")
    shp.add_argument("--why", help="with --seed: how the seed was chosen, written on the model card")
    shp.add_argument("--fluoro", action="store_true", help="as policy=pretrained_fluoro (runs of a C-arm preset)")
    crv = sub.add_parser("curves", help="the navigators' learning curves (median and spread over seeds)")
    crv.add_argument("--out", type=Path, default=Path("navigator_curves.png"))
    args = parser.parse_args(argv)
    try:
        if args.command in ("train", "evaluate"):
            # a key=value after a list option (--seed, --only, --anatomies) belongs with the overrides
            lists = [getattr(args, k) or [] for k in ("only", "anatomies") if hasattr(args, k)]
            given = [o for values in lists for o in values if "=" in str(o)] + args.overrides
            for values in lists:
                values[:] = [o for o in values if "=" not in str(o)]
            extra = [o for o in given if o.startswith("hydra.launcher.")]
            launcher = sweeps.launcher_overrides(args.launcher, args.jobs, extra)
            if args.command == "evaluate" and len(extra) < len(given):
                bad = next(o for o in given if not o.startswith("hydra.launcher."))
                raise UsageError(f"{bad}: evaluate takes launcher options only (hydra.launcher.<key>=<value>)")
        if args.command == "train":
            tool = [o for o in args.overrides if not o.startswith("hydra.launcher.")]
            return train(args.root, args.task, args.seed, args.specialist, tool, launcher)
        if args.command == "curves":
            print(f"wrote {curves(args.root, args.out)}")
            return 0
        if args.command == "ship":
            if (args.seed is None) != (args.why is None):
                raise UsageError("ship: give --seed and --why together, or neither (the tuning pool's best)")
            ship(args.root, args.task, args.seed, args.why, args.fluoro)
            return 0
    except UsageError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if args.command == "evaluate":
        return evaluate(
            args.root,
            args.task,
            args.episodes,
            args.shipped_episodes,
            args.only,
            args.unfinished,
            args.anatomies,
            launcher,
        )
    report(args.root, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
