"""cathsim-eval end to end (its bad-input cases are in test_bad_inputs.py)."""

import json
import subprocess
import sys

import imageio.v3 as iio
import numpy as np
import pytest

from cathsim_dmc.core import run_files
from cathsim_dmc.evaluation.trajectory import load_trajectories


def _run(args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "cathsim_dmc.app.cli.eval", *args], cwd=cwd, capture_output=True, text=True, timeout=600
    )


def test_eval_writes_trajectories_and_video(tmp_path):
    result = _run(
        [
            "task=lcca",
            "aorta=type1",
            "policy=forward",
            "episodes=1",
            "task.max_steps=12",
            f"hydra.run.dir={tmp_path}/run",
        ],
        tmp_path,
    )
    assert result.returncode == 0, result.stderr
    data = load_trajectories(tmp_path / "run" / "trajectories.npz")
    assert len(data["step"]) == 12 and data["truncated"][-1]
    assert np.all(data["action"][:, 0] == 1.0)
    # Full-speed insertion: the tip climbs the descending aorta.
    assert data["tip_position_m"][-1, 1] > data["start_tip_position_m"][0, 1] + 0.01
    gif = tmp_path / "run" / "video.gif"
    # The wire moves every step, so the GIF keeps (nearly) one frame per step.
    assert iio.improps(gif, index=None).n_images >= 10
    report = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert report["summary"]["episode_length"]["mean"] == 12 and report["summary"]["success_pct"]["mean"] == 0
    # Path length is the tip's travel, so at least its net climb.
    climb_cm = 100 * (data["tip_position_m"][-1, 1] - data["start_tip_position_m"][0, 1])
    assert report["summary"]["path_length_cm"]["mean"] >= climb_cm
    for name in ("metrics.md", "path.png", "forces.png"):
        assert (tmp_path / "run" / name).stat().st_size > 0
    # 12 steps climb the descending aorta: the report says the episode ended short of the target.
    (end,) = report["episode_ends"]
    assert end["ended"] == "short of the target" and end["other_branches"] == []
    assert end["end_along_vessel_mm"] > 100
    assert "Failed episodes: 1 of 1" in (tmp_path / "run" / "metrics.md").read_text()


def test_expert_reaches_the_lcca(tmp_path):
    result = _run(
        ["task=lcca", "aorta=type1", "policy=expert", "episodes=1", "video=false", f"hydra.run.dir={tmp_path}/run"],
        tmp_path,
    )
    assert result.returncode == 0, result.stderr
    report = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert report["summary"]["success_pct"]["mean"] == 100
    # SPL from the recorded tip path: the centerline length from the start over the path
    # travelled. The expert backs off and turns on the way, so it travels farther than
    # the centerline (docs/results.md: SPL 80 +- 10 on this case).
    data = load_trajectories(tmp_path / "run" / "trajectories.npz")
    tips = np.vstack([data["start_tip_position_m"][:1], data["tip_position_m"]])
    travelled_m = np.linalg.norm(np.diff(tips, axis=0), axis=1).sum()
    optimal_m = float(data["optimal_path_length_m"][0])
    assert 0.15 < optimal_m < travelled_m
    assert report["summary"]["spl_pct"]["mean"] == pytest.approx(100 * optimal_m / travelled_m, rel=1e-6)
    assert 50 < report["summary"]["spl_pct"]["mean"] < 100
    # Safe success: reached without any step's wall force (the step mean) above the task's 1.5 N.
    assert report["safe_force_n"] == 1.5 and float(data["safe_force_n"]) == 1.5
    safe = bool(np.all(data["mean_contact_force_n"] <= 1.5))
    assert report["summary"]["safe_success_pct"]["mean"] == (100 if safe else 0)
    assert "Safe Success (%)" in (tmp_path / "run" / "metrics.md").read_text()


def test_multirun_writes_one_combined_table(tmp_path):
    result = _run(
        [
            "-m",
            "task=bca,lcca",
            "aorta=type1",
            "policy=forward",
            "episodes=1",
            "task.max_steps=3",
            "video=false",
            f"hydra.sweep.dir={tmp_path}/sweep",
        ],
        tmp_path,
    )
    assert result.returncode == 0, result.stderr
    lines = (tmp_path / "sweep" / "metrics.md").read_text().strip().splitlines()
    assert len(lines) == 4 and lines[2].startswith("| BCA |") and lines[3].startswith("| LCCA |")


def test_corrupt_checkpoint_is_one_line_and_exit_2(tmp_path):
    run = tmp_path / "fake_run"
    run.mkdir()
    (run / run_files.POLICY_FILE).write_text(
        json.dumps({run_files.FORMAT_KEY: run_files.RUN_FORMAT, "algo": "sac", "obs": "internal"})
    )
    (run / "final_model.zip").write_bytes(b"not a zip file")
    result = _run([f"policy={run}", "episodes=1", f"hydra.run.dir={tmp_path}/out"], tmp_path)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "not a readable checkpoint" in lines[0]


def test_bench_prints_a_row_per_setting(tmp_path):
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "cathsim_dmc.app.cli.bench",
            "task=lcca",
            "aortas=[type1]",
            "presets=[internal]",
            "steps=5",
            "repeats=1",
            f"hydra.run.dir={tmp_path}/bench",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    rows = [line for line in result.stdout.splitlines() if line.startswith("| type1 | internal")]
    # One row per physics setting, side by side.
    assert [row.split("|")[5].strip() for row in rows] == ["fast", "fast_field"]
    assert all(float(row.split("|")[6]) > 0 for row in rows)


