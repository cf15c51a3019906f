"""SAC training on the navigation tasks: model set-up, memory check, callbacks, checkpoints.

Used by ``cathsim-train`` (cathsim_dmc/cli/train.py); importable for scripts.
"""

from __future__ import annotations

import contextlib
import json
import logging
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cathsim_dmc import run_files
from cathsim_dmc.checks import available_memory_bytes

CHECKPOINT_DIR = "checkpoints"
LAST_CHECKPOINT = "last.zip"
REPLAY_BUFFER_FORMAT = "replay_buffer_step_{}.pkl"  # saved with the checkpoint of that step
REPLAY_BUFFER_GLOB = "replay_buffer_step_*.pkl"
LEGACY_REPLAY_BUFFER = "replay_buffer.pkl"  # before 2026-11-25: one file, its step not recorded
FINAL_MODEL = "final_model.zip"
log = logging.getLogger("cathsim-train")
BEST_MODEL = "best.zip"  # the checkpoint with the best periodic deterministic evaluation
BEST_RECORD = "best.json"
EVALUATIONS = "evaluations.jsonl"  # one line per periodic evaluation: step, success rate, return, wall time


# -- environments ------------------------------------------------------------------
def make_env_fn(task: str, aorta: str, obs: str, seed: int, task_kwargs: dict):
    """A picklable constructor for vector envs (each subprocess builds its own env)."""

    def build():
        from stable_baselines3.common.monitor import Monitor

        from cathsim_dmc.gym import CathSimEnv

        env = CathSimEnv(task=task, aorta=aorta, obs=obs, **task_kwargs)
        env.reset(seed=seed)
        return Monitor(env, info_keywords=("success",))

    return build


def normalize_observations(env, resume_from: Path | None = None):
    """Wrap `env` in SB3's VecNormalize for the vector observations (images stay uint8).

    Running mean and variance of every non-image key, clipped at 10 standard deviations;
    rewards are left alone. Resuming continues the statistics saved beside `resume_from`.
    """
    from stable_baselines3.common.vec_env import VecNormalize

    from cathsim_dmc.gym import IMAGE_KEYS

    keys = [k for k in env.observation_space.spaces if k not in IMAGE_KEYS]
    if resume_from is not None and run_files.normalizer_path(resume_from).is_file():
        normalizer = run_files.load_normalizer(run_files.normalizer_path(resume_from))
        normalizer.set_venv(env)
        normalizer.training = True
        return normalizer
    return VecNormalize(env, norm_obs=True, norm_reward=False, norm_obs_keys=keys, clip_obs=10.0)


def make_vec_env(task, aorta, obs, seed, n_envs, task_kwargs):
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    fns = [make_env_fn(task, aorta, obs, seed + i, task_kwargs) for i in range(n_envs)]
    if n_envs == 1:
        return DummyVecEnv(fns)
    # forkserver/spawn: MuJoCo GL contexts and torch threads do not survive a fork well.
    return SubprocVecEnv(fns, start_method="spawn")


# -- memory ------------------------------------------------------------------------
def replay_bytes_per_transition(observation_space, action_dim: int) -> int:
    """Bytes one transition takes in SB3's (Dict)ReplayBuffer: observation and next
    observation at their own dtype (images stay uint8), action, reward, done, timeout."""
    obs_bytes = 0
    for space in getattr(observation_space, "spaces", {"": observation_space}).values():
        obs_bytes += int(np.prod(space.shape)) * np.dtype(space.dtype).itemsize
    return 2 * obs_bytes + 4 * action_dim + 4 + 4 + 4


def check_replay_memory(observation_space, action_dim: int, buffer_size: int, fraction: float = 0.8) -> int:
    """Raise MemoryError (one line: the estimate and the fix) if the buffer would not fit."""
    per = replay_bytes_per_transition(observation_space, action_dim)
    need = per * buffer_size
    have = available_memory_bytes()
    if need > fraction * have:
        fits = int(fraction * have / per)
        raise MemoryError(
            f"replay buffer of {buffer_size:,} transitions needs ~{need / 2**30:.1f} GiB "
            f"({per:,} B each) but {have / 2**30:.1f} GiB is available; "
            f"lower algo.buffer_size (at most ~{fits:,} here)")
    return need


