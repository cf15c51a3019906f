"""scripts/paper_tables.py: every cell composes into its recipe, the cells become Hydra
multiruns that put each job in its cell's folder, a finished cell is skipped, a killed one
resumes, the tables are written from what finished, and bad input is refused."""

import itertools
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time

import pytest
from conftest import load_script


@pytest.fixture(scope="module")
def paper(repo_root):
    return load_script(repo_root / "scripts" / "paper_tables.py")


def _script(repo_root, *args, **kwargs):
    return subprocess.run(
        [sys.executable, str(repo_root / "scripts" / "paper_tables.py"), *args],
        capture_output=True,
        text=True,
        timeout=600,
        **kwargs,
    )


def _overrides(command):
    """The Hydra overrides of a cell's command, without the run folder."""
    return [a for a in command[1:] if not a.startswith("hydra.run.dir=")]


def test_every_training_cell_composes_into_its_recipe(paper, tmp_path):
    from hydra import compose, initialize_config_dir

    from cathsim_dmc.core.shipped import conf_root

    plan = paper.build_plan(tmp_path)
    train = [c for c in plan.cells if c.tool == "train"]
    main = [c for c in train if c.name.startswith("main/")]
    assert len(main) == len(paper.MODALITIES) * len(paper.TARGETS) * len(paper.SEEDS)
    with initialize_config_dir(config_dir=str(conf_root()), version_base=None):
        for cell in train:
            cfg = compose("train", overrides=_overrides(paper.command(plan, cell)))
            kind, obs, target, seed = cell.name.split("/")
            assert (cfg.obs.name, cfg.task.target, cfg.aorta.name, f"seed{cfg.seed}") == (obs, target, "type1", seed)
            assert cfg.trainer.final_eval_episodes == paper.FINAL_EPISODES
            if kind == "main":  # the project's recipe: expert demonstrations, the pre-trained actor scored too
                assert cfg.demos.episodes > 0 and cfg.reward.name == "progress" and cfg.trainer.eval_at_start
                assert cfg.trainer.total_timesteps == paper.MAIN_STEPS[obs]
            else:  # the paper's protocol: its SAC, its reward, no demonstrations
                assert cfg.demos.episodes == 0 and cfg.reward.name == "euclidean"
                assert cfg.algo.name == {"internal": "sac", "pixels": "sac_cpu"}[obs]
                assert cfg.trainer.total_timesteps == paper.PROTOCOL_STEPS
                assert cfg.trainer.save_replay_buffer  # a resumed 100k-step run keeps its transitions
    # The other tools' cells compose too (the ENN agent's dataset needs a trained ENN first).
    with initialize_config_dir(config_dir=str(conf_root()), version_base=None):
        for cell in plan.cells:
            if cell.tool != "train" and not cell.name.startswith("imitation/data/enn_"):
                cfg = compose(cell.tool, overrides=_overrides(paper.command(plan, cell)))
                if cell.tool == "bc":
                    assert cfg.bc.frames == 1 and cfg.bc.image_key == "pixels"  # the paper's student
                    assert str(tmp_path / "imitation" / "data") in str(cfg.data)
                if "onesided" in cell.name:  # every start on one side of pi
                    assert cfg.task.start_rotation_rad - cfg.task.start_rotation_jitter_rad > 3.14159265


def _jobs(launch):
    """Each job of a multirun: its overrides (the fixed ones, then one value of each swept key)."""
    keys = list(launch.sweep)
    for values in itertools.product(*launch.sweep.values()):
        yield dict(zip(keys, values)), [*launch.fixed, *[f"{k}={v}" for k, v in zip(keys, values)]]