def _compose(config_name, overrides=()):
    from hydra import compose, initialize_config_dir

    from cathsim_dmc.core.shipped import conf_root

    with initialize_config_dir(config_dir=str(conf_root()), version_base="1.3"):
        return compose(config_name=config_name, overrides=list(overrides))


def test_one_function_turns_every_tools_config_into_environment_arguments():
    from cathsim_dmc.agents.trained import CheckpointPolicy
    from cathsim_dmc.app.cli._common import env_kwargs

    train = _compose(
        "train", ["obs=enn", "obs.style=fluoro", "task.max_steps=7", "experimental.extra_observations=[wire_slack]"]
    )
    scored = env_kwargs(train)
    assert scored == {
        "task": "bca",
        "aorta": "type1",
        "obs": "enn",
        "delta_m": 0.004,
        "success_reward": 10.0,
        "dense": True,
        "max_steps": 7,
        "physics": "fast",
        "renderer": "raster",
        "style": "fluoro",
        "extra_observations": ("wire_slack",),
    }
    # Only training uses the shaping reward: evaluation scores the paper's task.
    assert env_kwargs(train, training=True) == {**scored, "reward": "geodesic", "progress_weight": 1.0}
    # The obs group is untyped: its old `extra` key says where it went instead of being ignored.
    with pytest.raises(ValueError, match="experimental.extra_observations"):
        env_kwargs(_compose("eval", ["+obs.extra=[wire_slack]"]))
    # A checkpoint brings its own preset and options, whatever the tool's config says.
    policy = CheckpointPolicy(None, "internal", {"style": "camera"}, {"extra_observations": ["drive_force"]})
    assert env_kwargs(_compose("eval", ["obs=enn"]), policy=policy) == {
        "task": "bca",
        "aorta": "type1",
        "obs": "internal",
        "delta_m": 0.004,
        "success_reward": 10.0,
        "dense": True,
        "max_steps": 300,
        "physics": "fast",
        "renderer": "raster",
        "style": "camera",
        "extra_observations": ["drive_force"],
    }
    assert env_kwargs(_compose("eval", ["task.physics=accurate"]))["physics"] == "accurate"
    # ...and its solver settings: an agent trained under accurate is scored under accurate.
    trained_accurate = CheckpointPolicy(None, "internal", {}, {"physics": "accurate"})
    assert env_kwargs(_compose("eval"), policy=trained_accurate)["physics"] == "accurate"
    # Tools without an obs group (teleop, export) leave the preset to the environment.
    assert "obs" not in env_kwargs(_compose("teleop", ["aorta=type2"]))


def test_the_safe_success_threshold_is_a_task_option():
    from cathsim_dmc import tasks
    from cathsim_dmc.app.cli._common import env_kwargs

    assert "safe_force_n" not in env_kwargs(_compose("eval")), "the default is recorded as before the option existed"
    kwargs = env_kwargs(_compose("eval", ["task.safe_force_n=2.5"]))
    assert kwargs["safe_force_n"] == 2.5
    assert tasks.build_task("bca", "type1", safe_force_n=2.5).safe_force_n == 2.5
    assert tasks.build_task("bca", "type1").safe_force_n == 1.5
    with pytest.raises(ValueError, match=r"safe_force_n=0"):
        env_kwargs(_compose("eval", ["task.safe_force_n=0"]))


def test_an_asset_folder_is_an_aorta_and_names_the_run_and_the_table(tmp_path):
    import shutil

    from cathsim_dmc.core.shipped import resolve_asset

    folder = tmp_path / "my_phantom"
    shutil.copytree(resolve_asset("type1"), folder)
    result = _run(
        ["task=bca", f"aorta={folder}", "policy=forward", "episodes=1", "task.max_steps=3", "video=false"], tmp_path
    )
    assert result.returncode == 0, result.stderr
    runs = list((tmp_path / "outputs" / "eval").iterdir())
    assert [run.name for run in runs] == ["bca-my_phantom"]
    table = next(runs[0].iterdir()) / "metrics.md"
    assert "| BCA | my_phantom | forward |" in table.read_text()
    # The form it is rewritten to, which a sweep over folders needs (scripts/generalisation.py).
    result = _run(
        ["-m", "task=bca", "aorta=folder", f"aorta.name={folder}", "aorta.label=corpus", "policy=forward"]
        + ["episodes=1", "task.max_steps=3", "video=false"],
        tmp_path,
    )
    assert result.returncode == 0, result.stderr
    assert list((tmp_path / "multirun").rglob("metrics.md")), result.stdout


@pytest.mark.parametrize("value, reason", [("nowhere", "not a folder"), (".", "a folder without meta.json")])
def test_an_aorta_that_is_no_asset_folder_is_one_line_and_exit_2(tmp_path, value, reason):
    result = _run(["task=bca", f"aorta={value}", "policy=forward", "episodes=1"], tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and reason in lines[0] and "type1" in lines[0]


def test_resume_continues_in_the_run_folder_and_a_sweep_of_resumes_is_left_to_hydra():
    from cathsim_dmc.app.cli.train import resume_in_place

    assert resume_in_place(["resume=/r/a"]) == ["resume=/r/a", "hydra.run.dir=/r/a", "hydra.output_subdir=null"]
    assert resume_in_place(["resume=/r/a", "hydra.run.dir=/x"]) == ["resume=/r/a", "hydra.run.dir=/x"]
    # hydra.run.dir=/r/a,/r/b would be a sweep over Hydra's own config, which Hydra refuses.
    assert resume_in_place(["-m", "resume=/r/a,/r/b"]) == ["-m", "resume=/r/a,/r/b"]