def grow_replay_buffer(model, capacity: int) -> None:
    """Give `model` a replay buffer of `capacity` transitions, keeping what it holds.

    A resumed run may have a larger step budget than the one its buffer was sized for.
    """
    old = model.replay_buffer
    if old is None or old.buffer_size * old.n_envs >= capacity:
        return
    from cathsim_dmc.rl.demos import DemoReplayBuffer

    with_demos = isinstance(old, DemoReplayBuffer)
    # A DemoReplayBuffer keeps its demonstrations (a buffer of their own) and its batch share.
    extra = dict(demo_share=old.demo_share, demo_capacity=1) if with_demos else {}
    new = type(old)(capacity, old.observation_space, old.action_space, device=old.device, n_envs=old.n_envs,
                    handle_timeout_termination=old.handle_timeout_termination, **extra)
    if with_demos:
        new.demos = old.demos
    rows = old.buffer_size if old.full else old.pos
    for name in ("observations", "next_observations"):
        source, target = getattr(old, name), getattr(new, name)
        if isinstance(source, dict):
            for key in source:
                target[key][:rows] = source[key][:rows]
        else:
            target[:rows] = source[:rows]
    for name in ("actions", "rewards", "dones", "timeouts"):
        getattr(new, name)[:rows] = getattr(old, name)[:rows]
    new.pos, new.full = rows, False
    model.replay_buffer, model.buffer_size = new, capacity


def check_replay_buffer_step(buffer, step: int, source) -> None:
    """RuntimeError if `buffer` cannot hold the transitions of a run at `step` environment
    steps: every step stores one transition per environment, so a buffer that has not
    wrapped around holds exactly step / n_envs rows."""
    rows = buffer.buffer_size if buffer.full else buffer.pos
    if buffer.full and rows * buffer.n_envs <= step or not buffer.full and rows * buffer.n_envs == step:
        return
    raise RuntimeError(f"{source} holds {rows * buffer.n_envs:,} transitions{' (full)' if buffer.full else ''}, "
                       f"not the {step:,} of the checkpoint it was saved with; delete it to resume with an empty one")


# -- model -------------------------------------------------------------------------
def build_sac(env, algo: dict, seed: int, device: str, tensorboard_dir: str | None, demos: dict | None = None):
    """SAC on `env` from an `algo` config; with `demos` (its `share`, `capacity`) the replay
    buffer mixes demonstrations into every batch (`cathsim_dmc.rl.demos.DemoReplayBuffer`)."""
    from cathsim_dmc.rl.demos import DemoReplayBuffer, SACfD
    from cathsim_dmc.rl.features import ENNExtractor, LayerNormSACPolicy

    policy_kwargs = dict(
        features_extractor_class=ENNExtractor,
        net_arch=list(algo["net_arch"]),
        share_features_extractor=bool(algo["share_features_extractor"]),
    )
    with_demos = {}
    if demos:
        with_demos = dict(replay_buffer_class=DemoReplayBuffer, bc_weight=float(demos.get("bc_weight", 0.0)),
                          bc_filter=str(demos.get("bc_filter", "none")),  # conf/ no longer sets it: unfiltered
                          warm_start_steps=demos.get("warm_start_steps") or 0,
                          replay_buffer_kwargs=dict(demo_share=float(demos["share"]),
                                                    demo_capacity=int(demos["capacity"])))
    policy = LayerNormSACPolicy if algo.get("critic_layer_norm") else "MultiInputPolicy"
    return SACfD(
        policy, env, **with_demos, actor_average_tau=float(algo.get("actor_average_tau") or 0.0),
        actor_learning_rate_scale=float(algo.get("actor_learning_rate_scale", 1.0)),
        learning_rate=algo["learning_rate"], buffer_size=int(algo["buffer_size"]),
        learning_starts=int(algo["learning_starts"]), batch_size=int(algo["batch_size"]),
        tau=algo["tau"], gamma=algo["gamma"], train_freq=int(algo["train_freq"]),
        gradient_steps=int(algo["gradient_steps"]), target_update_interval=int(algo["target_update_interval"]),
        target_entropy=float(algo["target_entropy"]), ent_coef=algo["ent_coef"],
        policy_kwargs=policy_kwargs, tensorboard_log=tensorboard_dir, seed=seed, device=device, verbose=0,
    )