def test_the_cells_become_multiruns_whose_jobs_are_the_cells(paper, tmp_path):
    """A job of a multirun composes, with Hydra's own resolution of the sweep's subdir, to
    its cell's folder and to the config of the cell's command run alone."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf, open_dict

    from cathsim_dmc.core.shipped import conf_root

    plan = paper.build_plan(tmp_path, record=tmp_path / "results.json")
    cells = paper.ready(plan, plan.cells)
    assert all(not c.needs for c in cells) and len(cells) == 30 + 8 + 4  # main, datasets, protocol
    launches = paper.launches(plan, cells)
    assert sorted(c.name for job in launches for c in job.cells) == sorted(c.name for c in cells)
    # The main table is two sweeps: the joints' 8,000 steps, and the images' 3,000.
    first, second = launches[0], launches[1]
    assert first.sweep == {"obs": ["internal"], "task": ["bca", "lcca"], "seed": [0, 1, 2]}
    images = ["enn", "pixels_mask", "pixels", "internal_pixels"]
    assert second.sweep == {"obs": images, "task": ["bca", "lcca"], "seed": [0, 1, 2]}
    assert len(launches) == 2 + 4 + 2  # and four dataset sweeps over the targets, two protocol sweeps
    with initialize_config_dir(config_dir=str(conf_root()), version_base=None):
        for job in launches:
            by_name = {c.name: c for c in job.cells}
            jobs = list(_jobs(job))
            assert len(jobs) == len(job.cells)
            for values, overrides in (jobs[0], jobs[-1]):  # (composing each of the 42 takes a minute)
                cfg = compose(job.tool, [*overrides, f"hydra.sweep.subdir={job.subdir}"], return_hydra_config=True)
                cell = by_name[os.path.relpath(cfg.hydra.sweep.subdir, tmp_path)]
                assert cell.sweep == values
                alone = compose(job.tool, overrides=_overrides(paper.command(plan, cell)))
                with open_dict(cfg):
                    del cfg["hydra"]
                assert OmegaConf.to_container(cfg, resolve=True) == OmegaConf.to_container(alone, resolve=True)
    # A cell finished here (or on another machine) is not run again: the remaining seeds
    # of the block are swept, and the sweeps hold every unfinished cell once.
    done = ["main/internal/bca/seed1", "main/enn/lcca/seed0", "imitation/data/expert_more_bca"]
    plan.record.write_text(json.dumps({name: {"info": {"cell": name}} for name in done}))
    left = paper.ready(plan, plan.cells)
    assert sorted(c.name for c in left) == sorted(c.name for c in cells if c.name not in done)
    launches = paper.launches(plan, left)
    names = [c.name for job in launches for c in job.cells]
    assert sorted(names) == sorted(c.name for c in left)
    for job in launches:
        assert len(list(_jobs(job))) == len(job.cells)
    # A training cell killed after its first checkpoint resumes in its own folder.
    killed = tmp_path / "main/pixels/bca/seed2"
    (killed / "checkpoints").mkdir(parents=True)
    (killed / "checkpoints" / "last.zip").write_bytes(b"")
    resume = next(job for job in paper.launches(plan, paper.ready(plan, plan.cells)) if "resume" in job.sweep)
    assert (resume.tool, resume.fixed, resume.sweep, resume.subdir) == (
        "train",
        [],
        {"resume": [str(killed)]},
        "${resume}",
    )
    command = resume.command(tmp_path / "multirun", ["hydra/launcher=joblib"])
    assert f"hydra.run.dir={tmp_path / 'multirun'}" in command  # not set from resume= (cathsim-train)


def test_a_partial_set_of_jobs_is_swept_as_few_products_as_merging_finds(repo_root):
    sweeps = load_script(repo_root / "scripts" / "sweeps.py")
    points = [{"task": t, "seed": s} for t in ("bca", "lcca") for s in (0, 1, 2) if (t, s) != ("bca", 1)]
    blocks = sweeps.blocks(points)
    covered = [dict(zip(b, v)) for b in blocks for v in itertools.product(*b.values())]
    assert sorted(map(str, covered)) == sorted(map(str, points))  # each point once, nothing else
    assert len(blocks) == 2
    assert sweeps.blocks([{"task": t} for t in ("bca", "lcca")]) == [{"task": ["bca", "lcca"]}]


def test_cells_wait_for_what_they_need(paper, tmp_path):
    plan = paper.build_plan(tmp_path)
    names = [c.name for c in plan.cells]
    for cell in plan.cells:
        for need in cell.needs:
            assert names.index(need) < names.index(cell.name), (cell.name, need)
    assert paper.state(plan, plan.by_name("imitation/bc/enn_bca")) == "waiting"
    force = plan.by_name("force")
    assert sorted(force.needs) == sorted(
        f"imitation/data/{d}_{t}" for d in ("expert", "expert_more") for t in paper.TARGETS
    )


def _record(path, cells):
    """A record as another machine left it: the cells' numbers, none of their files."""
    path.write_text(
        json.dumps({name: {"info": {"cell": name, "seconds": 60.0}, **extra} for name, extra in cells.items()})
    )


