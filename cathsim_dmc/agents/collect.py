"""Demonstration datasets for behavioural cloning and force prediction (cathsim-collect).

A dataset is a folder:

    manifest.json        what was collected (task, aorta, policy, seed, observation preset,
                         image options, episodes per shard) and the counts so far
    shard_00000.npz      episodes 0 .. k-1, one trajectory file (schema in
    shard_00001.npz      cathsim_dmc/evaluation/trajectory.py) with every observation of the `enn`
    ...                  preset, the reset observations and, for an ENN policy, Z

Each shard holds `episodes_per_shard` whole episodes, so no array ever holds the whole
dataset while collecting; shards are uncompressed (a reader loads one key of one shard
without decompressing the rest) and written to a temporary name, then renamed. Episode
`e` is reset with seed `seed + e`, so a second run into the same folder skips the
finished shards and produces exactly the episodes a single run would have.
"""

from __future__ import annotations

import json
import logging
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from cathsim_dmc.core.run_files import remove_temporaries, write_atomic
from cathsim_dmc.evaluation.trajectory import SCHEMA_VERSION, TrajectoryRecorder, action_rows
from cathsim_dmc.learning.datasets import MANIFEST, read_manifest

log = logging.getLogger("cathsim-collect")

SHARD_FORMAT = "shard_{:05d}.npz"
COLLECT_OBS = "enn"  # every modality: the image, the mask and the joint state
# Settings that must match when a run continues an existing dataset (the episode count
# may grow: the new episodes go into new shards).
_SAME_ON_RESUME = (
    "task",
    "aorta",
    "policy",
    "seed",
    "episodes_per_shard",
    "obs",
    "image_options",
    "task_options",
    "action_noise_std",
)
_RESUME_DEFAULTS = {"action_noise_std": 0.0}  # settings older datasets did not record


@dataclass
class FeatureRecorder(TrajectoryRecorder):
    """A TrajectoryRecorder that also stores `feature_fn(observation)` per step as `feature_z`."""

    feature_fn: Callable | None = None
    features: list = field(default_factory=list)
    start_features: list = field(default_factory=list)
    clean_action_fn: Callable | None = None  # the policy's own action, before exploration noise
    clean_actions: list = field(default_factory=list)

    def start_episode(self, tip_position_m, optimal_path_length_m: float, observation=None, **episode) -> None:
        super().start_episode(tip_position_m, optimal_path_length_m, observation, **episode)
        if self.feature_fn is not None and observation is not None:
            self.start_features.append(self.feature_fn(observation))

    def record(self, action, reward, info, terminated, truncated, observation=None) -> None:
        super().record(action, reward, info, terminated, truncated, observation)
        if self.feature_fn is not None and observation is not None:
            self.features.append(self.feature_fn(observation))
        if self.clean_action_fn is not None:
            self.clean_actions.append(self.clean_action_fn())

    def arrays(self) -> dict:
        out = super().arrays()
        if self.features:
            out["feature_z"] = np.stack(self.features).astype(np.float32)
            out["start_feature_z"] = np.stack(self.start_features).astype(np.float32)
        if self.clean_action_fn is not None:
            out["expert_action"] = action_rows(np.asarray(self.clean_actions, dtype=np.float32), width=2)
        return out


class NoisyPolicy:
    """Executes the policy's action plus Gaussian noise, remembers the clean one.

    Demonstrations with injected noise (DART, Laskey et al. 2017): the closed-loop expert
    is pushed off its own path and shows how to recover, which a cloned student needs
    once its own small errors take it there. The clean action is the label.
    """

    def __init__(self, policy, std: float, seed):
        self.policy, self.std = policy, float(std)
        self._rng = np.random.default_rng(seed)
        self.last_clean = None

    def __call__(self, observation, env):
        self.last_clean = np.asarray(self.policy(observation, env), dtype=np.float32)
        noise = self._rng.normal(0.0, self.std, size=self.last_clean.shape)
        return np.clip(self.last_clean + noise, -1.0, 1.0).astype(np.float32)