# -- callbacks ---------------------------------------------------------------------
def _callbacks():
    from stable_baselines3.common.callbacks import BaseCallback

    class EpisodeStats(BaseCallback):
        """Logs success rate, mean contact force (N) and steps/s over finished episodes."""

        def __init__(self, window: int = 20):
            super().__init__()
            self.window = window
            self._force_sum = None
            self._steps = None
            self._successes, self._forces = [], []
            self._t0 = time.perf_counter()
            self._n0 = 0

        def _on_training_start(self):
            n = self.training_env.num_envs
            self._force_sum, self._steps = np.zeros(n), np.zeros(n)
            self._t0, self._n0 = time.perf_counter(), self.num_timesteps

        def _on_step(self) -> bool:
            infos, dones = self.locals["infos"], self.locals["dones"]
            for i, (info, done) in enumerate(zip(infos, dones)):
                # The step's wall force averaged over its physics steps, as the metrics read it.
                self._force_sum[i] += info.get("mean_contact_force_n", 0.0)
                self._steps[i] += 1
                if done:
                    self._successes.append(float(info.get("success", False)))
                    self._forces.append(self._force_sum[i] / max(self._steps[i], 1))
                    self._force_sum[i] = self._steps[i] = 0
                    self._successes, self._forces = self._successes[-self.window:], self._forces[-self.window:]
                    self.logger.record("rollout/success_rate", float(np.mean(self._successes)))
                    self.logger.record("rollout/mean_contact_force_n", float(np.mean(self._forces)))
            elapsed = time.perf_counter() - self._t0
            if elapsed > 0:
                self.logger.record("time/env_steps_per_s", (self.num_timesteps - self._n0) / elapsed)
            return True

    class Checkpoints(BaseCallback):
        """Every `every` steps: model (and optionally the replay buffer), written atomically."""

        def __init__(self, run_dir: Path, every: int, replay_buffer: bool):
            super().__init__()
            self.dir = Path(run_dir) / CHECKPOINT_DIR
            self.every, self.replay_buffer = int(every), bool(replay_buffer)
            self._last = None

        def _on_training_start(self):
            self.dir.mkdir(parents=True, exist_ok=True)
            self._last = self.num_timesteps

        def _on_step(self) -> bool:
            return True

        def _on_rollout_end(self) -> None:
            # Here, not in _on_step: SB3 stores a step's transition after _on_step, so a
            # checkpoint taken there would hold one transition fewer than its step count.
            if self.every > 0 and self.num_timesteps - self._last >= self.every:
                self.save()

        def save(self):
            self._last = self.num_timesteps
            save_checkpoint(self.model, self.dir, self.replay_buffer)

    class Progress(BaseCallback):
        """A tqdm bar over the run's total steps, with ETA."""

        def __init__(self, total: int):
            super().__init__()
            self.total = total
            self.bar = None

        def _on_training_start(self):
            from tqdm import tqdm

            self.bar = tqdm(total=self.total, initial=self.num_timesteps, unit="step", desc="training",
                            mininterval=2.0)

        def _on_step(self) -> bool:
            self.bar.update(self.num_timesteps - self.bar.n)
            return True

        def _on_training_end(self):
            self.bar.close()

    class PeriodicEval(BaseCallback):
        """Every `every` steps: deterministic episodes on a separate env, logged under eval/.

        With `confirm_episodes` > 0, an evaluation that scores at least the best's success
        rate is confirmed on that many more episodes (their own seeds, the same at every
        confirmation), and best.zip is chosen on the pooled rate: the best of many
        10-episode scores is optimistic, and more so when every evaluation replays the same
        ten starts.
        """

        def __init__(self, make_env, every: int, episodes: int, seed: int, run_dir: Path | None = None,
                     confirm_episodes: int = 0, confirm_seed: int = 0):
            super().__init__()
            self.make_env, self.every, self.episodes, self.seed = make_env, int(every), int(episodes), seed
            self.confirm_episodes, self.confirm_seed = int(confirm_episodes), confirm_seed
            self.run_dir = None if run_dir is None else Path(run_dir)
            self.env = None
            self._last = 0

        def _on_training_start(self):
            self._last = self.num_timesteps
            # Wall time counts from the run's start (a resumed run continues its clock).
            self._start_wall = time.time() - _elapsed_before(self.run_dir)

        def _on_step(self) -> bool:
            if self.every <= 0 or self.num_timesteps - self._last < self.every:
                return True
            self._last = self.num_timesteps
            if self.env is None:
                self.env = self.make_env()
            # The averaged actor (algo.actor_average_tau), when the model keeps one, is what
            # is evaluated and what best.zip holds.
            averaged = getattr(self.model, "averaged_actor", None)
            with averaged() if averaged else contextlib.nullcontext():
                self._evaluate()
            return True

        def _evaluate(self):
            from cathsim_dmc.evaluation import run_episodes

            act = deterministic_policy(self.model)

            def episodes(count, seed):
                return run_episodes(self.env, lambda observation, env: act(observation), count, seed,
                                    show_progress=False, log_episodes=False)

            def mean(summaries, key):
                return float(np.mean([float(s[key]) for s in summaries]))

            summaries = episodes(self.episodes, self.seed)
            success_rate = mean(summaries, "success")
            self.logger.record("eval/mean_return", mean(summaries, "return"))
            self.logger.record("eval/success_rate", success_rate)
            self.logger.record("eval/mean_episode_length", mean(summaries, "steps"))
            if self.run_dir is not None:
                record = {"step": int(self.num_timesteps), "success_rate": success_rate,
                          "mean_return": mean(summaries, "return"), "mean_episode_length": mean(summaries, "steps"),
                          "episodes": self.episodes}
                selection = summaries
                best = best_record(self.run_dir)
                if self.confirm_episodes and (best is None or success_rate >= best["success_rate"]):
                    extra = episodes(self.confirm_episodes, self.confirm_seed)
                    record["confirm_success_rate"] = mean(extra, "success")
                    selection = summaries + extra
                    self.logger.record("eval/confirmed_success_rate", mean(selection, "success"))
                keep_if_best(self.model, self.run_dir, self.num_timesteps, mean(selection, "success"),
                             mean(selection, "return"), episodes=len(selection))
                record["wall_s"] = round(time.time() - self._start_wall, 1)
                with open(self.run_dir / EVALUATIONS, "a") as f:
                    f.write(json.dumps(record) + "\n")

        def _on_training_end(self):
            if self.env is not None:
                self.env.close()

    return EpisodeStats, Checkpoints, Progress, PeriodicEval


