"""scripts/generalisation.py: the sweeps it hands to Hydra (what to start, resume or skip),
a real evaluation multirun whose scores land in their places, and the table writer: seeds
grouped by their median, success by arch type."""

import itertools
import json
import subprocess
import sys

from conftest import load_script


def _write(folder, successes, aortas, force=0.2, length=100, safe=None):
    """A cathsim-eval report; `safe` (safe successes) left out: one from before safe success."""
    folder.mkdir(parents=True)
    rate = 100.0 * sum(successes) / len(successes)
    summary = {
        "success_pct": {"mean": rate},
        **({"safe_success_pct": {"mean": 100.0 * sum(safe) / len(safe)}} if safe is not None else {}),
        "spl_pct": {"mean": rate / 2},
        "force_n": {"mean": force},
        "episode_length": {"mean": length},
    }
    episodes = [{"episode": i, "success": s, "aorta": a} for i, (s, a) in enumerate(zip(successes, aortas))]
    (folder / "metrics.json").write_text(json.dumps({"summary": summary, "episodes": episodes}))


def test_the_report_gives_the_median_of_the_seeds_and_success_by_arch_type_and_variant(tmp_path, repo_root):
    script = load_script(repo_root / "scripts" / "generalisation.py")
    aortas = ["a", "b", "c", "d"]
    types = {"a": "I", "b": "II", "c": "III", "d": "III"}
    scores = tmp_path / "scores" / "bca"
    _write(scores / "navigator_seed0_best" / "heldout", [True, True, True, False], aortas, safe=[1, 0, 0, 0])
    _write(scores / "navigator_seed1_best" / "heldout", [True, True, False, False], aortas, safe=[1, 1, 0, 0])
    _write(scores / "navigator_seed2_best" / "heldout", [True, True, True, True], aortas, safe=[1, 1, 1, 1])
    _write(scores / "navigator_seed0_last" / "heldout", [False, False, False, False], aortas)
    _write(scores / "navigator_seed0_best" / "heldout_noise", [True, False, True, False], aortas)
    _write(scores / "navigator_seed1_best" / "heldout_ap", [True, True, True, True], aortas)
    _write(scores / "navigator_seed2_best" / "heldout_lao40", [True, True, True, False], aortas)
    _write(scores / "expert" / "heldout", [True, True, True, True], aortas)
    _write(scores / "expert" / "type2", [True, False], ["type2", "type2"])
    variants = {"a": "separate", "b": "close ostia", "c": "bovine", "d": "bovine"}
    text = script.report(tmp_path, tmp_path / "table.md", arch_types=types, variants=variants)
    heldout, shipped_table = text.split("Success % on the shipped aortas")
    rows = {line.split(" | ")[0].strip("| "): line for line in heldout.splitlines() if line.startswith("| ")}
    best = rows["navigator, best.zip"].split(" | ")
    assert best[1] == "3"  # seeds
    assert best[2] == "75 (75, 50, 100)"  # median success, then each seed's
    assert best[3] == "50 (25, 50, 100)"  # safe success
    all_reached, half = "100 (100, 100, 100)", "50 (50, 0, 100)"
    assert best[7:10] == [all_reached, all_reached, half]  # by arch type
    assert best[10:13] == [all_reached, all_reached, half]  # by variant
    # with noise: seed 0; in the AP view: seed 1; in LAO 40: seed 2; none from the frame
    assert best[13:] == ["50", "100", "75", "- |"]
    assert rows["navigator, last.zip"].split(" | ")[2] == "0"
    assert rows["expert"].split(" | ")[3] == "-"  # a report from before safe success
    # The shipped-aorta table: a row per anatomy, a column only for the policies scored there
    # (the expert's 1 of 2 on type II), and a dash where nothing was scored.
    lines = [line for line in shipped_table.splitlines() if line.startswith("| ")]
    assert lines[0] == "| anatomy | BCA: expert |"
    rows = {line.split(" | ")[0].strip("| "): line.split(" | ")[1].strip("| ") for line in lines[1:]}
    assert rows["type2"] == "50" and rows["type1"] == "-" and rows["corpus: noisy"] == "-"
    assert (tmp_path / "table.md").read_text() == text