def enn_feature_fn(model, observation_keys):
    """Z for an SB3 SAC model whose actor uses the ENN extractor, else None.

    Z is the actor's features-extractor output: what the policy head acts on.
    """
    import torch

    from cathsim_dmc.learning.networks import ENNExtractor

    actor = getattr(model, "actor", None)
    if actor is None or not isinstance(getattr(actor, "features_extractor", None), ENNExtractor):
        return None

    def features(observation):
        obs = {k: observation[k] for k in observation_keys}
        with torch.no_grad():
            tensor, _ = model.policy.obs_to_tensor(obs)
            z = actor.extract_features(tensor, actor.features_extractor)
        return z[0].cpu().numpy()

    return features


def collection_policy(name: str, seed: int, task: str | None = None):
    """(policy, feature_fn or None, label, image options, env options) for a built-in name or
    a checkpoint; a checkpoint's image and env options are the ones it was trained with."""
    from cathsim_dmc.agents.trained import CheckpointPolicy, make_policy
    from cathsim_dmc.tasks.presets import OBSERVATION_PRESETS

    policy = make_policy(name, seed=seed, task=task)
    if not isinstance(policy, CheckpointPolicy):
        return policy, None, name, {}, {}
    # The dataset records every modality; the agent sees only what it was trained on.
    keys = sorted(
        OBSERVATION_PRESETS[policy.obs_preset].enabled | set(policy.env_options.get("extra_observations", ()))
    )

    def act(observation, env):
        return policy({k: observation[k] for k in keys}, env)

    return act, enn_feature_fn(policy.model, keys), Path(name).name, policy.image_options, policy.env_options


def shard_info(path) -> dict | None:
    """Episode, sample and success counts of a finished shard; None if unreadable."""
    try:
        with np.load(path, allow_pickle=False) as data:
            if int(data["schema_version"]) != SCHEMA_VERSION:
                return None
            episodes = int(data["start_tip_position_m"].shape[0])
            episode, terminated = data["episode"], data["terminated"]
            return {
                "file": Path(path).name,
                "first_episode": int(data["first_episode"]),
                "episodes": episodes,
                "samples": int(len(episode)),
                "successes": int(len(np.unique(episode[terminated]))),
            }
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):  # truncated by a kill: recorded again
        return None


def _write_manifest(out_dir: Path, settings: dict, shards: list) -> dict:
    manifest = {
        "format": "cathsim-collect",
        "schema_version": SCHEMA_VERSION,
        **settings,
        "episodes": sum(s["episodes"] for s in shards),
        "samples": sum(s["samples"] for s in shards),
        "successes": sum(s["successes"] for s in shards),
        "shards": shards,
    }
    write_atomic(out_dir / MANIFEST, lambda tmp: tmp.write_text(json.dumps(manifest, indent=2)))
    return manifest