def save_model(model, path: Path) -> None:
    """`model` to `path` (atomic), and its observation normaliser beside it if it has one."""
    normalizer = model.get_vec_normalize_env()
    if normalizer is not None:
        run_files.write_atomic(run_files.normalizer_path(path), lambda tmp: normalizer.save(tmp))
    run_files.write_atomic(path, lambda tmp: model.save(tmp))


def replay_buffer_path(folder: Path, step: int) -> Path:
    """The replay buffer saved with the checkpoint of `step`."""
    return Path(folder) / REPLAY_BUFFER_FORMAT.format(int(step))


def _replay_buffer_steps(folder: Path) -> dict:
    """step -> path of every replay buffer file in `folder`."""
    found = {}
    for path in Path(folder).glob(REPLAY_BUFFER_GLOB):
        digits = path.stem.rsplit("_", 1)[-1]
        if digits.isdigit():
            found[int(digits)] = path
    return found


def checkpoint_step(path: Path) -> int:
    """The environment steps an SB3 checkpoint had taken, read without loading it."""
    with zipfile.ZipFile(path) as archive:
        return int(json.loads(archive.read("data"))["num_timesteps"])


def save_checkpoint(model, folder: Path, replay_buffer: bool) -> Path:
    """One checkpoint of `model` at its current step n: step_<n>.zip, then last.zip (the
    same content), and before them, optionally, replay_buffer_step_<n>.pkl. Returns last.zip.

    Every file is written atomically, and last.zip is written last: it commits the
    checkpoint. A process killed at any point leaves last.zip at the previous step with
    that step's replay buffer still on disk (an older buffer is deleted only after the new
    last.zip is in place), so `resume_checkpoint` always finds a matching pair.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    step = int(model.num_timesteps)
    if replay_buffer:
        run_files.write_atomic(replay_buffer_path(folder, step), lambda tmp: model.save_replay_buffer(tmp))
    step_file = folder / f"step_{step}.zip"
    save_model(model, step_file)
    last = folder / LAST_CHECKPOINT
    step_normalizer = run_files.normalizer_path(step_file)
    if step_normalizer.is_file():
        copy = step_normalizer.read_bytes()
        run_files.write_atomic(run_files.normalizer_path(last), lambda tmp: tmp.write_bytes(copy))
    run_files.write_atomic(last, lambda tmp: tmp.write_bytes(step_file.read_bytes()))
    for old_step, path in _replay_buffer_steps(folder).items():
        if old_step != step or not replay_buffer:
            path.unlink(missing_ok=True)
    (folder / LEGACY_REPLAY_BUFFER).unlink(missing_ok=True)
    return last


def resume_checkpoint(folder: Path) -> tuple:
    """(last.zip, its step, the replay buffer saved with it or None) of a checkpoint folder.

    Removes what a killed run left half-done (temporary files, a replay buffer newer than
    last.zip), and refuses, naming the files, a replay buffer that cannot belong to
    last.zip: resuming with it would pair the weights of one step with the data of another.
    """
    folder = Path(folder)
    last = folder / LAST_CHECKPOINT
    if not last.is_file():
        raise FileNotFoundError(f"nothing to resume: no {LAST_CHECKPOINT} in {folder}")
    run_files.remove_temporaries(folder)
    step = checkpoint_step(last)
    buffers = _replay_buffer_steps(folder)
    for newer in [s for s in buffers if s > step]:  # written by a checkpoint that was never committed
        buffers.pop(newer).unlink()
    if step in buffers:
        return last, step, buffers[step]
    if buffers:
        found = ", ".join(p.name for p in buffers.values())
        raise RuntimeError(f"{last} is at step {step} but the replay buffer in {folder} ({found}) is not; "
                           f"delete the buffer to resume with an empty one")
    # An older run's single file: its step is checked from its contents once loaded.
    legacy = folder / LEGACY_REPLAY_BUFFER
    return last, step, legacy if legacy.is_file() else None


def _elapsed_before(run_dir) -> float:
    """Wall seconds of the run's earlier sessions (from its last periodic evaluation)."""
    if run_dir is None or not (Path(run_dir) / EVALUATIONS).is_file():
        return 0.0
    lines = (Path(run_dir) / EVALUATIONS).read_text().splitlines()
    return float(json.loads(lines[-1])["wall_s"]) if lines else 0.0


