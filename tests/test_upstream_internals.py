"""The private parts of dm_control that the package relies on, as the pinned dm-control
(1.0.50) has them: each test fails when an upstream release changes one.

* `composer.Environment._recompile_physics` (tasks/environment.py overrides it to build a
  `ConstraintSensingPhysics` from a cached compiled model) and `_mjcf_never_compiled`
  (cleared so that the first reset does not compile the model a second time);
* `mjcf.Physics._dirty` (cleared by `ConstraintSensingPhysics.complete_stepped_state`) and
  `engine.Physics._step_with_up_to_date_position_velocity` (the legacy step, which
  `ConstraintSensingPhysics` overrides to call back between its halves).
"""

import mujoco
import numpy as np
from dm_control import composer, mjcf

from cathsim_dmc.sim import physics as cs_physics


def _model() -> mjcf.RootElement:
    """A capsule on a slide and a hinge, driven by a velocity actuator, pressed into a plane."""
    root = mjcf.RootElement()
    root.worldbody.add("geom", type="plane", size=[1, 1, 0.1])
    body = root.worldbody.add("body", pos=[0, 0, 0.015])
    slide = body.add("joint", name="slide", type="slide", axis=[1, 0, 0])
    body.add("joint", name="hinge", type="hinge", axis=[0, 1, 0])
    body.add("geom", type="capsule", size=[0.02, 0.05], euler=[0, 90, 0], mass=0.1)
    root.actuator.add("velocity", name="drive", joint=slide, kv=1.0)
    return root


class _Arena(composer.Entity):
    def _build(self):
        self._root = _model()

    @property
    def mjcf_model(self):
        return self._root


def test_a_binding_write_sets_dirty_which_is_dirty_reads_and_a_read_forwards_only_while_set():
    root = _model()
    physics = mjcf.Physics.from_mjcf_model(root)
    body = root.worldbody.body[0]
    physics.forward()
    assert physics._dirty is False and physics.is_dirty is False
    physics.bind(root.find("joint", "slide")).qpos = [0.1]
    assert physics._dirty is True and physics.is_dirty is True
    # Cleared by hand, a binding read returns the state as it is, without mj_forward...
    physics._dirty = False
    assert not physics.is_dirty
    np.testing.assert_array_equal(physics.bind(body).xpos, [0, 0, 0.015])
    # ...set, it forwards the written position first.
    physics.mark_as_dirty()
    np.testing.assert_allclose(physics.bind(body).xpos, [0.1, 0, 0.015])
    assert physics._dirty is False


def test_the_legacy_step_is_step2_then_step1_in_the_private_method_step_calls():
    calls = []

    class Recording(mjcf.Physics):
        def _step_with_up_to_date_position_velocity(self, nstep=1):
            calls.append(nstep)
            super()._step_with_up_to_date_position_velocity(nstep)

    stepped = Recording.from_mjcf_model(_model())
    by_hand = mjcf.Physics.from_mjcf_model(_model())
    for physics in (stepped, by_hand):
        physics.data.ctrl[:] = 0.3
        physics.data.qvel[1] = 2.0
        physics.forward()
    assert stepped.legacy_step
    for _ in range(5):
        stepped.step()
        mujoco.mj_step2(by_hand.model.ptr, by_hand.data.ptr)
        mujoco.mj_step1(by_hand.model.ptr, by_hand.data.ptr)
    assert calls == [1] * 5
    for field in ("qpos", "qvel", "qacc", "xpos", "efc_force", "time"):
        np.testing.assert_array_equal(getattr(stepped.data, field), getattr(by_hand.data, field), err_msg=field)
    stepped.legacy_step = False
    stepped.step()
    assert calls == [1] * 5  # a non-legacy step (mj_step) does not go through it


def test_constraint_sensing_physics_calls_back_between_the_halves_and_steps_as_dm_control_does():
    sensed = cs_physics.ConstraintSensingPhysics.from_mjcf_model(_model())
    plain = mjcf.Physics.from_mjcf_model(_model())
    contacts = []
    sensed.after_constraint_solve = lambda physics: contacts.append(physics.data.ncon)
    for physics in (sensed, plain):
        physics.data.ctrl[:] = 0.3
        physics.forward()
    for _ in range(5):
        sensed.step()
        plain.step()
    assert len(contacts) == 5 and min(contacts) > 0
    for field in ("qpos", "qvel", "qacc", "efc_force"):
        np.testing.assert_array_equal(getattr(sensed.data, field), getattr(plain.data, field), err_msg=field)


def test_composer_builds_its_physics_in_recompile_physics_again_at_a_first_reset_unless_told_not_to():
    built = []

    class Recording(composer.Environment):
        def _recompile_physics(self):
            super()._recompile_physics()
            built.append(self._physics)

    env = Recording(composer.NullTask(_Arena()), recompile_mjcf_every_episode=False, legacy_step=True)
    assert len(built) == 1 and env.physics.model.ptr is built[0].model.ptr
    assert env._mjcf_never_compiled is True and env._legacy_step is True and built[0].legacy_step
    env.reset()  # the first reset compiles again...
    assert len(built) == 2 and env._mjcf_never_compiled is False
    env.reset()  # ...and no later one does
    assert len(built) == 2

    built.clear()
    env = Recording(composer.NullTask(_Arena()), recompile_mjcf_every_episode=False)
    env._mjcf_never_compiled = False  # what NavigationEnvironment does
    env.reset()
    env.reset()
    assert len(built) == 1 and env.physics.model.ptr is built[0].model.ptr