def test_a_cell_whose_input_finished_on_another_machine_runs_that_input_again_first(paper, tmp_path, capsys):
    plan = paper.build_plan(tmp_path, "tiny", record=tmp_path / "results.json")
    summary = lambda success, spl: {"summary": {"success_pct": {"mean": success}, "spl_pct": {"mean": spl}}}  # noqa: E731
    _record(
        plan.record,
        {
            "imitation/data/expert_bca": {},
            "main/enn/bca/seed0": summary(98, 90),
            "main/enn/bca/seed1": summary(100, 80),
            "main/enn/bca/seed2": summary(100, 70),
        },
    )
    student, data = plan.by_name("imitation/bc/expert_bca"), plan.by_name("imitation/data/expert_bca")
    assert paper.state(plan, data) == "recorded" and plan.done(data)
    assert paper.ready(plan, [student]) == [data]  # the dataset is made again here first
    assert "run again on this machine" in capsys.readouterr().out
    assert paper.ready(plan, [student], {data.name}) == []  # unless that failed
    (tmp_path / data.name).mkdir(parents=True)
    (tmp_path / data.name / paper.CELL_FILE).write_text("{}")
    assert paper.ready(plan, [student]) == [student] and paper.state(plan, data) == "done"

    # The ENN agent's dataset: the record's best seed (success, then SPL) is trained again;
    # once a seed's checkpoints are here, its run is the one used.
    enn_data = plan.by_name("imitation/data/enn_bca")
    assert [c.name for c in paper.ready(plan, [enn_data])] == ["main/enn/bca/seed1"]
    seed2 = tmp_path / "main/enn/bca/seed2"
    (seed2 / "eval").mkdir(parents=True)
    (seed2 / "eval" / "metrics.json").write_text(json.dumps({**summary(90, 60), "per_episode": []}))
    (seed2 / paper.CELL_FILE).write_text("{}")
    assert paper.best_enn_run(plan, "bca") == tmp_path / "main/enn/bca/seed2"
    assert paper.ready(plan, [enn_data]) == [enn_data]
    assert f"policy={seed2}" in paper.command(plan, enn_data)


def test_a_protocol_curve_from_the_record_alone_draws_its_return_when_kept(paper, tmp_path):
    plan = paper.build_plan(tmp_path, "tiny", record=tmp_path / "results.json")
    curve = [{"step": step, "success_rate": 0.0, "mean_episode_length": 300.0} for step in (10, 20)]
    _record(plan.record, {"protocol/pixels/bca/seed0": {"evaluations": curve}})  # kept no return
    caption = paper.curves_figure(plan, tmp_path / "old.png")
    assert "1 curves drawn" in caption and "mean return" not in caption
    _record(plan.record, {"protocol/pixels/bca/seed0": {"evaluations": [dict(e, mean_return=-50.0) for e in curve]}})
    caption = paper.curves_figure(plan, tmp_path / "new.png")
    assert "1 curves drawn" in caption and "mean return" in caption


def test_an_unfinished_protocol_cell_shows_its_curve_so_far(paper, tmp_path):
    plan = paper.build_plan(tmp_path, "tiny", record=tmp_path / "results.json")
    folder = tmp_path / "protocol/internal/lcca/seed0"
    folder.mkdir(parents=True)
    (folder / "evaluations.jsonl").write_text(
        json.dumps({"step": 10, "success_rate": 0.0, "mean_return": -40.0, "mean_episode_length": 300.0}) + "\n"
    )
    row = next(line for line in paper.protocol_table(plan).splitlines() if "| Internal | LCCA |" in line)
    assert row.startswith("| Internal | LCCA | 10 | 0 | unfinished |")
    assert paper.state(plan, plan.by_name("protocol/internal/lcca/seed0")) == "partial"


