"""Demonstrations: expert transitions, and a replay buffer that mixes them into every batch.

    buffer = model.replay_buffer                  # a DemoReplayBuffer (see rl/train.py build_sac)
    add_transitions(buffer, expert_transitions(env, episodes=20, seed=0))

The mix is symmetric sampling as in RLPD (Ball et al., 2023): a fixed share of every
batch comes from the demonstrations, the rest from the agent's own experience, so the
expert's way to the target keeps its weight however much the agent has collected.
Demonstrations come from the privileged scripted expert run in the training environment
itself (same reward, same observations), so their rewards are what the agent would get.
How the agent learns from them (pre-training, the cloning term) is `cathsim_dmc.learning.rl.sacfd`.

SB3 checkpoints name `DemoReplayBuffer` by this module's path (their replay_buffer_class):
it stays here so that saved runs keep loading.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from stable_baselines3.common.buffers import DictReplayBuffer
from stable_baselines3.common.type_aliases import DictReplayBufferSamples


class DemoReplayBuffer(DictReplayBuffer):
    """A DictReplayBuffer whose batches take `demo_share` of their samples from demonstrations.

    It can also hold expert labels (`labels`): states the agent reached, each with the
    action the expert would have taken there (DAgger's data, `expert_labels`). They are not
    transitions (the expert's action was not taken), so only behavioural cloning reads them
    (`cloning_batch`); the critic never does.

    Args (beyond DictReplayBuffer's):
      demo_share: fraction of each batch drawn from the demonstrations (0.5 in RLPD).
      demo_capacity: most demonstration transitions kept.
      label_capacity: most expert labels kept (0: none).
    """

    labels = None  # buffers pickled before expert labels existed have none

    def __init__(
        self,
        buffer_size,
        observation_space,
        action_space,
        device="auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        demo_share: float = 0.5,
        demo_capacity: int = 20_000,
        label_capacity: int = 0,
    ):
        if not 0.0 <= demo_share <= 1.0:
            raise ValueError(f"demo_share={demo_share!r} must be in [0, 1]")
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            device=device,
            n_envs=n_envs,
            optimize_memory_usage=optimize_memory_usage,
            handle_timeout_termination=handle_timeout_termination,
        )
        self.demo_share = float(demo_share)
        self.demos = DictReplayBuffer(
            max(int(demo_capacity), 1),
            observation_space,
            action_space,
            device=device,
            n_envs=1,
            handle_timeout_termination=handle_timeout_termination,
        )
        self.labels = None
        if int(label_capacity) > 0:
            self.labels = DictReplayBuffer(
                int(label_capacity),
                observation_space,
                action_space,
                device=device,
                n_envs=1,
                handle_timeout_termination=False,
            )

    def label_count(self) -> int:
        return 0 if self.labels is None else self.labels.size()

    def cloning_batch(self, batch_size: int, env=None) -> tuple[dict, torch.Tensor]:
        """(observations, expert actions) for behavioural cloning: `batch_size` samples
        drawn uniformly from the demonstrations' states and the expert labels together."""
        labels = self.label_count()
        if labels == 0:
            data = self.demos.sample(batch_size, env)
            return data.observations, data.actions
        from_labels = int(np.random.binomial(batch_size, labels / (labels + self.demos.size())))
        parts = [
            buffer.sample(n, env)
            for buffer, n in ((self.demos, batch_size - from_labels), (self.labels, from_labels))
            if n > 0
        ]
        observations = {k: torch.cat([p.observations[k] for p in parts]) for k in parts[0].observations}
        return observations, torch.cat([p.actions for p in parts])

    def demo_batch_size(self, batch_size: int) -> int:
        """How many of `batch_size` samples come from the demonstrations."""
        if self.demos.size() == 0:
            return 0
        if self.size() == 0:
            return batch_size
        return int(round(self.demo_share * batch_size))

    def sample(self, batch_size: int, env=None) -> DictReplayBufferSamples:
        n_demo = self.demo_batch_size(batch_size)
        if n_demo == 0:
            return super().sample(batch_size, env)
        demo = self.demos.sample(n_demo, env)
        if n_demo == batch_size:
            return demo
        online = super().sample(batch_size - n_demo, env)
        return _concat(online, demo)


def _concat(a: DictReplayBufferSamples, b: DictReplayBufferSamples) -> DictReplayBufferSamples:
    def cat(x, y):
        if x is None:
            return None
        if isinstance(x, dict):
            return {k: torch.cat([x[k], y[k]]) for k in x}
        return torch.cat([x, y])

    return DictReplayBufferSamples(*(cat(x, y) for x, y in zip(a, b)))


@dataclass
class Transitions:
    """Demonstration transitions as arrays (observations as dicts of arrays)."""

    observations: dict
    next_observations: dict
    actions: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray  # reached the target (a true terminal state)
    truncated: np.ndarray  # cut by the time limit or a divergence
    episodes: int
    successes: int
    steps_taken: int = 0  # environment steps spent recording them (more than len() if not every step was kept)

    def __len__(self) -> int:
        return len(self.actions)


def expert_transitions(env, episodes: int, seed: int = 0, policy=None, progress: str | None = None) -> Transitions:
    """Roll out the scripted expert (or `policy(observation, env)`) in `env`, a `CathSimEnv`
    built like the training environment, for `episodes` episodes seeded `seed`, `seed + 1`...
    `progress` labels a progress bar over the episodes (None: none)."""
    from cathsim_dmc.control.expert import CenterlineExpert

    policy = policy or CenterlineExpert()
    return _rollouts(env, episodes, seed, lambda: lambda obs, env, step: (policy(obs, env), True), progress)


def takeover_transitions(
    env, student, episodes: int, seed: int = 0, max_student_steps: int = 200, progress: str | None = None, expert=None
) -> Transitions:
    """Demonstrations from where the student goes: in each episode `student(observation)`
    drives for a random number of steps (0 to `max_student_steps`, drawn from `seed`), then
    the scripted expert (or `expert`, a `CenterlineExpert`) takes over to the end of the
    episode. The expert's part is returned.

    These are DAgger's states (Ross et al., 2011) with the expert's own transitions: the
    states a student reaches with its own mistakes, which the expert's episodes from the
    start never visit, each with the expert's action, reward and next state, so that the
    critic can learn from them as well as the behavioural-cloning term. The student's part
    is not returned (`Transitions.episodes` counts every episode; the environment steps of
    both parts are in `Transitions.steps_taken`). `progress` labels a progress bar (None: none).
    """
    from cathsim_dmc.control.expert import CenterlineExpert

    expert = expert or CenterlineExpert()
    rng = np.random.default_rng(seed)

    def episode_policy():
        handover = int(rng.integers(0, int(max_student_steps) + 1))

        def act(obs, env, step):
            if step < handover:
                return student(obs), False
            if step == handover:
                expert.reset(env)  # the expert starts afresh from the student's state
            return expert(obs, env), True

        return act

    return _rollouts(env, episodes, seed, episode_policy, progress)


@dataclass
class Labels:
    """States an agent reached, each with the expert's action there (DAgger's data)."""

    observations: dict
    actions: np.ndarray
    episodes: int
    successes: int  # episodes in which the agent (not the expert) reached the target

    def __len__(self) -> int:
        return len(self.actions)


def expert_labels(env, student, episodes: int, seed: int = 0, progress: str | None = None, expert=None) -> Labels:
    """DAgger's data (Ross et al., 2011): `student(observation)` drives `episodes` episodes
    (seeds `seed`, `seed + 1`, ...) and the scripted expert (or `expert`), asked at every step, labels
    each state with the action it would take there. The expert follows the student's
    episode as if it were its own (its back-off and end-game counters run on), so a label
    is what the expert does from that state in that situation. `progress` labels a
    progress bar (None: none)."""
    from cathsim_dmc.control.expert import CenterlineExpert

    expert = expert or CenterlineExpert()
    observations, actions = [], []

    def act(obs, env, step):
        observations.append(obs)
        actions.append(np.asarray(expert(obs, env), dtype=np.float32))
        return student(obs), False

    driven = _rollouts(env, episodes, seed, lambda: act, progress)
    stacked = {k: np.stack([o[k] for o in observations]) for k in observations[0]} if observations else {}
    return Labels(
        stacked,
        np.stack(actions) if actions else np.zeros((0, *env.action_space.shape), np.float32),
        driven.episodes,
        driven.successes,
    )


def add_labels(buffer: DemoReplayBuffer, labels: Labels) -> None:
    """Store `labels` in the buffer's expert labels (the oldest go when it is full)."""
    if buffer.labels is None:
        raise ValueError("this buffer keeps no expert labels (label_capacity=0)")
    for i in range(len(labels)):
        obs = {k: v[i : i + 1] for k, v in labels.observations.items()}
        buffer.labels.add(obs, obs, labels.actions[i : i + 1], np.zeros(1, np.float32), np.zeros(1, bool), [{}])


def _rollouts(env, episodes: int, seed: int, make_policy, progress: str | None = None) -> Transitions:
    """Run `episodes` episodes (seeds `seed`, `seed + 1`, ...); `make_policy()` gives each
    episode's `act(observation, env, step) -> (action, record)`. Returns the recorded steps."""
    from tqdm import tqdm

    rows = {k: [] for k in ("obs", "next_obs", "action", "reward", "terminated", "truncated")}
    successes = steps_taken = 0
    for episode in tqdm(range(int(episodes)), desc=progress, unit="episode", disable=progress is None):
        obs, info = env.reset(seed=seed + episode)
        act, done, step = make_policy(), False, 0
        while not done:
            action, record = act(obs, env, step)
            action = np.asarray(action, dtype=np.float32)
            next_obs, reward, terminated, truncated, info = env.step(action)
            if record:
                for key, value in zip(rows, (obs, next_obs, action, reward, terminated, truncated)):
                    rows[key].append(value)
            obs, done, step = next_obs, terminated or truncated, step + 1
        successes += int(info["success"])
        steps_taken += step
    if not rows["obs"]:
        empty = {k: np.zeros((0, *space.shape), space.dtype) for k, space in env.observation_space.spaces.items()}
        return Transitions(
            empty,
            dict(empty),
            np.zeros((0, *env.action_space.shape), np.float32),
            np.zeros(0, np.float32),
            np.zeros(0, bool),
            np.zeros(0, bool),
            int(episodes),
            successes,
            steps_taken,
        )
    stack = lambda dicts: {k: np.stack([d[k] for d in dicts]) for k in dicts[0]}  # noqa: E731
    return Transitions(
        stack(rows["obs"]),
        stack(rows["next_obs"]),
        np.stack(rows["action"]),
        np.asarray(rows["reward"], dtype=np.float32),
        np.asarray(rows["terminated"]),
        np.asarray(rows["truncated"]),
        int(episodes),
        successes,
        steps_taken,
    )


def add_transitions(buffer: DemoReplayBuffer, transitions: Transitions) -> None:
    """Store `transitions` as demonstrations (SB3's timeout convention: a truncation is not a terminal)."""
    room = buffer.demos.buffer_size - buffer.demos.size()
    if len(transitions) > room:
        raise ValueError(
            f"{len(transitions):,} demonstration transitions do not fit in demos.capacity="
            f"{buffer.demos.buffer_size:,} ({room:,} free); raise demos.capacity"
        )
    for i in range(len(transitions)):
        done = bool(transitions.terminated[i] or transitions.truncated[i])
        buffer.demos.add(
            {k: v[i : i + 1] for k, v in transitions.observations.items()},
            {k: v[i : i + 1] for k, v in transitions.next_observations.items()},
            transitions.actions[i : i + 1],
            transitions.rewards[i : i + 1],
            np.array([done]),
            [{"TimeLimit.truncated": bool(transitions.truncated[i])}],
        )


def dataset_transitions(paths, task, observation_space, episodes: int | None = None) -> Transitions:
    """Demonstrations from `cathsim-collect` data (folders or trajectory files), rewarded
    by `task` (a `Navigate` built like the training one) from the recorded tip positions,
    so a dataset collected under any reward serves any training reward.

    `observation_space` (the training env's) names the observation keys to read; the
    dataset must hold them (cathsim-collect records every modality) at the same sizes.
    """
    from cathsim_dmc.learning.datasets import load_arrays

    keys = list(observation_space.spaces)
    obs_keys = [f"obs_{k}" for k in keys]
    row_keys = ["step", "tip_position_m", "success", "terminated", "truncated", "action"]
    after = load_arrays(paths, obs_keys + row_keys)
    before = load_arrays(paths, obs_keys, before_action=True)
    for key in keys:
        want, have = observation_space[key].shape, after[f"obs_{key}"].shape[1:]
        if tuple(want) != tuple(have):
            raise ValueError(
                f"the dataset's {key} has shape {tuple(have)} but the training environment's is "
                f"{tuple(want)}; collect the demonstrations again with this version"
            )
    episode = after["episode"]
    keep = np.ones(len(episode), dtype=bool)
    if episodes is not None:  # the first `episodes` episodes
        keep = np.isin(episode, np.unique(episode)[: int(episodes)])
    tip = after["tip_position_m"].astype(float)
    distance = np.array([task.distance_for_reward_m(p) for p in tip])
    # The distance before each step: the previous row's, or at the episode's start.
    previous = np.empty_like(distance)
    previous[1:] = distance[:-1]
    first = after["step"] == 1
    start_tips = _episode_start_tips(paths)
    previous[first] = [task.distance_for_reward_m(p) for p in start_tips[episode[first]]]
    rewards = np.array(
        [task.reward_for(p, d, bool(s)) for p, d, s in zip(previous, distance, after["success"])], dtype=np.float32
    )
    take = lambda arrays: {k: arrays[f"obs_{k}"][keep] for k in keys}  # noqa: E731
    chosen = np.unique(episode[keep])
    return Transitions(
        take(before),
        take(after),
        after["action"][keep].astype(np.float32),
        rewards[keep],
        after["terminated"][keep].astype(bool),
        after["truncated"][keep].astype(bool),
        len(chosen),
        int(after["terminated"][keep].sum()),
    )


def _episode_start_tips(paths) -> np.ndarray:
    """start_tip_position_m of every episode, in the global episode order of load_arrays."""
    from cathsim_dmc.learning.datasets import expand_paths, read_keys

    return np.concatenate(
        [read_keys(p, ("start_tip_position_m",))["start_tip_position_m"] for p in expand_paths(paths)]
    ).astype(float)
