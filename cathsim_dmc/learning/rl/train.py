"""SAC training on the navigation tasks: the environments, the model, the loop and the
demonstrations it starts from.

Used by ``cathsim-train`` (cathsim_dmc/app/cli/train.py); importable for scripts. The run's
files are `cathsim_dmc.learning.rl.checkpoints`, its callbacks `cathsim_dmc.learning.rl.callbacks`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cathsim_dmc.control.policies import make_policy
from cathsim_dmc.core import run_files
from cathsim_dmc.core.settings import check_section, with_defaults
from cathsim_dmc.learning.rl.checkpoints import (
    CHECKPOINT_DIR,
    FINAL_MODEL,
    LAST_CHECKPOINT,
    check_replay_buffer_step,
    checkpoint_interval,
    checkpoint_step,
    resume_checkpoint,
    save_checkpoint,
    save_model,
    write_policy_file,
)
from cathsim_dmc.learning.rl.replay import check_replay_memory, grow_replay_buffer
from cathsim_dmc.learning.rl.settings import AlgoConfig, DemosConfig, TrainerConfig

log = logging.getLogger("cathsim-train")


# -- environments ------------------------------------------------------------------
def make_env_fn(task: str, aorta: str, obs: str, seed: int, task_kwargs: dict):
    """A picklable constructor for vector envs (each subprocess builds its own env)."""

    def build():
        import multiprocessing
        import signal

        from stable_baselines3.common.monitor import Monitor

        from cathsim_dmc.suite.gym import CathSimEnv

        if multiprocessing.parent_process() is not None:  # a SubprocVecEnv worker: Ctrl-C is the trainer's
            signal.signal(signal.SIGINT, signal.SIG_IGN)
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

    from cathsim_dmc.suite.gym import IMAGE_KEYS

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


# -- model -------------------------------------------------------------------------
def build_sac(env, algo: dict, seed: int, device: str, tensorboard_dir: str | None, demos: dict | None = None):
    """SAC on `env` from an `algo` config; with `demos` (its `share`, `capacity`) the replay
    buffer mixes demonstrations into every batch (`cathsim_dmc.learning.rl.demos.DemoReplayBuffer`)."""
    from cathsim_dmc.learning.networks import ENNExtractor, LayerNormSACPolicy
    from cathsim_dmc.learning.rl.demos import DemoReplayBuffer
    from cathsim_dmc.learning.rl.sacfd import SACfD

    algo = with_defaults(AlgoConfig, algo)
    demos = with_defaults(DemosConfig, demos) if demos else None
    policy_kwargs = dict(
        features_extractor_class=ENNExtractor,
        net_arch=list(algo["net_arch"]),
        share_features_extractor=bool(algo["share_features_extractor"]),
    )
    with_demos = {}
    if demos:
        with_demos = dict(
            replay_buffer_class=DemoReplayBuffer,
            bc_weight=float(demos["bc_weight"]),
            replay_buffer_kwargs=dict(demo_share=float(demos["share"]), demo_capacity=int(demos["capacity"])),
        )
        if int(demos["dagger_rounds"]) > 0:
            with_demos["replay_buffer_kwargs"]["label_capacity"] = int(demos["dagger_capacity"])
    policy = LayerNormSACPolicy if algo["critic_layer_norm"] else "MultiInputPolicy"
    return SACfD(
        policy,
        env,
        **with_demos,
        actor_average_tau=float(algo["actor_average_tau"]),
        learning_rate=algo["learning_rate"],
        buffer_size=int(algo["buffer_size"]),
        learning_starts=int(algo["learning_starts"]),
        batch_size=int(algo["batch_size"]),
        tau=algo["tau"],
        gamma=algo["gamma"],
        train_freq=int(algo["train_freq"]),
        gradient_steps=int(algo["gradient_steps"]),
        target_update_interval=int(algo["target_update_interval"]),
        target_entropy=float(algo["target_entropy"]),
        ent_coef=algo["ent_coef"],
        policy_kwargs=policy_kwargs,
        tensorboard_log=tensorboard_dir,
        seed=seed,
        device=device,
        verbose=0,
    )


def check_training(algo: dict, trainer: dict) -> None:
    """ValueError naming the setting for an `algo` or `trainer` value training cannot use;
    `train` calls it first, and cathsim-train before it builds an environment. The ranges
    are cathsim_dmc.learning.rl.settings'; keys the dicts lack are not checked."""
    check_section("algo", AlgoConfig, algo)
    check_section("trainer", TrainerConfig, trainer)


@dataclass
class TrainResult:
    """What `train` returns: the model, its run folder, and the environment steps this
    call took with their wall seconds."""

    model: object
    run_dir: Path
    steps: int
    seconds: float