def _script(repo_root, *args):
    return subprocess.run(
        [sys.executable, str(repo_root / "scripts" / "generalisation.py"), *args],
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_train_sweeps_the_runs_to_start_resumes_the_killed_and_skips_the_finished(tmp_path, repo_root):
    from hydra import compose, initialize_config_dir

    from cathsim_dmc.core.shipped import conf_root

    script = load_script(repo_root / "scripts" / "generalisation.py")
    runs = tmp_path / "runs"
    (runs / "bca" / "seed1" / "eval").mkdir(parents=True)
    (runs / "bca" / "seed1" / "eval" / "metrics.json").write_text(json.dumps({"summary": {}}))
    (runs / "lcca" / "seed1" / "eval").mkdir(parents=True)  # a Ctrl-C's report: not finished
    (runs / "lcca" / "seed1" / "eval" / "metrics.json").write_text(json.dumps({"summary": {}, "partial": True}))
    (runs / "lcca" / "seed0" / "checkpoints").mkdir(parents=True)
    (runs / "lcca" / "seed0" / "checkpoints" / "last.zip").write_bytes(b"")
    launches = script.train_launches(tmp_path, ["bca", "lcca"], [0, 1], False, ["obs=roadmap_timed"])
    assert launches[0] == ([], {"resume": [str(runs / "lcca" / "seed0")]}, "${resume}")
    fixed = launches[1][0]
    assert sorted((t, s) for _, sweep, _ in launches[1:] for t in sweep["task"] for s in sweep["seed"]) == [
        ("bca", 0),
        ("lcca", 1),
    ]
    assert fixed[:3] == ["+experiment=navigator", "trainer.progress_bar=false", "trainer.video=false"]
    with initialize_config_dir(config_dir=str(conf_root()), version_base=None):
        for fixed, sweep, subdir in launches[1:]:
            values = [f"{k}={v[0]}" for k, v in sweep.items()]
            cfg = compose("train", [*fixed, *values, f"hydra.sweep.subdir={subdir}"], return_hydra_config=True)
            assert cfg.obs.name == "roadmap_timed" and cfg.aorta.name == "random"  # the navigator recipe
            assert cfg.hydra.sweep.subdir == str(script.run_folder(tmp_path, cfg.task.target, cfg.seed, False))
        fixed, sweep, subdir = script.train_launches(tmp_path, ["bca"], [0], True, [])[0]
        cfg = compose("train", [*fixed, "task=bca", "seed=0", f"hydra.sweep.subdir={subdir}"], return_hydra_config=True)
        assert cfg.aorta.name == "type1" and cfg.hydra.sweep.subdir == str(runs / "bca" / "type1")


def test_evaluate_sweeps_each_anatomy_over_the_policies_without_a_score(tmp_path, repo_root):
    from hydra import compose, initialize_config_dir

    from cathsim_dmc.agents.trained import load_pretrained
    from cathsim_dmc.core.shipped import conf_root

    script = load_script(repo_root / "scripts" / "generalisation.py")
    _write(tmp_path / "scores" / "bca" / "expert" / "type2", [True], ["type2"])  # scored already
    anatomies = ["heldout", "heldout_noise", "heldout_ap", "heldout_lao40", "heldout_fluoro_image", "type1", "type2"]
    jobs = script.evaluation_jobs(tmp_path, "bca", 7, 3, None, False, anatomies)
    scored = set()
    with initialize_config_dir(config_dir=str(conf_root()), version_base=None):
        for fixed, sweep in jobs:
            for values in itertools.product(*sweep.values()):
                overrides = [*fixed, *[f"{k}={v}" for k, v in zip(sweep, values)]]
                cfg = compose("eval", overrides)
                job = dict(o.split("=", 1) for o in overrides)
                scored.add((job["policy"], script.anatomy_of(job)))
                pool = job.get("aorta") == "random"
                assert cfg.episodes == (7 if pool else 3) and cfg.seed == script.EVAL_SEED and not cfg.video
                if pool:
                    assert (cfg.aorta.params.pool_size, cfg.aorta.params.pool_seed) == (100, "heldout")
                    assert cfg.aorta.params.distribution == "morphometry"
                noisy = script.anatomy_of(job) == "heldout_noise"
                assert cfg.obs.get("tracking_noise_m", 0.0) == (0.001 if noisy else 0.0)
                fixed_view_deg = {"heldout_ap": 0, "heldout_lao40": 40}.get(script.anatomy_of(job))
                if fixed_view_deg is not None:  # one fixed view, nothing drawn
                    assert cfg.obs.view_deg_range is None and cfg.obs.cranial_deg_range is None
                    assert cfg.obs.lao_deg == fixed_view_deg
                # a trained agent brings its own observations, named where their noise is set
                own = script.anatomy_of(job) in ("heldout_noise", "heldout_ap", "heldout_lao40", "heldout_fluoro_image")
                assert ("obs" in job) == (job["policy"] == "expert" or own)
                # the expert drives the catheter the navigator recipe trains with
                assert cfg.task.catheter == ("angled_5f" if job["policy"] == "expert" else None)
    # The expert has no roadmap to be noisy; the shipped navigator has. Neither sees the C-arm.
    c_arm = ("heldout_ap", "heldout_lao40", "heldout_fluoro_image")
    expected = {("expert", a) for a in anatomies if a not in ("type2", "heldout_noise", *c_arm)}
    expected |= {("pretrained", a) for a in anatomies if a not in c_arm}
    # It sees the C-arm and tracks in the image; trained on the wire found in the frame, it reads
    # that everywhere, so the held-out pool with the found wire is the held-out pool itself.
    found_wire = {
        task: load_pretrained(task, kind="pretrained_fluoro").image_options.get("tracking_source") == "fluoro_image"
        for task in ("bca", "lcca")
    }
    expected |= {("pretrained_fluoro", a) for a in anatomies if not (found_wire["bca"] and a == "heldout_fluoro_image")}
    assert scored == expected
    # the shipped aortas: one sweep per policy (the expert's with obs=roadmap)
    assert len(jobs) == 9 - found_wire["bca"]
    for task in ("bca", "lcca"):
        jobs = script.evaluation_jobs(tmp_path, task, 7, 3, ["pretrained_fluoro"], False, ["heldout_fluoro_image"])
        assert len(jobs) == (0 if found_wire[task] else 1)
    corpus = {"aorta": "folder", "aorta.name": str(tmp_path / "corpus" / "pinched"), "aorta.label": "corpus"}
    assert script.anatomy_of(corpus) == "corpus_pinched"
    assert script.anatomy_of({"aorta": "random", "aorta.params.pool_seed": "tuning"}) == "tuning"
    ap = dict(o.split("=", 1) for o in script.anatomy_overrides(tmp_path, 7, 3, ["heldout_ap"])["heldout_ap"][0])
    assert script.anatomy_of(ap) == "heldout_ap" and ap["obs.view_deg_range"] == "null"
    lao = dict(o.split("=", 1) for o in script.anatomy_overrides(tmp_path, 7, 3, ["heldout_lao40"])["heldout_lao40"][0])
    assert script.anatomy_of(lao) == "heldout_lao40" and lao["obs.lao_deg"] == "40"
    frame = script.anatomy_overrides(tmp_path, 7, 3, ["heldout_fluoro_image"])["heldout_fluoro_image"][0]
    frame = dict(o.split("=", 1) for o in frame)
    assert script.anatomy_of(frame) == "heldout_fluoro_image" and frame["obs.tracking_source"] == "fluoro_image"


def test_evaluate_runs_a_multirun_and_files_each_score_in_its_place(tmp_path, repo_root):
    result = _script(
        repo_root,
        "--root",
        str(tmp_path),
        "evaluate",
        "--only",
        "expert",
        "--anatomies",
        "type1",
        "type2",
        "--shipped-episodes",
        "1",
        "--jobs",
        "2",
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "cathsim-eval -m hydra/launcher=joblib hydra.launcher.n_jobs=2" in result.stdout
    assert "aorta=type1,type2" in result.stdout
    for anatomy in ("type1", "type2"):
        report = json.loads((tmp_path / "scores" / "bca" / "expert" / anatomy / "metrics.json").read_text())
        assert report["aorta"] == anatomy and len(report["per_episode"]) == 1
    assert not (tmp_path / "multirun").exists() or not any((tmp_path / "multirun").iterdir())
    again = _script(repo_root, "--root", str(tmp_path), "evaluate", "--only", "expert", "--anatomies", "type1")
    assert again.returncode == 0 and "cathsim-eval" not in again.stdout  # scored already
    text = load_script(repo_root / "scripts" / "generalisation.py").report(tmp_path, None)
    assert "| anatomy | BCA: expert |" in text


def test_bad_input_is_one_line_and_exit_2(tmp_path, repo_root):
    for args, expected in (
        (["train", "--specialist", "--seed", "0", "1"], "--seed 0 1: the specialist is one run per task"),
        (["train", "--launcher", "slurmm"], "--launcher slurmm: choose one of"),
        (["evaluate", "--jobs", "0"], "--jobs 0: give 1 or more"),
        (["evaluate", "trainer.device=cuda"], "trainer.device=cuda"),
        (["ship", "--seed", "2"], "give --seed and --why together"),
        (["ship", "--seed", "2", "--why", "best"], "--seed 2: no finished run of bca seed 2"),
    ):
        result = _script(repo_root, "--root", str(tmp_path), *args)
        assert result.returncode == 2, result.stdout + result.stderr
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and expected in lines[0], result.stderr
    assert not any(tmp_path.iterdir())  # nothing was run


def test_ship_fluoro_refuses_a_run_that_reads_more_than_a_c_arm_shows(tmp_path, repo_root):
    run = tmp_path / "runs" / "lcca" / "seed0"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "best.json").write_text(json.dumps({"step": 10, "success_rate": 0.5}))
    (run / "config.yaml").write_text("obs:\n  name: roadmap_memory_carriage\n")
    shipped = sorted((repo_root / "assets" / "policies").iterdir())
    stamps = [p.stat().st_mtime_ns for p in shipped]
    result = _script(
        repo_root, "--root", str(tmp_path), "ship", "--task", "lcca", "--seed", "0", "--why", "x", "--fluoro"
    )
    assert result.returncode == 2, result.stdout + result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "reads obs=roadmap_memory_carriage, which a C-arm does not give" in lines[0]
    assert "catheter_called" in lines[0] and "roadmap," in lines[0]  # names what the C-arm lacks
    assert sorted((repo_root / "assets" / "policies").iterdir()) == shipped
    assert [p.stat().st_mtime_ns for p in shipped] == stamps  # nothing exported


def test_the_variant_of_an_arch_is_bovine_then_close_ostia_then_separate(repo_root):
    script = load_script(repo_root / "scripts" / "generalisation.py")
    apart = {"bovine": False, "bca_lcca_gap_m": 0.004, "lcca_lsa_gap_m": 0.006}
    assert script.variant_of(apart) == "separate"
    assert script.variant_of({**apart, "lcca_lsa_gap_m": 0.0015}) == "close ostia"
    assert script.variant_of({**apart, "bca_lcca_gap_m": 0.0}) == "close ostia"
    assert script.variant_of({**apart, "bca_lcca_gap_m": 0.0, "bovine": True}) == "bovine"


def test_curves_draw_the_median_and_spread_of_the_seeds_and_refuse_without_runs(tmp_path, repo_root):
    from cathsim_dmc.evaluation.plots import seed_spread

    script = load_script(repo_root / "scripts" / "generalisation.py")
    successes = {0: [0.5, 0.9, 1.0], 1: [0.7, 0.6, 0.8], 2: [0.9, 1.0]}  # seed 2 stopped before step 4,000
    for seed, rates in successes.items():
        run = tmp_path / "runs" / "bca" / f"seed{seed}"
        run.mkdir(parents=True)
        lines = [json.dumps({"step": 2000 * i, "success_rate": r}) for i, r in enumerate(rates)]
        (run / "evaluations.jsonl").write_text("\n".join(lines) + "\n")
    seeds = [
        [json.loads(line) for line in (tmp_path / "runs" / "bca" / f"seed{s}" / "evaluations.jsonl").open()]
        for s in successes
    ]
    steps, median, low, high = seed_spread(seeds)
    assert steps.tolist() == [0, 2000, 4000]
    assert median.tolist() == [0.7, 0.9, 0.9] and low.tolist() == [0.5, 0.6, 0.8] and high.tolist() == [0.9, 1.0, 1.0]
    out = script.curves(tmp_path, tmp_path / "curves.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    empty = subprocess.run(
        [sys.executable, str(repo_root / "scripts" / "generalisation.py"), "--root", str(tmp_path / "none"), "curves"],
        capture_output=True,
        text=True,
    )
    assert empty.returncode == 2 and len(empty.stderr.strip().splitlines()) == 1 and "evaluations.jsonl" in empty.stderr
