"""The agent's replay buffer: its memory, checked before it is allocated, and its growth
when a resumed run is given a larger step budget."""

from __future__ import annotations

import numpy as np

from cathsim_dmc.core.checks import available_memory_bytes


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
            f"lower algo.buffer_size (at most ~{fits:,} here)"
        )
    return need


def grow_replay_buffer(model, capacity: int) -> None:
    """Give `model` a replay buffer of `capacity` transitions, keeping what it holds.

    A resumed run may have a larger step budget than the one its buffer was sized for.
    """
    old = model.replay_buffer
    if old is None or old.buffer_size * old.n_envs >= capacity:
        return
    from cathsim_dmc.learning.rl.demos import DemoReplayBuffer

    with_demos = isinstance(old, DemoReplayBuffer)
    # A DemoReplayBuffer keeps its demonstrations and expert labels (buffers of their own)
    # and its batch share.
    extra = dict(demo_share=old.demo_share, demo_capacity=1) if with_demos else {}
    new = type(old)(
        capacity,
        old.observation_space,
        old.action_space,
        device=old.device,
        n_envs=old.n_envs,
        handle_timeout_termination=old.handle_timeout_termination,
        **extra,
    )
    if with_demos:
        new.demos, new.labels = old.demos, getattr(old, "labels", None)
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
