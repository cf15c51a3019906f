"""Each entity alone, and all three in a user's own composer task."""

import numpy as np
import pytest
from dm_control import composer

import cathsim_dmc  # noqa: F401  (selects the GL backend before dm_control renders)
from cathsim_dmc.entities import Aorta, FollowerRobot, Guidewire, TargetMarker
from cathsim_dmc.sim.arena import OperatingArena


def _compile_alone(entity):
    arena = OperatingArena()
    arena.attach(entity)
    env = composer.Environment(composer.NullTask(arena))
    env.reset()
    return env


@pytest.mark.parametrize("factory", [Guidewire, FollowerRobot, TargetMarker, lambda: Aorta("type1")])
def test_entity_compiles_alone(factory):
    entity = factory()
    env = _compile_alone(entity)
    assert env.physics.model.ngeom > 0
    env.physics.step()
    assert np.all(np.isfinite(env.physics.data.qpos))


def test_guidewire_structure_and_rest_shape():
    wire = Guidewire(n_segments=20, n_tip_segments=8, tip_angle_deg=60.0)
    assert len(wire.segments) == 28
    assert len(wire.joints) == 2 * 27  # two bending hinges between neighbours
    # The tip's rest angles add up to the configured bend, the shaft is straight.
    assert np.isclose(wire.rest_qpos.sum(), np.radians(60.0))
    assert np.count_nonzero(wire.rest_qpos[: 2 * 19]) == 0
    # Stiffness comes from the material: k = E I / l, l the rod length per joint.
    inertia = np.pi * wire.core_diameter_m**4 / 64
    shaft_spacing = wire.segment_lengths_m[1]
    assert np.isclose(wire.joint_stiffness[0], 40e9 * inertia / shaft_spacing)
    assert np.isclose(wire.segment_lengths_m.sum(), wire.length_m)


def test_guidewire_rejects_bad_shape():
    with pytest.raises(ValueError, match="tip_shape"):
        Guidewire(tip_shape="pigtail")


class _UserTask(composer.Task):
    """What a researcher writes: our entities in their own arena and task."""

    def __init__(self):
        self._arena = composer.Arena()
        self._aorta = Aorta("type1")
        self._arena.attach(self._aorta)
        self.wire = Guidewire(length_m=0.3, n_segments=30, n_tip_segments=6, tip_shape="j", tip_angle_deg=150)
        self.robot = FollowerRobot(wire_length_m=0.3, stroke_m=0.2, max_insertion_speed_m_s=0.02)
        frame = self._arena.attach(self.robot)
        # The sheath's tip (the robot's origin) into the vessel past the access, where its seal sits.
        frame.pos = self._aorta.access_position_m + self.robot.sheath_depth_m * self._aorta.entry_direction
        frame.quat = [np.cos(-np.pi / 4), np.sin(-np.pi / 4), 0, 0]  # robot +z onto world +y
        self.robot.attach(self.wire, self.robot.wire_attachment_site)
        self.set_timesteps(control_timestep=0.05, physics_timestep=0.002)

    @property
    def root_entity(self):
        return self._arena

    def initialize_episode(self, physics, random_state):
        self.robot.set_pose(physics, 0.0, 0.0)

    def before_step(self, physics, action, random_state):
        self.robot.apply_action(physics, [1.0, 0.0])

    def get_reward(self, physics):
        return 0.0


def test_entities_in_a_users_own_task():
    task = _UserTask()
    env = composer.Environment(task, random_state=0)
    env.reset()
    tip = env.physics.bind(task.wire.tip_site)
    start = tip.xpos.copy()
    for _ in range(20):
        env.step(np.zeros(2))
    # 1 s at the robot's 20 mm/s maximum: the carriage and the tip advanced ~20 mm.
    insertion = env.physics.bind(task.robot.joints).qpos[0]
    assert insertion == pytest.approx(0.02, rel=0.1)
    assert tip.xpos[1] - start[1] > 0.01


def test_entity_observables_report_their_joints():
    wire, robot = Guidewire(n_segments=6, n_tip_segments=2), FollowerRobot()
    arena = OperatingArena()
    arena.attach(robot)
    robot.attach(wire, robot.wire_attachment_site)
    for observables in (wire.observables, robot.observables):
        for item in observables.proprioception:
            item.enabled = True
    wire.observables.tip_position.enabled = True
    env = composer.Environment(composer.NullTask(arena), strip_singleton_obs_buffer_dim=True)
    observation = env.reset().observation
    assert observation["follower/guidewire/joint_pos"].shape == (2 * 7,)
    assert observation["follower/joint_pos"].shape == (2,)
    tip = env.physics.bind(wire.tip_site).xpos
    np.testing.assert_allclose(observation["follower/guidewire/tip_position"], tip)


def test_robot_pose_features_are_bounded_and_do_not_wrap():
    wire, robot = Guidewire(n_segments=6, n_tip_segments=2), FollowerRobot()
    arena = OperatingArena()
    arena.attach(robot)
    robot.attach(wire, robot.wire_attachment_site)
    for item in (robot.observables.pose_features, robot.observables.rate_features, robot.observables.drive_force):
        item.enabled = True
    env = composer.Environment(composer.NullTask(arena), strip_singleton_obs_buffer_dim=True)
    env.reset()
    robot.set_pose(env.physics, insertion_m=0.15, rotation_rad=7.0)  # past a full turn
    observation = env.step(np.zeros(2)).observation
    insertion, rotation = env.physics.bind(robot.joints).qpos
    assert rotation > 2 * np.pi and insertion == pytest.approx(0.15, abs=1e-3)
    np.testing.assert_allclose(
        observation["follower/pose_features"],
        [insertion / robot.stroke_m, np.sin(rotation), np.cos(rotation)],
        atol=1e-9,
    )
    rates = env.physics.bind(robot.joints).qvel
    np.testing.assert_allclose(
        observation["follower/rate_features"],
        rates / [robot.max_insertion_speed_m_s, robot.max_rotation_speed_rad_s],
        atol=1e-9,
    )
    assert observation["follower/drive_force"].shape == (1,)
