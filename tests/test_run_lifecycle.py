"""A run's life on the command line: evaluating a run folder scores what its report scored,
run folders are unique and held by one process, the default cadence leaves a checkpoint to
resume from, and Ctrl-C keeps what was complete (exit status 130, one line, no traceback)."""

import json
import os
import signal
import subprocess
import sys
import time
import zipfile

import numpy as np
import pytest

from cathsim_dmc.app.cli.train import explicit_algo

# A tiny training run; trainer.checkpoint_every is left at its default (with every evaluation).
TINY = [
    "obs=internal",
    "demos=none",
    "task.max_steps=20",
    "algo.learning_starts=20",
    "algo.batch_size=16",
    "algo.buffer_size=2000",
    "algo.net_arch=[32,32]",
    "trainer.eval_every=20",
    "trainer.eval_episodes=1",
    "trainer.final_eval_episodes=2",
    "trainer.video=false",
    "trainer.progress_bar=false",
]


def _tool(name):
    return [sys.executable, "-m", f"cathsim_dmc.app.cli.{name}"]


# Runs a module with SIGINT back at its default first: a suite started in the background by
# a non-interactive shell inherits SIGINT ignored, and Python keeps an ignored SIGINT, so
# Ctrl-C would never reach the tool under test.
_WITH_CTRL_C = (
    "import runpy, signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
    "sys.argv = sys.argv[1:]; runpy.run_module(sys.argv[0], run_name='__main__', alter_sys=True)"
)


_STARTED = []


@pytest.fixture(autouse=True)
def _no_process_outlives_its_test():
    yield
    while _STARTED:  # a failed assertion must not leave a 5,000-episode run behind
        process = _STARTED.pop()
        if process.poll() is None:
            process.kill()
            process.wait()


def _start(name, args, cwd, log):
    """The tool as a process, its stdout and stderr in files (a pipe nobody reads could block it)."""
    process = subprocess.Popen(
        [sys.executable, "-c", _WITH_CTRL_C, f"cathsim_dmc.app.cli.{name}", *args],
        cwd=cwd,
        stdout=open(f"{log}.out", "w"),
        stderr=open(f"{log}.err", "w"),
    )
    _STARTED.append(process)
    return process


def _wait_for(condition, timeout=600):
    deadline = time.time() + timeout
    while not condition():
        assert time.time() < deadline, "timed out"
        time.sleep(0.2)


def _step(checkpoint) -> int:
    with zipfile.ZipFile(checkpoint) as archive:
        return json.loads(archive.read("data"))["num_timesteps"]


def _log(run) -> str:
    """Hydra's log file of a run folder."""
    return "".join(path.read_text() for path in run.glob("*.log"))


def _assert_interrupted(process, log, timeout=600):
    process.wait(timeout=timeout)
    stderr = open(f"{log}.err").read()
    assert process.returncode == 130, stderr[-2000:]
    assert "Traceback" not in stderr
    lines = [line for line in stderr.splitlines() if line.startswith("interrupted:")]
    assert len(lines) == 1, stderr[-2000:]
    return lines[0]