def test_bad_input_is_one_line_and_exit_2(repo_root, tmp_path):
    root = tmp_path / "root"
    root.mkdir()
    (root / "plan.json").write_text(json.dumps({"budget": "tiny"}))
    for args, expected in (
        (["run", "--budget", "full"], "--budget tiny"),
        (["run", "--only", "mian/enn"], "mian/enn"),
        (["run", "--jobs", "0"], "--jobs 0"),
        (["run", "--launcher", "slurmm"], "--launcher slurmm: choose one of joblib, submitit_slurm"),
        (["run", "--launcher", "submitit_slurm", "--jobs", "2"], "--jobs 2: only with --launcher joblib"),
        (["run", "trainer.device=cuda"], "trainer.device=cuda: give launcher options as hydra.launcher."),
        (["plan", "--only", "main/enn", "hydra.launcher=x"], "hydra.launcher=x"),
    ):
        result = _script(repo_root, "--root", str(root), *args)
        assert result.returncode == 2, result.stderr
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and expected in lines[0], result.stderr
    assert sorted(p.name for p in root.iterdir()) == ["plan.json"]  # nothing was run


def _wait_for(path, process, timeout_s=300):
    start = time.time()
    while not path.is_file():
        assert process.poll() is None, "the run ended before its first checkpoint"
        assert time.time() - start < timeout_s
        time.sleep(0.05)