def train(
    env,
    run_dir: Path,
    algo: dict,
    trainer: dict,
    seed: int,
    obs: str,
    task: str,
    aorta: str,
    resume: bool = False,
    make_eval_env=None,
    image_options: dict | None = None,
    demos: dict | None = None,
    make_demo_env=None,
    env_options: dict | None = None,
    callbacks: list | None = None,
) -> TrainResult:
    """Train (or continue) SAC on `env` (a VecEnv) until trainer["total_timesteps"].

    With `demos` (`episodes` > 0), `make_demo_env()` builds an environment like the
    training one in which the scripted expert records that many episodes; they are mixed
    into every batch, and the actor and critic may be pre-trained on them first
    (`pretrain_actor_steps`, `critic_warmup_steps`). `callbacks` (SB3 callbacks) run after
    the built-in ones (episode statistics, checkpoints, periodic evaluation, progress bar).
    """
    import torch

    from cathsim_dmc.learning.rl.sacfd import SACfD

    # Options a Python caller leaves out take their defaults (cathsim_dmc.learning.rl.settings).
    algo, trainer = with_defaults(AlgoConfig, algo), with_defaults(TrainerConfig, trainer)
    demos = with_defaults(DemosConfig, demos) if demos else None
    check_training(algo, trainer)
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    if trainer["torch_threads"]:
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
        run_files.check_run_format(run_dir)  # another version's run is refused before anything loads
        last, step, buffer_file = resume_checkpoint(ckpt_dir)
        log.info("resuming from step %d of %d (%s)", step, total, last)
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
            log.warning(
                "no replay buffer was saved with %s (step %d): the policy refills an empty one for %d "
                "steps before training goes on",
                last,
                step,
                refill,
            )
            model.refill_before_training(refill)
        grow_replay_buffer(model, capacity)
    else:
        run_files.remove_temporaries(ckpt_dir)
        model = build_sac(env, algo, seed, trainer["device"], tb_dir, demos if _use_demos(demos) else None)
        write_policy_file(
            run_dir, obs, task, aorta, image_options, env_options, bool(trainer.get("normalize_observations"))
        )
    start_steps = model.num_timesteps
    try:
        seconds = _learn(model, env, run_dir, trainer, seed, demos, resume, make_eval_env, make_demo_env, callbacks)
    except KeyboardInterrupt:
        raise run_files.Interrupted(_interrupted(run_dir, total)) from None
    last = ckpt_dir / LAST_CHECKPOINT
    if not last.is_file() or checkpoint_step(last) != model.num_timesteps:  # not saved at this step already
        save_checkpoint(model, ckpt_dir, trainer["save_replay_buffer"])
    save_model(model, run_dir / FINAL_MODEL)
    if trainer["eval_every"] > 0 and make_eval_env is not None:
        from cathsim_dmc.learning.rl.callbacks import break_best_tie

        try:
            record = break_best_tie(
                run_dir, make_eval_env, trainer["eval_episodes"], trainer["tie_break_episodes"], 20_000 + seed
            )
        except KeyboardInterrupt:
            raise run_files.Interrupted(
                f"training finished ({run_dir / FINAL_MODEL}); choosing best.zip among tied "
                f"checkpoints stopped; finish it with: cathsim-train resume={run_dir}"
            ) from None
        if record is not None:
            log.info(
                "best.zip: step %d of the tied %s, %.0f%% success over %d selection episodes",
                record["step"],
                ", ".join(str(c["step"]) for c in record["tie_break"]["scores"]),
                100 * record["success_rate"],
                record["episodes"],
            )
    return TrainResult(model, run_dir, model.num_timesteps - start_steps, seconds)


def _interrupted(run_dir: Path, total: int) -> str:
    """What a Ctrl-C'd run kept, and how to continue it."""
    last = run_dir / CHECKPOINT_DIR / LAST_CHECKPOINT
    if not last.is_file():
        return f"training stopped before its first checkpoint; nothing to resume in {run_dir}: start it again"
    return (
        f"training stopped; checkpoint at step {checkpoint_step(last)} of {total} kept in {last}; "
        f"continue with: cathsim-train resume={run_dir}"
    )


