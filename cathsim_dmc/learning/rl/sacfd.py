"""SAC from demonstrations (SACfD): the actor pre-trained on the expert's actions, the
critic warmed up on them, and a cloning term kept in the actor's loss.

    model = build_sac(env, algo, seed, device, None, demos)   # rl/train.py: an SACfD
    add_transitions(model.replay_buffer, expert_transitions(env, episodes=20, seed=0))
    pretrain_actor(model, steps=2000)             # behavioural cloning of the actor's mean
    warm_up_critic(model, steps=1000)             # critic-only updates, actor fixed

The demonstrations and the buffer that mixes them into every batch are `cathsim_dmc.learning.rl.demos`.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.utils import polyak_update

from cathsim_dmc.core.checks import check_number
from cathsim_dmc.learning.rl.demos import DemoReplayBuffer


def _steps(steps: int, progress: str | None):
    """range(steps), shown as a tqdm bar labelled `progress` (None: no bar)."""
    from tqdm import tqdm

    return tqdm(range(int(steps)), desc=progress, unit="update", mininterval=2.0, disable=progress is None)


def pretrain_actor(model, steps: int, batch_size: int | None = None, progress: str | None = None) -> float:
    """Behavioural cloning of the SAC actor on the demonstrations; returns the last loss.

    The loss is the squared error of the actor's deterministic action (tanh of the mean)
    against the expert's action, on the demonstrations' states and the expert labels
    (`DemoReplayBuffer.cloning_batch`); the log standard deviation is left to SAC's
    entropy term.
    `progress` labels a progress bar (None: none).
    """
    buffer = model.replay_buffer
    batch_size = int(batch_size or model.batch_size)
    actor = model.actor
    actor.set_training_mode(True)
    loss_value = float("nan")
    for _ in _steps(steps, progress):
        observations, actions = buffer.cloning_batch(batch_size, env=model._vec_normalize_env)
        mean, _, _ = actor.get_action_dist_params(observations)
        loss = torch.nn.functional.mse_loss(torch.tanh(mean), actions)
        actor.optimizer.zero_grad()
        loss.backward()
        actor.optimizer.step()
        loss_value = float(loss.item())
    actor.set_training_mode(False)
    return loss_value


def warm_up_critic(model, steps: int, batch_size: int | None = None, progress: str | None = None) -> float:
    """Critic-only SAC updates on the mixed buffer, the actor held fixed; returns the last loss.

    A critic trained against a pre-trained actor starts the actor's updates from values
    that already favour the expert's actions, instead of undoing the pre-training.
    `progress` labels a progress bar (None: none).
    """
    batch_size = int(batch_size or model.batch_size)
    ent_coef = torch.exp(model.log_ent_coef.detach()) if model.ent_coef_optimizer is not None else model.ent_coef_tensor
    model.critic.set_training_mode(True)
    loss_value = float("nan")
    for _ in _steps(steps, progress):
        data = model.replay_buffer.sample(batch_size, env=model._vec_normalize_env)
        loss = _critic_step(model, data, ent_coef)
        polyak_update(model.critic.parameters(), model.critic_target.parameters(), model.tau)
        loss_value = float(loss.item())
    model.critic.set_training_mode(False)
    return loss_value


def _critic_step(model, data, ent_coef) -> torch.Tensor:
    """One soft Bellman update of `model`'s twin critics on `data`; returns the loss."""
    with torch.no_grad():
        next_actions, next_log_prob = model.actor.action_log_prob(data.next_observations)
        next_q = torch.cat(model.critic_target(data.next_observations, next_actions), dim=1)
        next_q = next_q.min(dim=1, keepdim=True)[0] - ent_coef * next_log_prob.reshape(-1, 1)
        discounts = data.discounts if data.discounts is not None else model.gamma
        target_q = data.rewards + (1 - data.dones) * discounts * next_q
    loss = 0.5 * sum(torch.nn.functional.mse_loss(q, target_q) for q in model.critic(data.observations, data.actions))
    model.critic.optimizer.zero_grad()
    loss.backward()
    model.critic.optimizer.step()
    return loss


