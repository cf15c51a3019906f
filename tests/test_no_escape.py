"""The wire never leaves the vessel, whatever the actions (issue: no wall escape).

Escape = a wire point (segment end, segment centre or the tip) outside both the lumen
(by more than the wire radius plus 0.5 mm of wall compliance) and the robot's guide
channel and introducer sheath (which ends inside the lumen): the task's `containment`,
checked on the whole wire, also below the entry plane.
"""

import numpy as np
import pytest
from shipped import aorta_params

from cathsim_dmc import tasks
from cathsim_dmc.anatomy.containment import Containment
from cathsim_dmc.control.policies import AdversarialPolicy
from cathsim_dmc.core.shipped import available_aortas


class EscapeMonitor:
    def __init__(self):
        self.escapes = 0
        self.first = None  # (step, point in mm) of the first escaped point

    def check(self, env, step):
        task = env.task
        points = task.wire_points_m(env.physics)
        outside = points[~task.containment.contains(points)]
        # The task saw the same points and truncated the episode.
        assert task.escaped == bool(len(outside))
        if len(outside) and self.first is None:
            self.first = (step, np.round(outside[0] * 1e3, 1))
        self.escapes += len(outside)

    def message(self):
        step, point = self.first
        return f"{self.escapes} wire points escaped; the first at step {step}, at {point} mm"


def _run(aorta, random_steps, max_steps, seed=0):
    env = tasks.load("bca", aorta, seed=seed, max_steps=random_steps + max_steps + 1)
    env.reset()
    monitor = EscapeMonitor()
    rng = np.random.default_rng(seed)
    actions = list(rng.uniform(-1, 1, (random_steps, 2))) + [np.array([1.0, 1.0])] * max_steps
    for step, action in enumerate(actions, 1):
        timestep = env.step(action)
        assert not env.task.diverged, "simulation diverged"
        assert np.all(np.isfinite(env.physics.data.qpos))
        monitor.check(env, step)
        if timestep.last():
            env.reset()
    return monitor, env


# The oblique arches run with -m slow (tests/shipped.py), as in the long test below.
@pytest.mark.parametrize("aorta", aorta_params())
def test_no_escape_short(aorta):
    monitor, _ = _run(aorta, random_steps=150, max_steps=100)
    assert monitor.escapes == 0, monitor.message()


@pytest.mark.parametrize("aorta", aorta_params())
def test_divergence_truncates(aorta):
    monitor, env = _run(aorta, random_steps=20, max_steps=0)
    assert monitor.escapes == 0, monitor.message()
    # A blown-up state ends the episode as a truncation without a reward (the dense reward
    # would be minus a distance), and the next reset works.
    env.physics.data.qvel[:] = np.nan
    timestep = env.step(np.array([1.0, 0.0]))
    assert timestep.last() and timestep.discount == 1.0 and env.task.diverged
    assert timestep.reward == 0.0 and not env.task.success
    env.reset()
    assert env.step(np.array([1.0, 0.0])).mid() and not env.task.diverged


def test_escape_truncates():
    """An escaped wire ends the episode as a truncation (reward 0, discount 1) and the next reset works."""
    env = tasks.load("bca", "type1", seed=0)
    env.reset()
    task = env.task
    allowed = task.containment
    # Tighter than the real check: no introducer, so the wire in the guide channel is out.
    task._containment = Containment(allowed.field, allowed.tolerance_m, channels=())
    timestep = env.step(np.array([1.0, 0.0]))
    assert timestep.last() and timestep.reward == 0.0 and timestep.discount == 1.0
    assert task.escaped and task.step_info(env.physics).escaped and not task.diverged and not task.success
    task._containment = allowed
    env.reset()
    timestep = env.step(np.array([1.0, 0.0]))
    assert timestep.mid() and not task.escaped and not task.step_info(env.physics).escaped


# Before the introducer sheath the wire bowed out of the unguided 15 mm between the
# guide channel's outlet and the vessel's open end (the short test escaped in every aorta
# at steps 181-244); the sheath and seal close that gap. The full protocol (10^5
# adversarial steps per aorta) is experiments/force_distribution.py, its output in docs/model.md.
@pytest.mark.slow
@pytest.mark.parametrize("aorta", available_aortas())
def test_no_escape_reproduction_and_adversarial_bursts(aorta):
    """Issue 17's reproduction (500 uniform random steps, then 500 of full insertion and
    rotation, in one episode) followed by 1,000 steps of adversarial bursts: 2,000 steps."""
    monitor, env = _run(aorta, random_steps=500, max_steps=500)
    policy = AdversarialPolicy(seed=1)
    env.reset()
    for step in range(1, 1001):
        timestep = env.step(policy())
        assert not env.task.diverged and np.all(np.isfinite(env.physics.data.qpos))
        monitor.check(env, 1000 + step)
        if timestep.last():
            env.reset()
    assert monitor.escapes == 0, monitor.message()
