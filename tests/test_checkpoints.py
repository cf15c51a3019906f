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
    # An older run's single replay_buffer.pkl is checked by its contents instead.
    (ckpt / "replay_buffer_step_20.pkl").rename(ckpt / checkpoints.LEGACY_REPLAY_BUFFER)
    from cathsim_dmc.learning.rl.sacfd import SACfD

    model = SACfD.load(ckpt / checkpoints.LAST_CHECKPOINT)
    model.load_replay_buffer(ckpt / checkpoints.LEGACY_REPLAY_BUFFER)
    checkpoints.check_replay_buffer_step(model.replay_buffer, STEPS, "buffer")
    with pytest.raises(RuntimeError, match=r"holds 40 transitions \(full\), not the 30 of the checkpoint"):
        checkpoints.check_replay_buffer_step(model.replay_buffer, 30, "buffer")


def _with_saved_attributes(checkpoint, **attributes):
    """Rewrite an SB3 checkpoint as if its model had carried `attributes` when it was saved."""
    with zipfile.ZipFile(checkpoint) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    data = json.loads(members["data"])
    data.update(attributes)
    members["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(checkpoint, "w") as archive:
        for name, content in members.items():
            archive.writestr(name, content)


def test_a_checkpoint_with_removed_settings_resumes_without_them(tmp_path):
    """Checkpoints saved before the Q-filter, the warm start and the slower actor were
    removed carry those settings, and SB3's load sets them on the model: nothing may read
    them (the actor learns at the full rate from the first step) and they are not saved again."""
    from stable_baselines3.common.callbacks import BaseCallback

    from cathsim_dmc.learning.rl.sacfd import SACfD

    _train(tmp_path, STEPS)
    last = tmp_path / checkpoints.CHECKPOINT_DIR / checkpoints.LAST_CHECKPOINT
    removed = dict(bc_filter="q", warm_start_steps=10 * STEPS, actor_learning_rate_scale=0.3)
    _with_saved_attributes(last, **removed)
    assert SACfD.load(last).warm_start_steps == 10 * STEPS  # what SB3 does with them

    class Actor(BaseCallback):
        def _on_training_start(self):
            self.start = _weights(self.model.actor)

        def _on_step(self):
            return True

    spy = Actor()
    resumed = _train(tmp_path, 2 * STEPS, resume=True, callbacks=[spy])
    assert not _same_weights(spy.start, _weights(resumed.model.actor))  # a warm start would have held it
    algo, _ = _configs()
    assert resumed.model.actor.optimizer.param_groups[0]["lr"] == algo["learning_rate"]
    with zipfile.ZipFile(last) as archive:
        assert not set(removed) & set(json.loads(archive.read("data")))


def test_an_agent_trained_with_a_removed_task_option_fails_to_load_in_one_line(tmp_path):
    """A policy.json written before insertion_limit_margin_m was removed: the agent, trained
    with the limit on, would be scored on another task; left at None (off) it loads."""
    from cathsim_dmc.agents.trained import make_policy

    env = training.make_vec_env("bca", "type1", "internal", 0, 1, {"max_steps": 3})
    algo, _ = _configs()
    algo.update(net_arch=[8])
    model = training.build_sac(env, algo, 0, "cpu", None)
    env.close()
    model.save(tmp_path / "final_model.zip")

    def policy_file(env_options):
        info = {
            "algo": "sac",
            "obs": "internal",
            "image_options": {},
            "task": "bca",
            "aorta": "type1",
            "env_options": env_options,
            "normalize_observations": False,
        }
        (tmp_path / run_files.POLICY_FILE).write_text(json.dumps(info))

    policy_file({"insertion_limit_margin_m": 0.02, "physics": "fast"})
    with pytest.raises(ValueError) as raised:
        make_policy(str(tmp_path))
    message = str(raised.value)
    assert "trained with insertion_limit_margin_m=0.02" in message and "removed on 2026-11-27" in message
    assert "\n" not in message
    policy_file({"insertion_limit_margin_m": None, "physics": "fast"})
    assert make_policy(str(tmp_path)).env_options == {"physics": "fast"}


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
