"""Checkpoints as one unit: model, replay buffer and step count written together, resumed
together, and a run killed at any point (inside any write) resumes from a matching pair."""

import json
import os
import signal
import subprocess
import sys
import time
import zipfile

import numpy as np
import pytest
import torch

from cathsim_dmc.core import run_files
from cathsim_dmc.learning.rl import checkpoints
from cathsim_dmc.learning.rl import train as training

STEPS = 40  # the tiny run below; a resumed run adds as many again


class Killed(BaseException):
    """Stands for the process dying: raised where the run would stop, caught by no one."""


def _configs(**trainer):
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from cathsim_dmc.core.shipped import conf_root

    with initialize_config_dir(config_dir=str(conf_root()), version_base=None):
        cfg = compose("train", overrides=["obs=internal", "demos=none"])
    algo = OmegaConf.to_container(cfg.algo, resolve=True)
    # A small network keeps each update cheap; what is checked does not depend on its size.
    algo.update(learning_starts=10, batch_size=16, net_arch=[32, 32])
    base = OmegaConf.to_container(cfg.trainer, resolve=True)
    base.update(
        eval_every=0, progress_bar=False, video=False, save_replay_buffer=True, checkpoint_every=20, torch_threads=1
    )
    base.update(trainer)
    return algo, base


def _train(run_dir, total, resume=False, callbacks=None):
    env = training.make_vec_env("bca", "type1", "internal", 0, 1, {"max_steps": 15})
    algo, trainer = _configs(total_timesteps=total)
    try:
        return training.train(
            env, run_dir, algo, trainer, 0, "internal", "bca", "type1", resume=resume, callbacks=callbacks
        )
    finally:
        env.close()


def _weights(module) -> dict:
    return {k: v.detach().clone() for k, v in module.state_dict().items()}


