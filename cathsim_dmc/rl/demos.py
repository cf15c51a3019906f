"""Learning from demonstrations: expert transitions mixed into every SAC batch.

    buffer = model.replay_buffer                  # a DemoReplayBuffer (see build_sac)
    add_transitions(buffer, expert_transitions(make_env, episodes=20, seed=0))
    pretrain_actor(model, steps=2000)             # behavioural cloning of the actor's mean
    warm_up_critic(model, steps=1000)             # critic-only updates, actor fixed

The mix is symmetric sampling as in RLPD (Ball et al., 2023): a fixed share of every
batch comes from the demonstrations, the rest from the agent's own experience, so the
expert's way to the target keeps its weight however much the agent has collected.
Demonstrations come from the privileged scripted expert run in the training environment
itself (same reward, same observations), so their rewards are what the agent would get.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from stable_baselines3.common.buffers import DictReplayBuffer
from stable_baselines3.common.type_aliases import DictReplayBufferSamples


class DemoReplayBuffer(DictReplayBuffer):
    """A DictReplayBuffer whose batches take `demo_share` of their samples from demonstrations.

    Args (beyond DictReplayBuffer's):
      demo_share: fraction of each batch drawn from the demonstrations (0.5 in RLPD).
      demo_capacity: most demonstration transitions kept.
    """

    def __init__(self, buffer_size, observation_space, action_space, device="auto", n_envs: int = 1,
                 optimize_memory_usage: bool = False, handle_timeout_termination: bool = True,
                 demo_share: float = 0.5, demo_capacity: int = 50_000):
        if not 0.0 <= demo_share <= 1.0:
            raise ValueError(f"demo_share={demo_share!r} must be in [0, 1]")
        super().__init__(buffer_size, observation_space, action_space, device=device, n_envs=n_envs,
                         optimize_memory_usage=optimize_memory_usage,
                         handle_timeout_termination=handle_timeout_termination)
        self.demo_share = float(demo_share)
        self.demos = DictReplayBuffer(max(int(demo_capacity), 1), observation_space, action_space, device=device,
                                      n_envs=1, handle_timeout_termination=handle_timeout_termination)

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

    def __len__(self) -> int:
        return len(self.actions)


def expert_transitions(env, episodes: int, seed: int = 0, policy=None) -> Transitions:
    """Roll out the scripted expert (or `policy(observation, env)`) in `env`, a `CathSimEnv`
    built like the training environment, for `episodes` episodes seeded `seed`, `seed + 1`..."""
    from cathsim_dmc.experts import CenterlineExpert

    policy = policy or CenterlineExpert()
    rows = {k: [] for k in ("obs", "next_obs", "action", "reward", "terminated", "truncated")}
    successes = 0
    for episode in range(int(episodes)):
        obs, info = env.reset(seed=seed + episode)
        done = False
        while not done:
            action = np.asarray(policy(obs, env), dtype=np.float32)
            next_obs, reward, terminated, truncated, info = env.step(action)
            for key, value in zip(rows, (obs, next_obs, action, reward, terminated, truncated)):
                rows[key].append(value)
            obs, done = next_obs, terminated or truncated
        successes += int(info["success"])
    stack = lambda dicts: {k: np.stack([d[k] for d in dicts]) for k in dicts[0]}  # noqa: E731
    return Transitions(stack(rows["obs"]), stack(rows["next_obs"]), np.stack(rows["action"]),
                       np.asarray(rows["reward"], dtype=np.float32), np.asarray(rows["terminated"]),
                       np.asarray(rows["truncated"]), int(episodes), successes)


def add_transitions(buffer: DemoReplayBuffer, transitions: Transitions) -> None:
    """Store `transitions` as demonstrations (SB3's timeout convention: a truncation is not a terminal)."""
    for i in range(len(transitions)):
        done = bool(transitions.terminated[i] or transitions.truncated[i])
        buffer.demos.add({k: v[i:i + 1] for k, v in transitions.observations.items()},
                         {k: v[i:i + 1] for k, v in transitions.next_observations.items()},
                         transitions.actions[i:i + 1], transitions.rewards[i:i + 1], np.array([done]),
                         [{"TimeLimit.truncated": bool(transitions.truncated[i])}])


def pretrain_actor(model, steps: int, batch_size: int | None = None) -> float:
    """Behavioural cloning of the SAC actor on the demonstrations; returns the last loss.

    The loss is the squared error of the actor's deterministic action (tanh of the mean)
    against the expert's action; the log standard deviation is left to SAC's entropy term.
    """
    buffer = model.replay_buffer
    batch_size = int(batch_size or model.batch_size)
    actor = model.actor
    actor.set_training_mode(True)
    loss_value = float("nan")
    for _ in range(int(steps)):
        data = buffer.demos.sample(batch_size, env=model._vec_normalize_env)
        mean, _, _ = actor.get_action_dist_params(data.observations)
        loss = torch.nn.functional.mse_loss(torch.tanh(mean), data.actions)
        actor.optimizer.zero_grad()
        loss.backward()
        actor.optimizer.step()
        loss_value = float(loss.item())
    actor.set_training_mode(False)
    return loss_value


def warm_up_critic(model, steps: int, batch_size: int | None = None) -> float:
    """Critic-only SAC updates on the mixed buffer, the actor held fixed; returns the last loss.

    A critic trained against a pre-trained actor starts the actor's updates from values
    that already favour the expert's actions, instead of undoing the pre-training.
    """
    from stable_baselines3.common.utils import polyak_update

    batch_size = int(batch_size or model.batch_size)
    critic, target, actor = model.critic, model.critic_target, model.actor
    ent_coef = (torch.exp(model.log_ent_coef.detach()) if model.ent_coef_optimizer is not None
                else model.ent_coef_tensor)
    critic.set_training_mode(True)
    loss_value = float("nan")
    for _ in range(int(steps)):
        data = model.replay_buffer.sample(batch_size, env=model._vec_normalize_env)
        with torch.no_grad():
            next_actions, next_log_prob = actor.action_log_prob(data.next_observations)
            next_q = torch.min(torch.cat(target(data.next_observations, next_actions), dim=1), dim=1, keepdim=True)[0]
            next_q = next_q - ent_coef * next_log_prob.reshape(-1, 1)
            discounts = data.discounts if data.discounts is not None else model.gamma
            target_q = data.rewards + (1 - data.dones) * discounts * next_q
        loss = 0.5 * sum(torch.nn.functional.mse_loss(q, target_q) for q in critic(data.observations, data.actions))
        critic.optimizer.zero_grad()
        loss.backward()
        critic.optimizer.step()
        polyak_update(critic.parameters(), target.parameters(), model.tau)
        loss_value = float(loss.item())
    critic.set_training_mode(False)
    return loss_value