def keep_if_best(model, run_dir: Path, step: int, success_rate: float, mean_return: float,
                 episodes: int | None = None) -> bool:
    """Save `model` as best.zip if its evaluation beats the best so far (success rate first,
    then return; a tie keeps the earlier one). best.json records the scores, the step and
    how many episodes the scores are over."""
    record_file = Path(run_dir) / CHECKPOINT_DIR / BEST_RECORD
    best = json.loads(record_file.read_text()) if record_file.is_file() else None
    if best is not None and (success_rate, mean_return) <= (best["success_rate"], best["mean_return"]):
        return False
    record_file.parent.mkdir(parents=True, exist_ok=True)
    save_model(model, record_file.parent / BEST_MODEL)
    record = {"step": int(step), "success_rate": success_rate, "mean_return": mean_return}
    if episodes is not None:
        record["episodes"] = int(episodes)
    run_files.write_atomic(record_file, lambda tmp: tmp.write_text(json.dumps(record)))
    return True


def best_record(run_dir: Path) -> dict | None:
    """best.json of a run (None if no periodic evaluation saved a best model)."""
    record_file = Path(run_dir) / CHECKPOINT_DIR / BEST_RECORD
    return json.loads(record_file.read_text()) if record_file.is_file() else None


def check_training(algo: dict, trainer: dict) -> None:
    """ValueError naming the setting for an `algo` or `trainer` value training cannot use;
    `train` calls it first, and cathsim-train before it builds an environment. The ranges
    are the schema's (cathsim_dmc.config); keys the dicts lack are not checked."""
    from cathsim_dmc.config import AlgoConfig, TrainerConfig, check_section

    check_section("algo", AlgoConfig, algo)
    check_section("trainer", TrainerConfig, trainer)


