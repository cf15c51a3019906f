"""Observables the entities share: joint positions and velocities.

This module sits in the entities layer so that building an entity never loads the
image observables (`cathsim_dmc.sim.render`, with its raster renderer and GL set-up).
"""

from __future__ import annotations

from dm_control import composer
from dm_control.composer.observation import observable


class JointObservables(composer.Observables):
    """Positions and velocities of an entity's `joints` (the proprioception group)."""

    @composer.observable
    def joint_pos(self):
        return observable.MJCFFeature("qpos", self._entity.joints)

    @composer.observable
    def joint_vel(self):
        return observable.MJCFFeature("qvel", self._entity.joints)

    @property
    def proprioception(self):
        return [self.joint_pos, self.joint_vel]