def _learn(model, env, run_dir, trainer, seed, demos, resume, make_eval_env, make_demo_env, callbacks) -> float:
    """`train`'s work after the model exists: the demonstrations, then SAC to the budget;
    returns the wall seconds of the SAC part."""
    from stable_baselines3.common.callbacks import CallbackList

    from cathsim_dmc.learning.rl.callbacks import Checkpoints, EpisodeStats, PeriodicEvaluation, Progress

    total, ckpt_dir = int(trainer["total_timesteps"]), run_dir / CHECKPOINT_DIR
    if _use_demos(demos) and model.num_timesteps < total:  # a finished run resumed needs none
        load_demonstrations(
            model,
            demos,
            make_demo_env,
            seed,
            pretrain=not resume,
            show_progress=trainer["progress_bar"],
            labels_path=run_dir / CHECKPOINT_DIR / LABELS_FILE,
        )
    t0, remaining = time.perf_counter(), total - model.num_timesteps
    if remaining > 0:
        built_in = [EpisodeStats(), Checkpoints(checkpoint_interval(trainer), ckpt_dir, trainer["save_replay_buffer"])]
        if trainer["eval_every"] > 0 and make_eval_env is not None:
            # Selection episodes are seeded apart from the final report's (10_000 + seed), so
            # the report is not scored on the episodes the best checkpoint was chosen on, and
            # apart from the demonstrations' (30_000+) and the takeover rounds' (40_000+).
            built_in.append(
                PeriodicEvaluation(
                    make_eval_env(),
                    trainer["eval_every"],
                    trainer["eval_episodes"],
                    20_000 + seed,
                    run_dir=run_dir,
                    evaluate_at_start=trainer["eval_at_start"],
                )
            )
        if trainer["progress_bar"]:
            built_in.append(Progress(total))
        model.learn(
            total_timesteps=remaining,
            callback=CallbackList([*built_in, *(callbacks or [])]),
            log_interval=1,
            tb_log_name="sac",
            reset_num_timesteps=not resume,
        )
    return time.perf_counter() - t0


# -- demonstrations ----------------------------------------------------------------
def _use_demos(demos: dict | None) -> bool:
    return bool(demos) and int(demos["episodes"]) > 0


def _takeover_rounds(model, demos: dict, make_demo_env, seed: int, show_progress: bool = False) -> None:
    """`demos["takeover_rounds"]` rounds: takeover demonstrations of the current actor
    (`rl.demos.takeover_transitions`) join the demonstrations, then the actor is
    re-trained on them for half of `pretrain_actor_steps`."""
    from cathsim_dmc.learning.rl.callbacks import deterministic_policy
    from cathsim_dmc.learning.rl.demos import add_transitions, takeover_transitions
    from cathsim_dmc.learning.rl.sacfd import pretrain_actor

    env, student = make_demo_env(), deterministic_policy(model)
    label = lambda text: text if show_progress else None  # noqa: E731  (a bar's label, or no bar)
    try:
        for round_index in range(int(demos["takeover_rounds"])):
            t0 = time.perf_counter()
            transitions = takeover_transitions(
                env,
                student,
                int(demos["takeover_episodes"]),
                seed=40_000 + 1000 * seed + 100 * round_index,
                max_student_steps=int(demos["takeover_max_student_steps"]),
                progress=label(f"takeover round {round_index + 1}"),
                expert=make_policy(demos["expert"]),
            )
            add_transitions(model.replay_buffer, transitions)
            loss = pretrain_actor(
                model,
                int(demos["pretrain_actor_steps"]) // 2,
                progress=label(f"round {round_index + 1}: re-training the actor"),
            )
            log.info(
                "takeover round %d: %d episodes, %d environment steps, %d expert transitions kept "
                "(%d reached the target); actor re-trained, action MSE %.4f; %.0f s",
                round_index + 1,
                transitions.episodes,
                transitions.steps_taken,
                len(transitions),
                transitions.successes,
                loss,
                time.perf_counter() - t0,
            )
    finally:
        env.close()


LABELS_FILE = "expert_labels.npz"  # in the checkpoint folder: a resumed run keeps its DAgger labels


def _dagger_rounds(
    model, demos: dict, make_demo_env, seed: int, labels_path: Path | None, show_progress: bool = False
) -> None:
    """`demos["dagger_rounds"]` rounds of DAgger: the current actor drives, the expert labels
    every state (`rl.demos.expert_labels`), the labels join the buffer's and the actor is
    re-trained on demonstrations and labels for `pretrain_actor_steps`. The labels are
    saved to `labels_path` for a resumed run."""
    from cathsim_dmc.learning.rl.callbacks import deterministic_policy
    from cathsim_dmc.learning.rl.demos import add_labels, expert_labels
    from cathsim_dmc.learning.rl.sacfd import pretrain_actor

    env, student = make_demo_env(), deterministic_policy(model)
    label = lambda text: text if show_progress else None  # noqa: E731  (a bar's label, or no bar)
    try:
        for round_index in range(int(demos["dagger_rounds"])):
            t0 = time.perf_counter()
            # Seeds apart from the demonstrations' (30_000+) and the takeover rounds' (40_000+).
            labels = expert_labels(
                env,
                student,
                int(demos["dagger_episodes"]),
                seed=50_000 + 1000 * seed + 100 * round_index,
                progress=label(f"DAgger round {round_index + 1}"),
                expert=make_policy(demos["expert"]),
            )
            add_labels(model.replay_buffer, labels)
            loss = pretrain_actor(
                model,
                int(demos["pretrain_actor_steps"]),
                progress=label(f"round {round_index + 1}: re-training the actor"),
            )
            log.info(
                "DAgger round %d: the actor reached the target in %d of %d episodes; %d states labelled "
                "(%d in all); actor re-trained, action MSE %.4f; %.0f s",
                round_index + 1,
                labels.successes,
                labels.episodes,
                len(labels),
                model.replay_buffer.label_count(),
                loss,
                time.perf_counter() - t0,
            )
    finally:
        env.close()
    if labels_path is not None:
        save_labels(model.replay_buffer, labels_path)