@dataclass
class TrainResult:
    model: object
    run_dir: Path
    steps: int
    seconds: float


def write_policy_file(run_dir: Path, cfg_obs: str, task: str, aorta: str, image_options: dict | None = None,
                      env_options: dict | None = None, normalize_observations: bool = False) -> None:
    """policy.json: what evaluating the checkpoint needs (observation preset, image options,
    and the environment options it was trained with that change what it sees or drives)."""
    info = {"algo": "sac", "obs": cfg_obs, "image_options": dict(image_options or {}), "task": task, "aorta": aorta,
            "env_options": dict(env_options or {}), "normalize_observations": bool(normalize_observations)}
    run_files.write_atomic(Path(run_dir) / run_files.POLICY_FILE, lambda tmp: tmp.write_text(json.dumps(info)))


def train(env, run_dir: Path, algo: dict, trainer: dict, seed: int, obs: str, task: str, aorta: str,
          resume: bool = False, make_eval_env=None, image_options: dict | None = None,
          demos: dict | None = None, make_demo_env=None, env_options: dict | None = None,
          callbacks: list | None = None) -> TrainResult:
    """Train (or continue) SAC on `env` (a VecEnv) until trainer["total_timesteps"].

    With `demos` (`episodes` > 0), `make_demo_env()` builds an environment like the
    training one in which the scripted expert records that many episodes; they are mixed
    into every batch, and the actor and critic may be pre-trained on them first
    (`pretrain_actor_steps`, `critic_warmup_steps`). `callbacks` (SB3 callbacks) run after
    the built-in ones (episode statistics, checkpoints, periodic evaluation, progress bar).
    """
    import torch
    from stable_baselines3.common.callbacks import CallbackList

    from cathsim_dmc.rl.demos import SACfD

    check_training(algo, trainer)
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    if trainer.get("torch_threads"):
        torch.set_num_threads(int(trainer["torch_threads"]))
    total = int(trainer["total_timesteps"])
    # A run never stores more transitions than it takes, so the buffer is allocated (and
    # checked against free memory) for min(buffer_size, total_timesteps): a short run
    # with the paper's 1e6 buffer does not need 24.9 GiB.
    capacity = max(1, min(int(algo["buffer_size"]), total))
    algo = dict(algo, buffer_size=capacity)
    # The demonstrations have a buffer of their own, checked together with the agent's.
    demo_capacity = int(demos["capacity"]) if _use_demos(demos) else 0
    check_replay_memory(env.observation_space, env.action_space.shape[0], capacity + demo_capacity)
    tb_dir = str(run_dir / "tensorboard")
    ckpt_dir = run_dir / CHECKPOINT_DIR
    if resume:
        last, step, buffer_file = resume_checkpoint(ckpt_dir)
    if trainer.get("normalize_observations"):
        # The normaliser of step_<n>.zip, written before last.zip, is the one that matches it.
        env = normalize_observations(env, ckpt_dir / f"step_{step}.zip" if resume else None)
    if resume:
        model = SACfD.load(last, env=env, device=trainer["device"], tensorboard_log=tb_dir)
        if buffer_file is not None:
            model.load_replay_buffer(buffer_file)
            check_replay_buffer_step(model.replay_buffer, step, buffer_file)
        else:
            refill = max(int(algo["learning_starts"]), int(algo["batch_size"]))
            log.warning("no replay buffer was saved with %s (step %d): the policy refills an empty one for %d "
                        "steps before training goes on", last, step, refill)
            model.refill_before_training(refill)
        grow_replay_buffer(model, capacity)
    else:
        run_files.remove_temporaries(ckpt_dir)
        model = build_sac(env, algo, seed, trainer["device"], tb_dir, demos if _use_demos(demos) else None)
        write_policy_file(run_dir, obs, task, aorta, image_options, env_options,
                          bool(trainer.get("normalize_observations")))
    if _use_demos(demos):
        load_demonstrations(model, demos, make_demo_env, seed, pretrain=not resume)
    EpisodeStats, Checkpoints, Progress, PeriodicEval = _callbacks()
    checkpoints = Checkpoints(run_dir, trainer["checkpoint_every"], trainer["save_replay_buffer"])
    extra_callbacks, callbacks = list(callbacks or []), [EpisodeStats(), checkpoints]
    if trainer.get("eval_every", 0) > 0 and make_eval_env is not None:
        # Selection episodes are seeded apart from the final report's (10_000 + seed), so
        # the report is not scored on the episodes the best checkpoint was chosen on.
        # Confirmation episodes have seeds of their own too (50_000 + seed), apart from the
        # demonstrations' (30_000+) and the takeover rounds' (40_000+).
        callbacks.append(PeriodicEval(make_eval_env, trainer["eval_every"], trainer["eval_episodes"], 20_000 + seed,
                                      run_dir=run_dir, confirm_episodes=trainer.get("confirm_episodes") or 0,
                                      confirm_seed=50_000 + seed))
    if trainer.get("progress_bar", True):
        callbacks.append(Progress(total))
    callbacks.extend(extra_callbacks)
    start_steps, t0 = model.num_timesteps, time.perf_counter()
    remaining = total - model.num_timesteps
    if remaining > 0:
        model.learn(total_timesteps=remaining, callback=CallbackList(callbacks), log_interval=1,
                    tb_log_name="sac", reset_num_timesteps=not resume)
    seconds = time.perf_counter() - t0
    last = ckpt_dir / LAST_CHECKPOINT
    if not last.is_file() or checkpoint_step(last) != model.num_timesteps:  # not saved at this step already
        save_checkpoint(model, ckpt_dir, trainer["save_replay_buffer"])
    save_model(model, run_dir / FINAL_MODEL)
    return TrainResult(model, run_dir, model.num_timesteps - start_steps, seconds)