def collect(
    out_dir,
    task: str,
    aorta: str,
    policy: str,
    episodes: int,
    episodes_per_shard: int,
    seed: int,
    task_options: dict | None = None,
    image_options: dict | None = None,
    show_progress: bool = True,
    action_noise_std: float = 0.0,
) -> dict:
    """Collect (or continue collecting) `episodes` episodes into shards under `out_dir`.

    With `action_noise_std` > 0 the executed action is the policy's plus seeded Gaussian
    noise (clipped to [-1, 1]), and the policy's clean action is stored as `expert_action`.
    """
    from tqdm import tqdm

    from cathsim_dmc.agents.trained import check_catheter
    from cathsim_dmc.control.policies import BUILTIN_POLICIES
    from cathsim_dmc.evaluation.rollouts import run_episodes
    from cathsim_dmc.suite.gym import CathSimEnv

    if episodes < 1:
        raise ValueError(f"episodes={episodes} must be at least 1")
    if episodes_per_shard < 1:
        raise ValueError(f"episodes_per_shard={episodes_per_shard} must be at least 1")
    if not action_noise_std >= 0:
        raise ValueError(f"action_noise_std={action_noise_std} must be >= 0")
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"out={str(out_dir)!r} is a file; name a dataset folder (new, or one to continue)")
    act, feature_fn, label, policy_images, policy_options = collection_policy(policy, seed, task)
    if policy not in BUILTIN_POLICIES:  # a trained agent: it drives what it was trained with
        check_catheter(policy, (task_options or {}).get("catheter"), policy_options)
    images = {**(image_options or {}), **policy_images}
    # A trained agent drives with what it was trained with (insertion limit, extra
    # observations), as cathsim-eval evaluates it.
    task_options = {**(task_options or {}), **policy_options}
    settings = {
        "task": task,
        "aorta": aorta,
        "policy": label,
        "seed": seed,
        "episodes_per_shard": episodes_per_shard,
        "obs": COLLECT_OBS,
        "image_options": images,
        "task_options": task_options,
        "feature_z": feature_fn is not None,
        "action_noise_std": float(action_noise_std),
    }
    manifest_path = out_dir / MANIFEST
    if manifest_path.is_file():
        old = read_manifest(manifest_path)
        for key in _SAME_ON_RESUME:
            # Compared as JSON holds them (a tuple of extra observations reads back as a list).
            if old.get(key, _RESUME_DEFAULTS.get(key)) != json.loads(json.dumps(settings[key])):
                raise ValueError(
                    f"{out_dir} holds a dataset collected with {key}={old.get(key)!r}, not "
                    f"{settings[key]!r}; continue it with the same settings or choose another out folder"
                )
    out_dir.mkdir(parents=True, exist_ok=True)
    remove_temporaries(out_dir)  # half-written shards of a killed collection

    counts = [min(episodes_per_shard, episodes - first) for first in range(0, episodes, episodes_per_shard)]
    done = {}
    for index, count in enumerate(counts):
        info = shard_info(out_dir / SHARD_FORMAT.format(index))
        if info is not None and info["episodes"] == count:
            done[index] = info
    manifest = _write_manifest(out_dir, settings, [done[i] for i in sorted(done)])
    if len(done) == len(counts):
        log.info("all %d episodes already collected in %s", episodes, out_dir)
        return manifest

    env = CathSimEnv(task=task, aorta=aorta, obs=COLLECT_OBS, **images, **task_options)
    bar = tqdm(
        total=episodes,
        initial=sum(d["episodes"] for d in done.values()),
        unit="episode",
        desc="collecting",
        disable=not show_progress,
    )
    try:
        for index, count in enumerate(counts):
            if index in done:
                continue
            first = index * episodes_per_shard
            shard_policy, clean = act, None
            if action_noise_std > 0:  # seeded per shard, so a resumed run repeats it
                shard_policy = NoisyPolicy(act, action_noise_std, (seed, first))
                clean = lambda p=shard_policy: p.last_clean  # noqa: E731
            recorder = FeatureRecorder(
                task,
                aorta,
                env.task.target_position_m,
                policy=label,
                record_observations=True,
                safe_force_n=env.task.safe_force_n,
                feature_fn=feature_fn,
                clean_action_fn=clean,
            )
            run_episodes(env, shard_policy, count, seed + first, recorder, show_progress=False)
            path = out_dir / SHARD_FORMAT.format(index)
            recorder.save(path, compress=False, first_episode=np.int32(first))
            done[index] = shard_info(path)
            manifest = _write_manifest(out_dir, settings, [done[i] for i in sorted(done)])
            bar.update(count)
            bar.set_postfix(samples=manifest["samples"], success=f"{manifest['successes']}/{manifest['episodes']}")
    finally:
        bar.close()
        env.close()
    return manifest