def save_labels(buffer, path: Path) -> None:
    """The buffer's expert labels as an .npz (observation keys prefixed obs_, and action)."""
    n = buffer.label_count()
    arrays = {f"obs_{k}": v[:n, 0] for k, v in buffer.labels.observations.items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, action=buffer.labels.actions[:n, 0], **arrays)


def load_labels(buffer, path: Path) -> int:
    """Expert labels saved by `save_labels` back into the buffer; returns how many."""
    from cathsim_dmc.learning.rl.demos import Labels, add_labels

    with np.load(path) as data:
        observations = {k[4:]: data[k] for k in data.files if k.startswith("obs_")}
        labels = Labels(observations, data["action"], 0, 0)
    add_labels(buffer, labels)
    return len(labels)


def load_demonstrations(
    model,
    demos: dict,
    make_demo_env,
    seed: int,
    pretrain: bool = True,
    show_progress: bool = False,
    labels_path: Path | None = None,
) -> None:
    """Record the expert's episodes (or read them from `demos["path"]`) into the model's
    DemoReplayBuffer, then (on a new run) pre-train the actor and warm up the critic on
    them; each stage is logged with its size, loss and time, and with `show_progress`
    shows a progress bar while it runs."""
    from cathsim_dmc.learning.rl.demos import DemoReplayBuffer, add_transitions, dataset_transitions, expert_transitions
    from cathsim_dmc.learning.rl.sacfd import pretrain_actor, warm_up_critic

    demos = with_defaults(DemosConfig, demos)
    buffer = model.replay_buffer
    label = lambda text: text if show_progress else None  # noqa: E731  (a bar's label, or no bar)
    if not isinstance(buffer, DemoReplayBuffer):
        raise ValueError("this run was started without demonstrations; resume it without demos.episodes")
    if buffer.demos.size() == 0:
        if make_demo_env is None:
            raise ValueError("demos.episodes > 0 needs an environment to record the expert in")
        env = make_demo_env()
        try:
            t0 = time.perf_counter()
            if demos["path"]:
                transitions = dataset_transitions(
                    demos["path"], env.task, env.observation_space, int(demos["episodes"])
                )
            else:
                # Demonstration seeds are apart from training (seed) and evaluation (10_000+, 20_000+).
                transitions = expert_transitions(
                    env,
                    int(demos["episodes"]),
                    seed=30_000 + 1000 * seed,
                    policy=make_policy(demos["expert"]),
                    progress=label("recording demonstrations"),
                )
        finally:
            env.close()
        add_transitions(buffer, transitions)
        normalizer = model.get_vec_normalize_env()
        if normalizer is not None:  # start the statistics from the expert's states, not from zero
            for key in normalizer.norm_obs_keys:
                normalizer.obs_rms[key].update(transitions.observations[key])
        log.info(
            "demonstrations: %d episodes of %s (%d reached the target), %d transitions, %.0f s",
            transitions.episodes,
            demos["path"] or demos["expert"],
            transitions.successes,
            len(transitions),
            time.perf_counter() - t0,
        )
    if not pretrain and buffer.labels is not None and buffer.label_count() == 0 and labels_path is not None:
        if labels_path.is_file():  # a resumed run: its DAgger labels, for the cloning term
            log.info("expert labels: %d read from %s", load_labels(buffer, labels_path), labels_path)
    if pretrain:
        if int(demos["pretrain_actor_steps"]) > 0:
            loss = pretrain_actor(model, int(demos["pretrain_actor_steps"]), progress=label("pre-training the actor"))
            log.info(
                "actor pre-trained on the demonstrations: %d steps, action MSE %.4f",
                int(demos["pretrain_actor_steps"]),
                loss,
            )
        if int(demos["takeover_rounds"]) > 0:
            _takeover_rounds(model, demos, make_demo_env, seed, show_progress)
        if int(demos["dagger_rounds"]) > 0:
            _dagger_rounds(model, demos, make_demo_env, seed, labels_path, show_progress)
        if int(demos["critic_warmup_steps"]) > 0:
            loss = warm_up_critic(model, int(demos["critic_warmup_steps"]), progress=label("warming up the critic"))
            log.info("critic warmed up: %d steps, loss %.4f", int(demos["critic_warmup_steps"]), loss)
