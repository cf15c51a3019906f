"""The SB3 callbacks of a cathsim-train run: episode statistics, checkpoints, periodic
evaluation and a progress bar.

Checkpoints and the periodic evaluation are SB3's `CheckpointCallback` and `EvalCallback`
with what differs here overridden; each override says why.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from pathlib import Path

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback, EvalCallback

from cathsim_dmc.core import run_files
from cathsim_dmc.learning.rl.checkpoints import (
    BEST_MODEL,
    CHECKPOINT_DIR,
    append_evaluation,
    best_record,
    copy_model,
    evaluated_wall_seconds,
    keep_if_best,
    load_policy_model,
    read_evaluations,
    save_checkpoint,
    write_best_record,
)


def deterministic_policy(model):
    """`act(observation) -> action` of `model`'s deterministic policy, through its
    observation normaliser if it has one (as the periodic evaluation and cathsim-eval see it).

    :param model: an SB3 model (its normaliser, if any, is the one attached to its env)
    """
    normalizer = model.get_vec_normalize_env()

    def act(observation):
        if normalizer is not None:
            observation = normalizer.normalize_obs(observation)
        return model.predict(observation, deterministic=True)[0]

    return act


def saved_policy(path: Path, normalized: bool):
    """`policy(observation, env) -> action` of the model saved at `path` (a run's .zip), as
    cathsim-eval plays it: the deterministic action of its evaluated actor
    (`load_policy_model`), through the normaliser saved beside it when `normalized`.

    :returns: (the policy, the loaded model)
    """
    model = load_policy_model(path)
    normalizer = run_files.load_normalizer(run_files.normalizer_path(path)) if normalized else None

    def act(observation, env) -> np.ndarray:
        if normalizer is not None:
            observation = normalizer.normalize_obs(observation)
        action, _ = model.predict(observation, deterministic=True)
        return np.asarray(action, dtype=np.float32)

    return act, model


class EpisodeStats(BaseCallback):
    """Logs the mean contact force (N) over finished episodes and steps/s.

    SB3 logs the success rate itself (`rollout/success_rate`, from the last step's
    ``info["is_success"]``, which `CathSimEnv` sets).

    :param window: the number of latest episodes the force is averaged over
    """

    def __init__(self, window: int = 20):
        super().__init__()
        self.window = window
        self._force_sum = None
        self._steps = None
        self._forces = []
        self._t0 = time.perf_counter()
        self._n0 = 0

    def _on_training_start(self) -> None:
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
                self._forces.append(self._force_sum[i] / max(self._steps[i], 1))
                self._force_sum[i] = self._steps[i] = 0
                self._forces = self._forces[-self.window :]
                self.logger.record("rollout/mean_contact_force_n", float(np.mean(self._forces)))
        elapsed = time.perf_counter() - self._t0
        if elapsed > 0:
            self.logger.record("time/env_steps_per_s", (self.num_timesteps - self._n0) / elapsed)
        return True


class Checkpoints(CheckpointCallback):
    """Every `save_freq` environment steps, one checkpoint of the model in `save_path`:
    step_<n>.zip and last.zip, each with its observation normaliser, and optionally the
    replay buffer (`cathsim_dmc.learning.rl.checkpoints.save_checkpoint`).

    Ctrl-C (SIGINT) during training is held until the step in progress is stored, then
    the model is checkpointed and KeyboardInterrupt raised; a second Ctrl-C stops at once.

    :param save_freq: environment steps between checkpoints (0: none during training)
    :param save_path: the run's checkpoint folder
    :param save_replay_buffer: also save the replay buffer with each checkpoint
    """

    def __init__(self, save_freq: int, save_path: Path, save_replay_buffer: bool = False):
        # The normaliser is always saved beside the model it belongs to.
        super().__init__(
            int(save_freq), Path(save_path), save_replay_buffer=bool(save_replay_buffer), save_vecnormalize=True
        )
        self._last_saved = 0
        self._stop_requested = False
        self._previous_handler = None

    def _on_training_start(self) -> None:
        self._last_saved = self.num_timesteps
        self._stop_requested = False
        if threading.current_thread() is threading.main_thread():  # only there can Python take signals
            self._previous_handler = signal.signal(signal.SIGINT, self._request_stop)

    def _request_stop(self, signum, frame) -> None:
        if self._stop_requested:  # the second Ctrl-C
            self._restore_handler()
            raise KeyboardInterrupt
        self._stop_requested = True

    def _restore_handler(self) -> None:
        if self._previous_handler is not None:
            signal.signal(signal.SIGINT, self._previous_handler)
            self._previous_handler = None

    def _on_training_end(self) -> None:
        self._restore_handler()

    def _on_step(self) -> bool:
        # SB3 saves here, every save_freq calls; see _on_rollout_end.
        return True

    def _on_rollout_end(self) -> None:
        # Here, not in _on_step: SB3 stores a step's transition after _on_step, so a
        # checkpoint taken there would hold one transition fewer than its step count.
        # Counted in environment steps since the last checkpoint (SB3 counts calls, which
        # restart at a resume and advance n_envs steps each). The files form one unit
        # that a resume can trust (save_checkpoint), not SB3's three independent names.
        if self._stop_requested or self.save_freq > 0 and self.num_timesteps - self._last_saved >= self.save_freq:
            self._last_saved = self.num_timesteps
            save_checkpoint(self.model, self.save_path, self.save_replay_buffer)
        if self._stop_requested:
            self._restore_handler()
            raise KeyboardInterrupt


class PeriodicEvaluation(EvalCallback):
    """Every `eval_freq` environment steps: `n_eval_episodes` deterministic episodes on
    `eval_env`, logged under eval/ (success rate, mean return, mean episode length).

    Episode i of every evaluation is reset with seed `seed + i`, so that evaluations
    replay the same starts and differ only by the policy. With `run_dir`, each evaluation
    is a line of evaluations.jsonl (with the run's wall time, which a resumed run
    continues), and the model is kept as best.zip when it beats the best so far
    (`cathsim_dmc.learning.rl.checkpoints.keep_if_best`). A model with an averaged actor
    (`SACfD.averaged_actor`) is evaluated, and kept, with it.

    :param eval_env: a `CathSimEnv` (not vectorised) built like the training environment
    :param eval_freq: environment steps between evaluations (0: none)
    :param n_eval_episodes: episodes of each evaluation
    :param seed: the seed of each evaluation's first episode
    :param run_dir: the run folder (None: log only)
    :param evaluate_at_start: also evaluate before the first step of a new run: the
        pre-trained policy competes for best.zip, so an online phase that loses what
        pre-training gave cannot lose it from the run's result
    :param callback_on_new_best: as EvalCallback's: run when an evaluation is the new best
    :param callback_after_eval: as EvalCallback's: run after every evaluation
    :param verbose: as EvalCallback's
    """

    def __init__(
        self,
        eval_env,
        eval_freq: int,
        n_eval_episodes: int,
        seed: int,
        run_dir: Path | None = None,
        callback_on_new_best: BaseCallback | None = None,
        callback_after_eval: BaseCallback | None = None,
        verbose: int = 0,
        evaluate_at_start: bool = False,
    ):
        super().__init__(
            eval_env,
            callback_on_new_best=callback_on_new_best,
            callback_after_eval=callback_after_eval,
            n_eval_episodes=int(n_eval_episodes),
            eval_freq=int(eval_freq),
            deterministic=True,
            verbose=verbose,
            warn=False,
        )
        self.episode_env = eval_env  # EvalCallback keeps it wrapped in a DummyVecEnv; episodes run on it directly
        self.seed = int(seed)
        self.run_dir = None if run_dir is None else Path(run_dir)
        self.evaluate_at_start = bool(evaluate_at_start)
        self.best_success_rate = self.last_success_rate = -np.inf
        self._last_evaluated = 0
        self._start_wall = 0.0

    def _init_callback(self) -> None:
        # Not EvalCallback's: its warning about differently wrapped training and evaluation
        # environments does not apply (the policy normalises its own observations,
        # `deterministic_policy`), and there is no log folder to make.
        if self.callback_on_new_best is not None:
            self.callback_on_new_best.init_callback(self.model)

    def _on_training_start(self) -> None:
        super()._on_training_start()
        self._last_evaluated = self.num_timesteps
        # Wall time counts from the run's start (a resumed run continues its clock).
        self._start_wall = time.time() - evaluated_wall_seconds(self.run_dir)
        best = best_record(self.run_dir) if self.run_dir is not None else None
        if best is not None:  # a resumed run competes with the best it already kept
            self.best_success_rate, self.best_mean_reward = best["success_rate"], best["mean_return"]
        if self.evaluate_at_start and self.eval_freq > 0 and self.num_timesteps == 0:
            self._evaluate()  # the pre-trained policy (no averaged actor exists before the first update)

    def _on_step(self) -> bool:
        # Counted in environment steps since the last evaluation, not in calls as
        # EvalCallback counts: the same schedule with any number of environments and
        # across a resume.
        if self.eval_freq <= 0 or self.num_timesteps - self._last_evaluated < self.eval_freq:
            return True
        self._last_evaluated = self.num_timesteps
        averaged = getattr(self.model, "averaged_actor", None)
        with averaged() if averaged else contextlib.nullcontext():
            new_best = self._evaluate()
        continue_training = True
        if new_best and self.callback_on_new_best is not None:
            continue_training = self.callback_on_new_best.on_step()
        if self.callback is not None:
            continue_training = continue_training and self._on_event()
        return continue_training

    def _evaluate(self) -> bool:
        """One evaluation: logged, recorded and compared with the best; True for a new best.

        Not EvalCallback's `evaluate_policy`: episodes run through
        `cathsim_dmc.evaluation.rollouts.run_episodes` with their own seeds, as every tool evaluates,
        and the best is chosen by success rate, then return (a tie keeps the earlier).
        """
        from cathsim_dmc.evaluation.rollouts import run_episodes

        act = deterministic_policy(self.model)
        summaries = run_episodes(
            self.episode_env,
            lambda observation, env: act(observation),
            self.n_eval_episodes,
            self.seed,
            show_progress=False,
            log_episodes=False,
        )

        def mean(key):
            return float(np.mean([float(s[key]) for s in summaries]))

        success_rate, mean_return, mean_length = mean("success"), mean("return"), mean("steps")
        self.last_success_rate, self.last_mean_reward = success_rate, mean_return
        self.logger.record("eval/mean_return", mean_return)
        self.logger.record("eval/success_rate", success_rate)
        self.logger.record("eval/mean_episode_length", mean_length)
        if self.run_dir is None:
            new_best = (success_rate, mean_return) > (self.best_success_rate, self.best_mean_reward)
        else:
            new_best = keep_if_best(
                self.model, self.run_dir, self.num_timesteps, success_rate, mean_return, episodes=self.n_eval_episodes
            )
            append_evaluation(
                self.run_dir,
                {
                    "step": int(self.num_timesteps),
                    "success_rate": success_rate,
                    "mean_return": mean_return,
                    "mean_episode_length": mean_length,
                    "episodes": self.n_eval_episodes,
                    "wall_s": round(time.time() - self._start_wall, 1),
                },
            )
        if new_best:
            self.best_success_rate, self.best_mean_reward = success_rate, mean_return
        return new_best

    def _on_training_end(self) -> None:
        self.eval_env.close()


def has_unbroken_tie(run_dir: Path) -> bool:
    """True when several periodic evaluations of the run share the best success rate (above
    0) and `break_best_tie` has not looked at them yet."""
    best, evaluations = best_record(run_dir), read_evaluations(run_dir)
    if best is None or not evaluations:
        return False
    top = max(e["success_rate"] for e in evaluations)
    if top <= 0 or sum(e["success_rate"] == top for e in evaluations) < 2:
        return False
    return best.get("tie_break", {}).get("after_step") != evaluations[-1]["step"]


TIE_BREAK_CANDIDATES = 3  # the tied checkpoints with the highest return: each costs tie_break_episodes episodes


def break_best_tie(run_dir: Path, make_eval_env, periodic_episodes: int, extra_episodes: int, seed: int):
    """When several periodic evaluations share the best success rate, score the tied
    checkpoints on `extra_episodes` more selection episodes and keep the best as best.zip.

    Ten episodes cannot tell a policy that succeeds in 86% of starts from one that
    succeeds in all: both often score 10 of 10. Before this, a tie kept the earlier
    checkpoint, which with `eval_at_start` is often the pre-trained actor. Here each
    candidate (at most `TIE_BREAK_CANDIDATES`, those with the highest mean return; models
    with the same weights once) plays the episodes that follow the periodic evaluation's
    own (seeds `seed + periodic_episodes` onwards), and is ranked by its success rate and
    then its return over all its selection episodes; a tie still keeps the earlier. A
    best success rate of 0 is left to the return, as before. The final report's episodes
    (10_000 + seed) are never among them.

    :param run_dir: a cathsim-train run folder with evaluations.jsonl and its checkpoints
    :param make_eval_env: builds a `CathSimEnv` like the periodic evaluation's
    :param periodic_episodes: episodes of each periodic evaluation (trainer.eval_episodes)
    :param extra_episodes: more episodes for each candidate (trainer.tie_break_episodes)
    :param seed: the periodic evaluation's first seed (20_000 + the run's seed)
    :returns: the new best.json record, or None when there was no tie to break
    """
    import hashlib

    from cathsim_dmc.evaluation.rollouts import run_episodes

    run_dir = Path(run_dir)
    best = best_record(run_dir)
    if extra_episodes <= 0 or not has_unbroken_tie(run_dir):
        return None
    evaluations = read_evaluations(run_dir)
    normalized = bool(run_files.check_run_format(run_dir).get("normalize_observations"))
    top = max(e["success_rate"] for e in evaluations)
    ckpt_dir = run_dir / CHECKPOINT_DIR
    files = {}
    for e in sorted((e for e in evaluations if e["success_rate"] == top), key=lambda e: -e["mean_return"]):
        path = ckpt_dir / (BEST_MODEL if e["step"] == best["step"] else f"step_{e['step']}.zip")
        if path.is_file() and e["step"] not in files:
            files[e["step"]] = (path, e)
    record = dict(
        best,
        tie_break={
            "episodes": int(extra_episodes),
            "first_seed": int(seed + periodic_episodes),
            "after_step": int(evaluations[-1]["step"]),
            "scores": [],
        },
    )
    candidates, seen = [], set()
    for step, (path, e) in files.items():
        policy, model = saved_policy(path, normalized)
        weights = hashlib.sha1(b"".join(v.cpu().numpy().tobytes() for v in model.actor.state_dict().values()))
        if weights.hexdigest() in seen:  # e.g. the pre-trained actor again, before the first update
            continue
        seen.add(weights.hexdigest())
        candidates.append((step, path, e, policy))
        if len(candidates) == TIE_BREAK_CANDIDATES:
            break
    if len(candidates) < 2:  # the tied models are one and the same (or only one was kept on disk)
        write_best_record(run_dir, record)
        return None
    env = make_eval_env()
    scores = []
    try:
        for step, path, e, policy in candidates:
            summaries = run_episodes(
                env, policy, extra_episodes, seed + periodic_episodes, show_progress=False, log_episodes=False
            )
            played = int(e.get("episodes", periodic_episodes))  # the periodic evaluation's own count
            n = played + extra_episodes
            success = (e["success_rate"] * played + sum(float(s["success"]) for s in summaries)) / n
            mean_return = (e["mean_return"] * played + sum(float(s["return"]) for s in summaries)) / n
            scores.append({"step": int(step), "success_rate": success, "mean_return": mean_return, "episodes": n})
    finally:
        env.close()
    winner = max(scores, key=lambda c: (c["success_rate"], c["mean_return"], -c["step"]))
    path = next(p for step, p, _, _ in candidates if step == winner["step"])
    if path.name != BEST_MODEL:
        copy_model(path, ckpt_dir / BEST_MODEL)
    record = dict(winner, tie_break=dict(record["tie_break"], scores=scores))
    write_best_record(run_dir, record)
    return record


class Progress(BaseCallback):
    """A tqdm bar over the run's total steps, with ETA.

    Not SB3's ProgressBarCallback, which needs `rich` (not a dependency here) and counts
    only the steps left: a resumed run's bar starts where the run stands.

    :param total: the run's total environment steps
    """

    def __init__(self, total: int):
        super().__init__()
        self.total = total
        self.bar = None

    def _on_training_start(self) -> None:
        from tqdm import tqdm

        self.bar = tqdm(total=self.total, initial=self.num_timesteps, unit="step", desc="training", mininterval=2.0)

    def _on_step(self) -> bool:
        self.bar.update(self.num_timesteps - self.bar.n)
        return True

    def _on_training_end(self) -> None:
        self.bar.close()
