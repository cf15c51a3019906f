"""The navigation environment: a composer.Environment for a `Navigate` task, with a fast
build, a divergence that truncates, and actions checked before any physics runs."""

from __future__ import annotations

import numpy as np
from dm_control import composer
from dm_control.mujoco import wrapper

from cathsim_dmc.sim import model_cache
from cathsim_dmc.sim import physics as cs_physics


class NavigationEnvironment(composer.Environment):
    """composer.Environment that turns a physics divergence into a truncation.

    composer ends a diverged episode with discount 0 (as if terminal); a diverged
    simulation says nothing about the task, so the episode is cut with discount 1.

    Building is fast: an aorta built with ``hulls_in_mjcf=False`` gets its wall added
    to a `mujoco.MjSpec` of the compiled scene (see `Aorta.add_geoms`), the compiled
    model is cached as MJB (keyed by the scene, the wall and the MuJoCo version), and
    the model compiled here is kept for the first reset (composer compiles a second
    time otherwise; no entity changes its MJCF per episode).

    The physics is a `ConstraintSensingPhysics`, so that the task can average the wall
    force over each control step's physics steps (`StepInfo.mean_contact_force_n`).
    """

    def __init__(self, task, cache_models: bool = True, **kwargs):
        """`task`: a `Navigate`; `cache_models`: keep compiled models as MJB files; the
        other keyword arguments go to composer.Environment."""
        kwargs.setdefault("raise_exception_on_physics_error", False)
        kwargs.setdefault("strip_singleton_obs_buffer_dim", True)
        kwargs.setdefault("recompile_mjcf_every_episode", False)
        self._cache_models = bool(cache_models)
        super().__init__(task, **kwargs)
        if not kwargs["recompile_mjcf_every_episode"]:
            # No public switch: composer would compile again at the first reset (tests/test_upstream_internals.py).
            self._mjcf_never_compiled = False

    # composer builds its Physics here only, with no public way to choose the class or the compiled model.
    def _recompile_physics(self):
        aorta = self.task.aorta
        physics = getattr(self, "_physics", None)
        if physics:
            physics.free()
        root = self.task.root_entity.mjcf_model
        if aorta.hulls_in_mjcf:
            self._physics = cs_physics.ConstraintSensingPhysics.from_mjcf_model(root)
            self._physics.legacy_step = self._legacy_step
            return
        model = model_cache.compile_model(root, aorta.add_geoms, aorta.geoms_key, cache=self._cache_models)
        self._physics = cs_physics.ConstraintSensingPhysics.from_model(wrapper.MjModel(model))
        self._physics.legacy_step = self._legacy_step

    def step(self, action):
        """Steps with `action` = [insertion, rotation] (then the catheter's carriage, with a
        catheter), each in [-1, 1]; values outside are clipped.

        An action of another shape or with a NaN or infinite value raises ValueError before
        any physics runs, and the environment stays usable. A diverged simulation or an
        escaped wire ends the episode as a truncation (reward 0, discount 1).
        """
        timestep = super().step(validated_action(action, self.task.action_names))
        if (self.task.diverged or self.task.escaped) and timestep.last():
            timestep = timestep._replace(reward=0.0, discount=1.0)
        return timestep


def expected_action(names=("insertion", "rotation")) -> str:
    """What an action with entries `names` must be (the error messages' "expected ...")."""
    return f"shape ({len(names)},), finite, [{', '.join(names)}] in [-1, 1] (values outside are clipped)"


def validated_action(action, names=("insertion", "rotation")) -> np.ndarray:
    """`action` as a float64 array of shape (len(names),); ValueError naming the bad value otherwise."""
    expected = expected_action(names)
    try:
        raw = np.asarray(action)
        if raw.dtype.kind not in "iufO":
            raise TypeError
        array = raw.astype(np.float64)
    except (TypeError, ValueError):  # strings, ragged lists, objects that are not numbers
        raise ValueError(f"action={_one_line(action)} is not numeric; expected {expected}") from None
    if array.shape != (len(names),):
        raise ValueError(f"action={_one_line(action)} has shape {array.shape}; expected {expected}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"action={_one_line(action)} is not finite; expected {expected}")
    return array


def _one_line(value) -> str:
    if isinstance(value, np.ndarray):
        text = np.array2string(value, separator=", ", threshold=6, max_line_width=10**6)
    else:
        text = repr(value)
    text = " ".join(text.split())
    return text if len(text) <= 80 else text[:77] + "..."