def test_a_killed_cell_resumes_a_finished_one_is_skipped_and_the_tables_follow(paper, repo_root, tmp_path):
    cell = "main/internal/bca/seed0"
    folder = tmp_path / cell
    run = [
        sys.executable,
        str(repo_root / "scripts" / "paper_tables.py"),
        "--root",
        str(tmp_path),
        "run",
        "--budget",
        "tiny",
        "--only",
        cell,
    ]
    # Killed (the whole process group, as a machine that stops) after its first checkpoint.
    process = subprocess.Popen(run, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    _wait_for(folder / "checkpoints" / "last.zip", process)
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    assert not (folder / paper.CELL_FILE).exists()
    listing = _script(repo_root, "--root", str(tmp_path), "plan", "--only", cell).stdout
    assert re.search(rf"^{cell}\s+train\s+partial", listing, re.M), listing
    assert f"resume={folder} " in listing and "hydra.sweep.subdir=${resume}" in listing  # what `run` launches
    # An unfinished seed's curve is not drawn: it would stop short of the finished ones.
    assert (folder / "evaluations.jsonl").read_text().strip()
    doc = tmp_path / "paper.md"
    assert _script(repo_root, "--root", str(tmp_path), "report", "--out", str(doc)).returncode == 0
    assert "0 curves drawn" in doc.read_text()

    result = subprocess.run(run, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    assert f"[{cell}] finished in " in result.stdout
    attempts = [json.loads(line) for line in (folder / "attempts.jsonl").read_text().splitlines()]
    assert len(attempts) == 2 and f"resume={folder}" in attempts[1]["command"]
    assert not any(a.startswith("resume=") for a in attempts[0]["command"])
    info = json.loads((folder / paper.CELL_FILE).read_text())
    assert info["attempts"] == 2 and info["budget"] == "tiny" and info["command"].startswith("cathsim-train resume=")
    assert info["commit"] == attempts[1]["commit"] and 0 < info["seconds"] < 600
    assert json.loads((folder / "evaluations.jsonl").read_text().splitlines()[-1])["step"] == 20
    assert len(list((tmp_path / "multirun").iterdir())) == 2  # each launch's multirun.yaml

    again = subprocess.run(run, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0 and cell not in again.stdout and "cathsim-train" not in again.stdout
    assert json.loads((folder / paper.CELL_FILE).read_text()) == info

    # The tables: the finished cell fills its row from its final report; the rest say "not run".
    doc.write_text("# Intro kept\n\n<!-- paper_tables:main -->\nold\n<!-- /paper_tables:main -->\n\nOutro kept\n")
    result = _script(repo_root, "--root", str(tmp_path), "report", "--out", str(doc))
    assert result.returncode == 0, result.stderr
    text = doc.read_text()
    assert text.startswith("# Intro kept\n") and text.rstrip().endswith("Outro kept") and "\nold\n" not in text
    rows = [line for line in text.splitlines() if line.startswith("| ")]
    internal = next(r for r in rows if r.startswith("| Internal | BCA |"))
    report = json.loads((folder / "eval" / "metrics.json").read_text())
    success = report["summary"]["success_pct"]["mean"]
    assert "| 1 | " in internal and f"| {success:.0f} ± " in internal and internal.endswith("| 97 / 80 |")
    assert next(r for r in rows if r.startswith("| ENN | LCCA |")).count("not run") == 6
    assert "1 of 30 cells finished" in text and info["commit"] in text
    assert (tmp_path / "paper_learning_curves.png").stat().st_size > 0
    assert _script(repo_root, "--root", str(tmp_path), "report", "--out", str(tmp_path / "full.md")).returncode == 0
    assert "1 curves drawn" in (tmp_path / "full.md").read_text()

    # A cell finished while ties kept the earlier checkpoint: `reselect` breaks its tie and
    # scores it again, keeping the training's commit and cost.
    lines = (folder / "evaluations.jsonl").read_text().splitlines()
    tied = [dict(json.loads(line), success_rate=1.0, mean_return=float(i)) for i, line in enumerate(lines)]
    (folder / "evaluations.jsonl").write_text("".join(json.dumps(e) + "\n" for e in tied))
    best = json.loads((folder / "checkpoints" / "best.json").read_text())
    assert "tie_break" not in best
    demonstrations = (folder / "train.log").read_text().count("] - demonstrations: ")
    assert demonstrations >= 1
    result = _script(repo_root, "--root", str(tmp_path), "reselect")
    assert result.returncode == 0 and f"[{cell}] best.zip chosen again" in result.stdout, result.stdout
    reselected = json.loads((folder / paper.CELL_FILE).read_text())
    assert {k: v for k, v in reselected.items() if k != "selected"} == info
    assert (folder / "train.log").read_text().count("] - demonstrations: ") == demonstrations  # none recorded again
    assert json.loads((folder / "checkpoints" / "best.json").read_text())["tie_break"]["after_step"] == 20
    assert json.loads((tmp_path / "results.json").read_text())[cell]["info"] == reselected
    info = reselected
    assert _script(repo_root, "--root", str(tmp_path), "report", "--out", str(doc)).returncode == 0
    text = doc.read_text()
    assert f"chosen again on more episodes at {info['selected']['commit']}" in text

    # The record outlives the run folder: a new machine with the record alone skips the cell
    # and writes the same row.
    recorded = json.loads((tmp_path / "results.json").read_text())
    assert list(recorded) == [cell] and recorded[cell]["info"] == info
    shutil.rmtree(tmp_path / "main")
    again = subprocess.run(run, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0 and cell not in again.stdout and not folder.exists()
    assert _script(repo_root, "--root", str(tmp_path), "report", "--out", str(doc)).returncode == 0
    assert doc.read_text() == text


@pytest.mark.slow
def test_the_whole_plan_runs_on_a_tiny_budget(paper, repo_root, tmp_path):
    result = _script(repo_root, "--root", str(tmp_path), "run", "--budget", "tiny", "--jobs", "2")
    assert result.returncode == 0, result.stdout + result.stderr
    plan = paper.open_plan(tmp_path, None)
    assert all(plan.done(c) for c in plan.cells)
    # The ENN-agent dataset comes from the ENN seed that scored best (a dataset names its
    # policy by the run folder's name).
    manifest = json.loads((tmp_path / "imitation/data/enn_bca/manifest.json").read_text())
    assert manifest["policy"] == paper.best_enn_run(plan, "bca").name
    out = tmp_path / "paper.md"
    assert _script(repo_root, "--root", str(tmp_path), "report", "--out", str(out)).returncode == 0
    text = out.read_text()
    assert "not run" not in text
    assert "30 of 30 cells finished" in text and "Paper: force network" in text
    assert "No human data was recorded" in text