class SACfD(SAC):
    """SAC whose actor is also pulled towards the expert's actions on demonstration states.

    The actor's loss gains `bc_weight` x mean|Q| x the squared error between its
    deterministic action and the expert's, on every demonstration state of the batch
    (TD3+BC's term, Fujimoto and Gu, 2021): it keeps the actor near the expert even where
    the critic overrates the actor's own action. With expert labels in the buffer (DAgger's
    states, `rl.demos.expert_labels`) the term is taken on as many states drawn from the
    demonstrations and the labels together. With `bc_weight` 0 this is plain SAC.

    With `actor_average_tau` > 0 it also keeps an exponential moving average of the
    actor's weights (each update moves it `actor_average_tau` of the way to the current
    actor: about 1/tau updates of memory), which `averaged_actor()` swaps in, e.g. for
    deterministic evaluation: the averaged policy does not follow every swing of the
    critic (weight averaging in RL: Nikishin et al., 2018).

    :param bc_weight: strength of the cloning term, in units of the critic's mean |Q|
        (0: plain SAC); it needs a `DemoReplayBuffer`
    :param actor_average_tau: rate of the actor's weight average, in [0, 1] (0: none)
    :param args: SB3's SAC arguments
    :param kwargs: SB3's SAC arguments
    """

    def __init__(self, *args, bc_weight: float = 0.0, actor_average_tau: float = 0.0, **kwargs):
        self.bc_weight = float(bc_weight)
        if not 0.0 <= float(actor_average_tau) <= 1.0:
            raise ValueError(f"actor_average_tau={actor_average_tau!r} must be within [0, 1] (0: no average)")
        self.actor_average_tau = float(actor_average_tau)
        self._actor_average = None  # name -> tensor, like actor.state_dict()
        self._actor_refills = False
        super().__init__(*args, **kwargs)

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        self._train_steps(gradient_steps, batch_size)
        self._update_actor_average(gradient_steps)

    def _sample_action(self, learning_starts: int, action_noise=None, n_envs: int = 1):
        # During a refill after a resume the actor acts from the first step: SB3 would take
        # uniform random actions until learning_starts.
        return super()._sample_action(0 if self._actor_refills else learning_starts, action_noise, n_envs)

    def refill_before_training(self, steps: int) -> None:
        """No update for the next `steps` environment steps, while the current actor refills
        the replay buffer: for a run resumed without its buffer, whose first updates would
        otherwise draw every batch from the first few transitions."""
        self.learning_starts = self.num_timesteps + check_number("steps", steps, 0, whole=True)
        self._actor_refills = True

    def _update_actor_average(self, gradient_steps: int) -> None:
        if self.actor_average_tau <= 0:
            return
        current = self.actor.state_dict()
        if self._actor_average is None:
            self._actor_average = {k: v.detach().clone() for k, v in current.items()}
            return
        rate = 1.0 - (1.0 - self.actor_average_tau) ** gradient_steps
        with torch.no_grad():
            for key, value in current.items():
                if value.dtype.is_floating_point:
                    self._actor_average[key].lerp_(value, rate)
                else:
                    self._actor_average[key].copy_(value)

    @property
    def actor_average(self) -> dict | None:
        """The actor's averaged weights (name -> tensor, like `actor.state_dict()`), or None
        (no average: `actor_average_tau` 0, or no update yet)."""
        return self._actor_average

    @contextmanager
    def averaged_actor(self):
        """Within the block the actor holds its averaged weights (unchanged without an average)."""
        if self._actor_average is None:
            yield self
            return
        current = {k: v.detach().clone() for k, v in self.actor.state_dict().items()}
        self.actor.load_state_dict(self._actor_average)
        try:
            yield self
        finally:
            self.actor.load_state_dict(current)

    def _train_steps(self, gradient_steps: int, batch_size: int) -> None:
        buffer = self.replay_buffer
        n_demo = buffer.demo_batch_size(batch_size) if isinstance(buffer, DemoReplayBuffer) else 0
        if self.bc_weight <= 0 or n_demo == 0:
            return super().train(gradient_steps, batch_size)
        self._train_with_cloning(gradient_steps, batch_size, n_demo)

    def _train_with_cloning(self, gradient_steps: int, batch_size: int, n_demo: int) -> None:
        """SB3 2.9's `SAC.train` with the cloning term on `n_demo` states in the actor's loss
        (0: none, and then the same updates as `SAC.train`'s, bit for bit)."""
        # A copy, as SAC.train has no hook into the actor's loss; tests/test_learning.py fails when they part.
        buffer = self.replay_buffer
        self.policy.set_training_mode(True)
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        if self.ent_coef_optimizer is not None:
            optimizers.append(self.ent_coef_optimizer)
        self._update_learning_rate(optimizers)
        stats = {k: [] for k in ("critic_loss", "actor_loss", "bc_loss", "ent_coef")}
        for step in range(gradient_steps):
            data = buffer.sample(batch_size, env=self._vec_normalize_env)
            # The batch is online first, demonstrations last (DemoReplayBuffer.sample).
            demo = slice(batch_size - n_demo, batch_size)
            actions_pi, log_prob = self.actor.action_log_prob(data.observations)
            log_prob = log_prob.reshape(-1, 1)
            if self.ent_coef_optimizer is not None:
                ent_coef = torch.exp(self.log_ent_coef.detach())
                ent_loss = -(self.log_ent_coef * (log_prob + self.target_entropy).detach()).mean()
                self.ent_coef_optimizer.zero_grad()
                ent_loss.backward()
                self.ent_coef_optimizer.step()
            else:
                ent_coef = self.ent_coef_tensor
            critic_loss = _critic_step(self, data, ent_coef)

            q_pi = torch.cat(self.critic(data.observations, actions_pi), dim=1).min(dim=1, keepdim=True)[0]
            actor_loss = loss = (ent_coef * log_prob - q_pi).mean()
            if n_demo:
                if buffer.label_count():  # the cloning term also covers the expert labels' states
                    demo_obs, demo_actions = buffer.cloning_batch(n_demo, env=self._vec_normalize_env)
                else:
                    demo_obs, demo_actions = {k: v[demo] for k, v in data.observations.items()}, data.actions[demo]
                mean, _, _ = self.actor.get_action_dist_params(demo_obs)
                deterministic = torch.tanh(mean)
                bc_loss = ((deterministic - demo_actions) ** 2).sum(dim=1).mean()
                # Scaled by the critic's magnitude (as TD3+BC does), so that bc_weight means the
                # same whatever the reward's scale.
                loss = actor_loss + self.bc_weight * q_pi.abs().mean().detach() * bc_loss
                stats["bc_loss"].append(float(bc_loss.item()))
            self.actor.optimizer.zero_grad()
            loss.backward()
            self.actor.optimizer.step()
            if step % self.target_update_interval == 0:
                polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
                polyak_update(self.batch_norm_stats, self.batch_norm_stats_target, 1.0)
            for key, value in (("critic_loss", critic_loss), ("actor_loss", actor_loss), ("ent_coef", ent_coef)):
                stats[key].append(float(value.item()))
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        for key, values in stats.items():
            if values:
                self.logger.record(f"train/{key}", float(np.mean(values)))