def _use_demos(demos: dict | None) -> bool:
    return bool(demos) and int(demos.get("episodes", 0)) > 0


def deterministic_policy(model):
    """`act(observation) -> action` of `model`'s deterministic policy, through its
    observation normaliser if it has one (as the periodic evaluation and cathsim-eval see it)."""
    normalizer = model.get_vec_normalize_env()

    def act(observation):
        if normalizer is not None:
            observation = normalizer.normalize_obs(observation)
        return model.predict(observation, deterministic=True)[0]

    return act


def _takeover_rounds(model, demos: dict, make_demo_env, seed: int) -> None:
    """`demos["takeover_rounds"]` rounds: takeover demonstrations of the current actor
    (`rl.demos.takeover_transitions`) join the demonstrations, then the actor is
    re-trained on them for half of `pretrain_actor_steps`."""
    from cathsim_dmc.rl.demos import add_transitions, pretrain_actor, takeover_transitions

    env, student = make_demo_env(), deterministic_policy(model)
    try:
        for round_index in range(int(demos["takeover_rounds"])):
            t0 = time.perf_counter()
            transitions = takeover_transitions(env, student, int(demos["takeover_episodes"]),
                                               seed=40_000 + 1000 * seed + 100 * round_index,
                                               max_student_steps=int(demos["takeover_max_student_steps"]))
            add_transitions(model.replay_buffer, transitions)
            loss = pretrain_actor(model, int(demos.get("pretrain_actor_steps", 0)) // 2)
            log.info("takeover round %d: %d episodes, %d environment steps, %d expert transitions kept "
                     "(%d reached the target); actor re-trained, action MSE %.4f; %.0f s", round_index + 1,
                     transitions.episodes, transitions.steps_taken, len(transitions), transitions.successes,
                     loss, time.perf_counter() - t0)
    finally:
        env.close()


def load_demonstrations(model, demos: dict, make_demo_env, seed: int, pretrain: bool = True) -> None:
    """Record the expert's episodes (or read them from `demos["path"]`) into the model's
    DemoReplayBuffer, then (on a new run) pre-train the actor and warm up the critic on
    them; each stage is logged with its size, loss and time."""
    from cathsim_dmc.rl.demos import (DemoReplayBuffer, add_transitions, dataset_transitions, expert_transitions,
                                      pretrain_actor, warm_up_critic)

    buffer = model.replay_buffer
    if not isinstance(buffer, DemoReplayBuffer):
        raise ValueError("this run was started without demonstrations; resume it without demos.episodes")
    if buffer.demos.size() == 0:
        if make_demo_env is None:
            raise ValueError("demos.episodes > 0 needs an environment to record the expert in")
        env = make_demo_env()
        try:
            t0 = time.perf_counter()
            if demos.get("path"):
                transitions = dataset_transitions(demos["path"], env.task, env.observation_space,
                                                  int(demos["episodes"]))
            else:
                # Demonstration seeds are apart from training (seed) and evaluation (10_000+, 20_000+).
                transitions = expert_transitions(env, int(demos["episodes"]), seed=30_000 + 1000 * seed)
        finally:
            env.close()
        add_transitions(buffer, transitions)
        normalizer = model.get_vec_normalize_env()
        if normalizer is not None:  # start the statistics from the expert's states, not from zero
            for key in normalizer.norm_obs_keys:
                normalizer.obs_rms[key].update(transitions.observations[key])
        log.info("demonstrations: %d expert episodes (%d reached the target), %d transitions, %.0f s",
                 transitions.episodes, transitions.successes, len(transitions), time.perf_counter() - t0)
    if pretrain:
        if int(demos.get("pretrain_actor_steps", 0)) > 0:
            loss = pretrain_actor(model, int(demos["pretrain_actor_steps"]))
            log.info("actor pre-trained on the demonstrations: %d steps, action MSE %.4f",
                     int(demos["pretrain_actor_steps"]), loss)
        if int(demos.get("takeover_rounds") or 0) > 0:
            _takeover_rounds(model, demos, make_demo_env, seed)
        if int(demos.get("critic_warmup_steps", 0)) > 0:
            loss = warm_up_critic(model, int(demos["critic_warmup_steps"]))
            log.info("critic warmed up: %d steps, loss %.4f", int(demos["critic_warmup_steps"]), loss)
