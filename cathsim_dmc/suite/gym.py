"""Gymnasium adapter: ``gymnasium.make("cathsim_dmc/bca-type1-v0", obs="enn")``.

Observations are a Dict: images channel-first uint8 (1, H, W) as stable-baselines3
expects, vectors float32. ``terminated`` means the target was reached; ``truncated``
means the 300-step limit, a diverged simulation (``info["diverged"]``) or a wire that
left the anatomy (``info["escaped"]``). Actions are [insertion, rotation] in [-1, 1]
(values outside are clipped), with ``catheter=`` a third entry for the catheter's carriage
(``info["catheter_offset_m"]``: its tip behind the wire's); a wrong shape, NaN or inf
raises ValueError. The last step of an episode also has ``info["is_success"]`` (the
``success`` that ended it), from which stable-baselines3 logs ``rollout/success_rate``.
"""

from __future__ import annotations

import dataclasses

import gymnasium
import numpy as np
from gymnasium import spaces

from cathsim_dmc.core.registry import env_id

IMAGE_KEYS = ("pixels", "guidewire_mask", "roadmap_overlay")


class CathSimEnv(gymnasium.Env):
    """One (task, aorta) navigation environment behind the Gymnasium API."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        task: str = "bca",
        aorta: str = "type1",
        obs: str = "internal",
        render_mode: str | None = None,
        render_size: int = 480,
        **kwargs,
    ):
        from cathsim_dmc import tasks  # deferred: building the suite needs the assets

        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode={render_mode!r}; choose None or 'rgb_array'")
        from cathsim_dmc.sim.render import check_render_size

        self.render_mode = render_mode
        self._render_size = check_render_size("render_size", render_size)
        self._cameras = None
        self._env = tasks.load(task, aorta, obs=obs, **kwargs)
        self.task_name, self.aorta_name, self.obs_preset = task, aorta, obs
        self.observation_space = spaces.Dict(
            {key: _space(key, spec) for key, spec in self._env.observation_spec().items()}
        )
        self.action_space = _action_space(self._env.action_spec())
        self._needs_reset = True

    @property
    def dm_env(self):
        """The underlying composer environment."""
        return self._env

    @property
    def task(self):
        return self._env.task

    @property
    def physics(self):
        return self._env.physics

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        if seed is not None:
            self._env.random_state.seed(seed)
        timestep = self._env.reset()
        self._needs_reset = False
        return self._observation(timestep), self._info()

    def step(self, action):
        """Steps with `action` = [insertion, rotation], each in [-1, 1]; values outside are clipped.

        Raises RuntimeError before the first `reset` or after the episode ended, and
        ValueError for an action of another shape or with a NaN or inf value (checked
        before any physics runs; the environment stays usable).
        """
        if self._needs_reset:
            raise RuntimeError(
                "step() needs a running episode: call reset() first (at the start and after terminated or truncated)"
            )
        timestep = self._env.step(action)  # NavigationEnvironment validates the action
        terminated = bool(timestep.last() and timestep.discount == 0.0)
        truncated = bool(timestep.last() and not terminated)
        self._needs_reset = terminated or truncated
        info = self._info()
        if self._needs_reset:  # the Gymnasium/SB3 key of an episode's outcome (SB3 logs rollout/success_rate from it)
            info["is_success"] = info["success"]
        return self._observation(timestep), float(timestep.reward), terminated, truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        from cathsim_dmc.sim.render import CameraCache, video_frame

        if self._cameras is None:
            self._cameras = CameraCache()
        return video_frame(self._env.physics, self._render_size, cache=self._cameras)

    def close(self):
        if getattr(self, "_env", None) is not None:
            self._env.close()
            self._env = None

    def _observation(self, timestep):
        out = {}
        for key, value in timestep.observation.items():
            if key in IMAGE_KEYS:
                out[key] = np.ascontiguousarray(np.moveaxis(value, -1, 0))
            else:
                out[key] = np.asarray(value, dtype=np.float32).reshape(self.observation_space[key].shape)
        return out

    def _info(self):
        info = dataclasses.asdict(self._env.task.step_info(self._env.physics))
        info["step"] = self._env.task.step_count
        # The episode's anatomy: the aorta's name, or the drawn one with aorta="random".
        info["aorta"] = getattr(self._env, "anatomy_name", self.aorta_name)
        if self._env.task.catheter is not None:
            info["catheter_offset_m"] = self._env.task.catheter_offset_m
        return info


def make_registered(registered_id: str, **kwargs) -> CathSimEnv:
    """The entry point of the registered ids. An id names its task and aorta, so
    `gymnasium.make(id, task=..., aorta=...)` naming others is refused: the environment's
    `spec.id` would name one that it is not."""
    task, aorta = kwargs.get("task"), kwargs.get("aorta")
    if env_id(task, aorta) != registered_id:
        import gymnasium

        other = env_id(task, aorta)
        instead = (
            f"gymnasium.make({other!r})"
            if other in gymnasium.registry
            else f"CathSimEnv(task={task!r}, aorta={aorta!r})"
        )
        raise ValueError(
            f"{registered_id} is the {registered_id.split('/')[1].rsplit('-', 1)[0]} environment; "
            f"for task={task!r}, aorta={aorta!r} use {instead}"
        )
    return CathSimEnv(**kwargs)


def _action_space(spec):
    """The Box of a dm_env BoundedArray action spec: the task owns its action's bounds."""
    shape = tuple(spec.shape)
    low = np.broadcast_to(spec.minimum, shape).astype(spec.dtype)
    high = np.broadcast_to(spec.maximum, shape).astype(spec.dtype)
    return spaces.Box(low, high, shape=shape, dtype=spec.dtype)


def _space(key, spec):
    if key in IMAGE_KEYS:
        h, w, c = spec.shape
        return spaces.Box(0, 255, shape=(c, h, w), dtype=np.uint8)
    shape = spec.shape if spec.shape else (1,)
    # Unbounded on purpose (Gymnasium's checker warns about it): joint_pos holds the robot's
    # rotation, an unlimited hinge whose angle (rad) grows with every turn, and joint_vel
    # rates that a stiff wall contact or a diverging step can drive to any value; a finite
    # bound would be a claim the simulation does not keep.
    return spaces.Box(-np.inf, np.inf, shape=shape, dtype=np.float32)