def test_a_run_folder_evaluates_its_best_checkpoint_with_the_numbers_of_its_report(tmp_path):
    run = tmp_path / "run"
    trained = subprocess.run(
        [*_tool("train"), *TINY, "trainer.total_timesteps=60", f"hydra.run.dir={run}"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert trained.returncode == 0, trained.stderr[-2000:]
    assert (run / "checkpoints" / "best.zip").is_file()
    assert "recipe: algo=sac_tuned: batch_size 16" in _log(run)
    # The default cadence: a checkpoint with every periodic evaluation.
    assert {"step_20.zip", "step_40.zip", "step_60.zip"} <= {p.name for p in (run / "checkpoints").iterdir()}

    evaluated = subprocess.run(
        [
            *_tool("eval"),
            f"policy={run}",
            "episodes=2",
            "seed=10000",
            "task.max_steps=20",
            "video=false",
            f"hydra.run.dir={tmp_path}/eval",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert evaluated.returncode == 0, evaluated.stderr[-2000:]
    assert f"evaluating {run / 'checkpoints' / 'best.zip'}" in evaluated.stdout.splitlines()
    report = json.loads((run / "eval" / "metrics.json").read_text())
    again = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert again["summary"] == report["summary"] and again["per_episode"] == report["per_episode"]


def test_a_second_run_into_a_held_folder_is_refused_and_ctrl_c_keeps_the_finished_episodes(tmp_path):
    out = tmp_path / "out"
    first = _start(
        "eval",
        ["policy=expert", "episodes=5000", "task.max_steps=20", "video=false", f"hydra.run.dir={out}"],
        tmp_path,
        tmp_path / "first",
    )
    _wait_for(lambda: (out / ".lock").is_file())
    second = subprocess.run(
        [*_tool("eval"), "policy=forward", "episodes=1", "task.max_steps=5", "video=false", f"hydra.run.dir={out}"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert second.returncode == 2 and "Traceback" not in second.stderr
    assert second.stderr.strip().count("\n") == 0 and "in use by another run" in second.stderr

    # Ctrl-C once the first has finished two episodes (it logs each one); 5000 episodes are
    # far more than it can finish meanwhile, however loaded the machine.
    _wait_for(lambda: "episode 1:" in open(tmp_path / "first.out").read())
    first.send_signal(signal.SIGINT)
    line = _assert_interrupted(first, tmp_path / "first")
    report = json.loads((out / "metrics.json").read_text())
    finished = len(report["per_episode"])
    assert f"after {finished} of 5000 episodes" in line and 2 <= finished < 5000
    assert report["partial"] is True and report["episodes_requested"] == 5000 and report["policy"] == "expert"
    assert f"[partial: {finished} of 5000 episodes]" in (out / "metrics.md").read_text()
    with np.load(out / "trajectories.npz") as trajectories:
        assert (
            set(trajectories["episode"]) == set(range(finished))
            and len(trajectories["start_tip_position_m"]) == finished
        )
        assert str(trajectories["policy"]) == "expert"
    assert not (out / ".lock").exists()


def test_default_run_folders_of_runs_started_together_differ(tmp_path):
    args = ["policy=forward", "episodes=1", "task.max_steps=2", "video=false"]
    processes = [_start("eval", args, tmp_path, tmp_path / f"run{i}") for i in range(2)]
    for process in processes:
        assert process.wait(timeout=600) == 0
    folders = sorted((tmp_path / "outputs" / "eval" / "bca-type1").iterdir())
    # Named to the microsecond and after the process: two runs never share one.
    assert sorted(int(f.name.rsplit("_", 1)[1]) for f in folders) == sorted(p.pid for p in processes)
    assert all((f / "metrics.json").is_file() for f in folders)


def test_ctrl_c_stops_training_with_a_checkpoint_and_shows_each_stage(tmp_path):
    run = tmp_path / "run"
    args = [
        *TINY,
        "demos=expert",
        "demos.episodes=1",
        "demos.pretrain_actor_steps=5",
        "demos.critic_warmup_steps=5",
        "trainer.progress_bar=true",
        "trainer.total_timesteps=100000",
        f"hydra.run.dir={run}",
    ]
    process = _start("train", args, tmp_path, tmp_path / "train")
    last = run / "checkpoints" / "last.zip"
    _wait_for(lambda: last.is_file())
    process.send_signal(signal.SIGINT)
    line = _assert_interrupted(process, tmp_path / "train")
    step = _step(last)
    assert step > 20 and f"checkpoint at step {step} of 100000 kept" in line and f"resume={run}" in line
    stderr = open(tmp_path / "train.err").read()
    for stage in ("recording demonstrations", "pre-training the actor", "warming up the critic", "training"):
        assert f"{stage}:" in stderr, stage


@pytest.mark.slow
def test_the_default_cadence_resumes_a_run_killed_at_a_random_step(tmp_path):
    run = tmp_path / "run"
    process = _start(
        "train", [*TINY, "trainer.total_timesteps=100", f"hydra.run.dir={run}"], tmp_path, tmp_path / "killed"
    )
    _wait_for(lambda: (run / "checkpoints" / "last.zip").is_file())
    time.sleep(np.random.default_rng().uniform(0.0, 3.0))
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    step = _step(run / "checkpoints" / "last.zip")
    assert step < 100, "finished before the kill"
    # resume= continues in the run's own folder, past the killed run's stale lock.
    resumed = subprocess.run(
        [*_tool("train"), f"resume={run}"], cwd=tmp_path, capture_output=True, text=True, timeout=900
    )
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert _step(run / "final_model.zip") == 100
    assert f"resuming from step {step} of 100" in _log(run)
    assert not (tmp_path / "outputs").exists()


def test_an_image_preset_takes_its_measured_recipe_unless_algo_is_given():
    from hydra import compose, initialize_config_dir

    from cathsim_dmc.app.tool_schemas import register_schemas
    from cathsim_dmc.core.shipped import conf_root

    register_schemas()
    with initialize_config_dir(config_dir=str(conf_root()), version_base="1.3"):

        def algo(*overrides):
            cfg = compose("train", overrides=explicit_algo(list(overrides)))
            return cfg.algo.name, cfg.algo.batch_size, cfg.algo.share_features_extractor

        assert algo() == algo("obs=internal") == ("sac_tuned", 256, False)
        for preset in ("enn", "pixels", "pixels_mask", "internal_pixels"):
            assert algo(f"obs={preset}") == ("sac_tuned", 64, True), preset
        assert algo("obs=enn", "algo=sac_tuned") == ("sac_tuned", 256, False)
        assert algo("obs=enn", "algo=sac") == ("sac", 256, False)
        assert algo("obs=enn", "algo.batch_size=32") == ("sac_tuned", 32, True)


def test_ctrl_c_stops_a_collection_keeping_its_finished_shards(tmp_path):
    out = tmp_path / "data"
    process = _start(
        "collect",
        [
            "episodes=5000",
            "episodes_per_shard=1",
            "task.max_steps=10",
            "progress_bar=false",
            f"out={out}",
            f"hydra.run.dir={tmp_path}/run",
        ],
        tmp_path,
        tmp_path / "collect",
    )
    _wait_for(lambda: len(list(out.glob("shard_*.npz"))) >= 2)
    process.send_signal(signal.SIGINT)
    line = _assert_interrupted(process, tmp_path / "collect")
    kept = json.loads((out / "manifest.json").read_text())["episodes"]
    assert 2 <= kept < 5000 and f"{kept} finished episodes kept in {out}" in line
    # (a shard written just before the manifest was updated is complete, and counted by a continuation)
    assert kept <= len(list(out.glob("shard_*.npz"))) <= kept + 1
