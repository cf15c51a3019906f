"""The wire never leaves the vessel, whatever the actions (issue: no wall escape).

Escape = a wire segment centre or the tip outside the lumen surface by more than the
wire radius plus 0.5 mm of allowed wall compliance. Points below the entry sit in the
introducer, outside the anatomy by design, and are not checked.
"""

import numpy as np
import pytest
import trimesh

from cathsim_dmc import tasks
from cathsim_dmc.paths import available_aortas

ALLOWED_PENETRATION_M = 0.5e-3


class EscapeMonitor:
    def __init__(self, env):
        task = env.task
        asset = task.aorta.asset
        # trimesh's closest-point tolerances are absolute: query in millimetres.
        self._lumen_mm = trimesh.Trimesh(asset.visual_vertices * 1e3, asset.visual_faces, process=False)
        self._entry_y = task.aorta.entry_position_m[1]
        self._segments = env.physics.bind(task.guidewire.segments)
        self._radius = task.guidewire.radius_m
        self.worst_outside_m = -np.inf
        self.escapes = 0

    def check(self, env):
        points = np.vstack([self._segments.xpos, env.task.tip_position_m(env.physics)])
        points = points[points[:, 1] > self._entry_y]
        if not len(points):
            return
        inside = self._lumen_mm.contains(points * 1e3)
        outside = points[~inside]
        if len(outside):
            _, distance_mm, _ = trimesh.proximity.closest_point(self._lumen_mm, outside * 1e3)
            depth = distance_mm.max() * 1e-3
            self.worst_outside_m = max(self.worst_outside_m, depth)
            # A segment centre may sit up to one wire radius plus the compliance past the surface.
            self.escapes += int((distance_mm * 1e-3 > self._radius + ALLOWED_PENETRATION_M).sum())


def _run(aorta, random_steps, max_steps, seed=0):
    env = tasks.load("bca", aorta, seed=seed, max_steps=random_steps + max_steps + 1)
    env.reset()
    monitor = EscapeMonitor(env)
    rng = np.random.default_rng(seed)
    actions = list(rng.uniform(-1, 1, (random_steps, 2))) + [np.array([1.0, 1.0])] * max_steps
    for action in actions:
        timestep = env.step(action)
        assert not env.task.diverged, "simulation diverged"
        assert np.all(np.isfinite(env.physics.data.qpos))
        monitor.check(env)
        if timestep.last():
            env.reset()
    return monitor, env


@pytest.mark.parametrize("aorta", available_aortas())
def test_no_escape_short_then_divergence_truncates(aorta):
    monitor, env = _run(aorta, random_steps=150, max_steps=100)
    assert monitor.escapes == 0, f"worst point {monitor.worst_outside_m * 1e3:.2f} mm outside the lumen"
    # A blown-up state ends the episode as a truncation, and the next reset works.
    env.physics.data.qvel[:] = np.nan
    timestep = env.step(np.array([1.0, 0.0]))
    assert timestep.last() and timestep.discount == 1.0 and env.task.diverged
    env.reset()
    assert env.step(np.array([1.0, 0.0])).mid() and not env.task.diverged


@pytest.mark.slow
@pytest.mark.parametrize("aorta", available_aortas())
def test_no_escape_long(aorta):
    """The issue's protocol: 10,000 random steps, then 300 at full insertion and rotation."""
    monitor, _ = _run(aorta, random_steps=10_000, max_steps=300)
    print(f"\n{aorta}: worst point {monitor.worst_outside_m * 1e3:.2f} mm outside the lumen "
          f"(allowed {(monitor._radius + ALLOWED_PENETRATION_M) * 1e3:.3f})")
    assert monitor.escapes == 0, f"worst point {monitor.worst_outside_m * 1e3:.2f} mm outside the lumen"