def _same_weights(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_resume_continues_from_the_saved_weights_buffer_and_step_count(tmp_path):
    from stable_baselines3.common.callbacks import BaseCallback

    from cathsim_dmc.learning.rl.sacfd import SACfD

    first = _train(tmp_path, STEPS)
    ckpt = tmp_path / checkpoints.CHECKPOINT_DIR
    assert checkpoints.checkpoint_step(ckpt / checkpoints.LAST_CHECKPOINT) == STEPS
    assert sorted(p.name for p in ckpt.glob(checkpoints.REPLAY_BUFFER_GLOB)) == [f"replay_buffer_step_{STEPS}.pkl"]
    saved = SACfD.load(ckpt / checkpoints.LAST_CHECKPOINT)
    first_rows = first.model.replay_buffer.actions[:STEPS].copy()

    class Spy(BaseCallback):
        """What the resumed run starts from, and how many environment steps it takes."""

        def _on_training_start(self):
            self.start = dict(
                actor=_weights(self.model.actor),
                critic=_weights(self.model.critic),
                steps=self.model.num_timesteps,
                rows=self.model.replay_buffer.pos,
            )
            self.calls = 0

        def _on_step(self):
            self.calls += 1
            return True

    spy = Spy()
    second = _train(tmp_path, 2 * STEPS, resume=True, callbacks=[spy])
    assert _same_weights(spy.start["actor"], _weights(saved.actor))
    assert _same_weights(spy.start["critic"], _weights(saved.critic))
    assert spy.start["steps"] == STEPS and spy.start["rows"] == STEPS  # the buffer came back whole
    assert spy.calls == STEPS and second.steps == STEPS  # only the missing steps ran
    buffer = second.model.replay_buffer
    rows = buffer.buffer_size if buffer.full else buffer.pos  # sized for the run: exactly full at its end
    assert rows == 2 * STEPS and np.array_equal(buffer.actions[:STEPS], first_rows)
    assert checkpoints.checkpoint_step(ckpt / checkpoints.LAST_CHECKPOINT) == 2 * STEPS


def test_a_run_killed_inside_any_checkpoint_write_resumes_from_a_matching_pair(tmp_path, monkeypatch):
    """Kill the run inside each of its writes in turn (the temporary file written, the
    rename not yet done), resume it, and check the resumed checkpoint is consistent."""
    real_write = run_files.write_atomic
    writes = []

    def counting(path, write):
        writes.append(path.name)
        return real_write(path, write)

    monkeypatch.setattr(run_files, "write_atomic", counting)
    _train(tmp_path / "clean", STEPS)
    # policy.json, step 20 and step 40 (buffer, step file, last.zip each), then final_model.zip
    assert writes[:4] == ["policy.json", "replay_buffer_step_20.pkl", "step_20.zip", "last.zip"]
    assert len(writes) == 8

    for kill_at in range(len(writes)):
        run_dir, calls = tmp_path / f"killed_{kill_at}", []

        def dying(path, write, kill_at=kill_at, calls=calls):
            calls.append(path.name)
            if len(calls) - 1 == kill_at:
                write(run_files.temporary_path(path))  # the file is half-way: written, not renamed
                raise Killed(path.name)
            return real_write(path, write)

        monkeypatch.setattr(run_files, "write_atomic", dying)
        with pytest.raises(Killed):
            _train(run_dir, STEPS)
        monkeypatch.setattr(run_files, "write_atomic", real_write)
        ckpt = run_dir / checkpoints.CHECKPOINT_DIR
        if not (ckpt / checkpoints.LAST_CHECKPOINT).is_file():  # killed before the first checkpoint committed
            continue
        assert any(run_files.is_temporary(p) for p in [*ckpt.iterdir(), *run_dir.iterdir()])
        last, step, buffer_file = checkpoints.resume_checkpoint(ckpt)
        assert buffer_file == ckpt / f"replay_buffer_step_{step}.pkl", (kill_at, writes[kill_at])
        assert not any(run_files.is_temporary(p) for p in ckpt.iterdir())
        resumed = _train(run_dir, STEPS, resume=True)
        buffer = resumed.model.replay_buffer
        assert resumed.model.num_timesteps == STEPS and (buffer.buffer_size if buffer.full else buffer.pos) == STEPS
        assert resumed.steps == STEPS - step


def test_a_run_resumed_without_its_buffer_refills_it_before_training_goes_on(tmp_path):
    """With no replay buffer saved, the resumed run's first updates would draw every batch
    from its first few transitions: it takes max(learning_starts, batch_size) steps first."""
    from stable_baselines3.common.callbacks import BaseCallback

    _train(tmp_path, STEPS)
    for buffer in (tmp_path / checkpoints.CHECKPOINT_DIR).glob(checkpoints.REPLAY_BUFFER_GLOB):
        buffer.unlink()

    class Updates(BaseCallback):
        """The update count after every environment step of the resumed run."""

        def _on_training_start(self):
            self.counts = {}

        def _on_step(self):
            self.counts[self.model.num_timesteps] = self.model._n_updates
            return True

    updates = Updates()
    resumed = _train(tmp_path, 2 * STEPS, resume=True, callbacks=[updates])
    refill = 16  # the batch size, above learning_starts (10)
    first = updates.counts[STEPS + 1]
    assert all(updates.counts[step] == first for step in range(STEPS + 1, STEPS + refill + 1))
    assert resumed.model._n_updates - first == STEPS - refill  # one update per step after the refill
    assert resumed.model.replay_buffer.pos == STEPS  # only the resumed run's transitions


def test_resume_refuses_a_replay_buffer_from_another_step(tmp_path):
    _train(tmp_path, STEPS)
    ckpt = tmp_path / checkpoints.CHECKPOINT_DIR
    (ckpt / f"replay_buffer_step_{STEPS}.pkl").rename(ckpt / "replay_buffer_step_20.pkl")
    with pytest.raises(RuntimeError, match=r"last\.zip is at step 40 but the replay buffer .*replay_buffer_step_20"):
        checkpoints.resume_checkpoint(ckpt)
    # The buffer of last.zip's step is checked by its contents too, once loaded.
    from cathsim_dmc.learning.rl.sacfd import SACfD

    model = SACfD.load(ckpt / checkpoints.LAST_CHECKPOINT)
    model.load_replay_buffer(ckpt / "replay_buffer_step_20.pkl")
    checkpoints.check_replay_buffer_step(model.replay_buffer, STEPS, "buffer")
    with pytest.raises(RuntimeError, match=r"holds 40 transitions \(full\), not the 30 of the checkpoint"):
        checkpoints.check_replay_buffer_step(model.replay_buffer, 30, "buffer")


def test_a_run_of_another_run_format_is_refused_in_one_line_by_resume_and_by_its_readers(tmp_path):
    from cathsim_dmc.agents.trained import make_policy

    _train(tmp_path, STEPS)
    policy_file = tmp_path / run_files.POLICY_FILE
    info = json.loads(policy_file.read_text())
    assert info.pop(run_files.FORMAT_KEY) == run_files.RUN_FORMAT
    last = tmp_path / checkpoints.CHECKPOINT_DIR / checkpoints.LAST_CHECKPOINT
    before = last.read_bytes()
    current = run_files.RUN_FORMAT
    for version, expected in [
        (None, f"was written by an older cathsim-dmc (run format 0, this version reads {current}); train it again"),
        (current - 1, f"was written by an older cathsim-dmc (run format {current - 1}, this version reads {current})"),
        (current + 1, f"was written by a newer cathsim-dmc (run format {current + 1}, this version reads {current})"),
    ]:
        policy_file.write_text(json.dumps(info if version is None else {**info, run_files.FORMAT_KEY: version}))
        for load in (lambda: _train(tmp_path, 2 * STEPS, resume=True), lambda: make_policy(str(tmp_path))):
            with pytest.raises(ValueError) as raised:
                load()
            assert expected in str(raised.value) and "\n" not in str(raised.value), version
    assert last.read_bytes() == before  # the refused resumes trained nothing


def test_stale_temporary_files_are_ignored_by_readers_and_removed_by_writers(tmp_path):
    from cathsim_dmc.evaluation.trajectory import save_npz
    from cathsim_dmc.learning.datasets import expand_paths

    save_npz(tmp_path / "shard_00000.npz", {"x": np.zeros(3)})
    for stale in ("shard_00001.npz.tmp.npz", ".shard_00002.tmp.npz"):  # the old and the new temporary names
        (tmp_path / stale).write_bytes(b"half a file")
    assert [p.name for p in expand_paths(tmp_path)] == ["shard_00000.npz"]
    assert sorted(p.name for p in run_files.remove_temporaries(tmp_path)) == [
        ".shard_00002.tmp.npz",
        "shard_00001.npz.tmp.npz",
    ]
    assert [p.name for p in tmp_path.iterdir()] == ["shard_00000.npz"]


@pytest.mark.slow
def test_cathsim_train_killed_at_random_moments_resumes_each_time(tmp_path):
    """kill -9 of the real command while it trains and checkpoints (with the replay buffer)."""
    run = tmp_path / "run"
    args = [
        "obs=internal",
        "demos=none",
        "task.max_steps=20",
        "algo.learning_starts=20",
        "algo.batch_size=16",
        "trainer.checkpoint_every=25",
        "trainer.save_replay_buffer=true",
        "trainer.eval_every=0",
        "trainer.final_eval_episodes=1",
        "trainer.video=false",
        "trainer.progress_bar=false",
    ]
    command = [sys.executable, "-m", "cathsim_dmc.app.cli.train"]
    rng = np.random.default_rng(0)
    process = subprocess.Popen(
        [*command, *args, "trainer.total_timesteps=400", f"hydra.run.dir={run}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    for kill in range(4):
        last = run / "checkpoints" / "last.zip"
        deadline = time.time() + 300
        while not last.is_file() and time.time() < deadline:
            time.sleep(0.2)
        time.sleep(rng.uniform(0.5, 4.0))
        os.kill(process.pid, signal.SIGKILL)
        process.wait()
        with zipfile.ZipFile(last) as archive:  # always a whole file
            assert archive.testzip() is None
        process = subprocess.Popen(
            [*command, f"resume={run}", "trainer.total_timesteps=400", f"hydra.run.dir={tmp_path}/resume{kill}"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
    _, stderr = process.communicate(timeout=900)
    assert process.returncode == 0, stderr[-2000:]
    ckpt = run / "checkpoints"
    assert checkpoints.checkpoint_step(ckpt / "last.zip") == 400
    assert [p.name for p in ckpt.glob(checkpoints.REPLAY_BUFFER_GLOB)] == ["replay_buffer_step_400.pkl"]
    assert not any(run_files.is_temporary(p) for p in ckpt.iterdir())
