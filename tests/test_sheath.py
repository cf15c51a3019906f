"""The introducer sheath and its seal: the access is closed by construction (issue 17, Build 1).

The robot's guide channel runs on as a sheath through the vessel's open end to a tip a
few mm inside the lumen, and a plate around it closes the open end, so the wire can only
go forward into the lumen or back into the channel.
"""

import numpy as np
import pytest
from shipped import aorta_params

from cathsim_dmc import tasks
from cathsim_dmc.anatomy.containment import Channel, Containment
from cathsim_dmc.anatomy.validate import open_end_plane


def _outlet_m(task):
    return task.aorta.access_position_m + task.robot.sheath_depth_m * task.aorta.entry_direction


@pytest.mark.parametrize("aorta", aorta_params())
def test_sheath_reaches_into_the_lumen_and_the_seal_closes_the_open_end(aorta):
    env = tasks.load("bca", aorta, seed=0)
    env.reset()
    task, physics = env.task, env.physics
    robot, direction = task.robot, task.aorta.entry_direction
    centre, outward, radius = open_end_plane(task.aorta.asset)
    # The sheath crosses the open end at its centre (every shipped asset enters there).
    np.testing.assert_allclose(task.aorta.access_position_m, centre, atol=1e-9)
    outlet = _outlet_m(task)
    assert robot.sheath_depth_m > 0
    assert task.containment.field.signed_distance_m(outlet[None])[0] > robot.sheath_depth_m - 0.3e-3
    # The channel walls reach the outlet and not beyond.
    walls = physics.bind(robot.guide_geoms)
    far_end = np.max([(pos - outlet) @ direction + size[2] for pos, size in zip(walls.xpos, walls.size)])
    assert far_end == pytest.approx(0.0, abs=1e-9)
    # The seal plate lies just outside the open end, its vessel side in the plane, and
    # covers the wall's end (lumen radius plus wall thickness).
    seal = physics.bind(robot.seal_geoms)
    faces = [float((pos - centre) @ -outward) + size[2] for pos, size in zip(seal.xpos, seal.size)]
    np.testing.assert_allclose(faces, 0.0, atol=1e-9)
    assert robot.seal_half_width_m >= radius + task.aorta.wall_thickness_m
    # The shaped tip starts outside the sheath, a few mm past the entry site.
    tip_base = physics.bind(task.guidewire.tip_base_site).xpos
    assert (tip_base - outlet) @ direction > 1e-3
    tip = task.tip_position_m(physics)
    assert 0 < (tip - task.aorta.entry_position_m) @ direction < 0.012
    assert task.containment.contains(task.wire_points_m(physics)).all()


def test_wire_retracts_into_the_sheath_and_advances_again():
    """Pulled 25 mm behind its start, the tip goes into the sheath and straightens; pushed
    out again, it takes its shape back. Nothing escapes on the way."""
    env = tasks.load("bca", "type1", seed=0)
    env.reset()
    task, physics = env.task, env.physics
    robot, wire, direction = task.robot, task.guidewire, task.aorta.entry_direction
    pull_m = 0.025
    # Let the carriage travel behind the start of its stroke (model values, this episode only).
    physics.bind(robot.joints[0]).range = [-pull_m, robot.stroke_m]
    physics.bind(robot.actuators[0]).actrange = [-pull_m, robot.stroke_m]
    # The wire's proximal end then leaves the back of the channel's containment capsule
    # (the rail holds it there): extend the channel backwards by the pull.
    allowed = task.containment
    channel = allowed.channels[0]
    task._containment = Containment(
        allowed.field,
        allowed.tolerance_m,
        [Channel(channel.start_m - pull_m * direction, channel.end_m, channel.radius_m)],
    )
    outlet = _outlet_m(task)

    def tip_past_outlet_m():
        return float((task.tip_position_m(physics) - outlet) @ direction)

    def tip_bend_deg():
        last = physics.bind(wire.segments[-1]).xmat.reshape(3, 3)[:, 2]
        return float(np.degrees(np.arccos(np.clip(last @ direction, -1.0, 1.0))))

    assert tip_bend_deg() == pytest.approx(45.0, abs=2.0)
    drive = []
    for action in [[-1.0, 0.0]] * 10 + [[0.0, 0.5]] * 3:
        assert env.step(np.array(action)).mid() and not task.escaped and not task.diverged
        drive.append(abs(robot.drive_force_n(physics)))
    assert robot.insertion_m(physics) == pytest.approx(-pull_m, abs=0.5e-3)
    assert tip_past_outlet_m() < -5e-3  # inside the sheath
    assert tip_bend_deg() < 10.0  # straightened by the bore
    for _ in range(14):
        assert env.step(np.array([1.0, 0.0])).mid() and not task.escaped and not task.diverged
        drive.append(abs(robot.drive_force_n(physics)))
    assert tip_past_outlet_m() > 0.03
    assert tip_bend_deg() == pytest.approx(45.0, abs=6.0)
    assert max(drive) < 2.0  # the frictionless bore neither pinches nor snags the tip


def test_issue_reproduction_never_reaches_beside_the_sheath():
    """The issue's reproduction (500 random actions, then 500 of full insertion and
    rotation) once looped the wire out of the open end at step 520: now no wire point
    escapes, and below the open end the wire stays in the bore."""
    env = tasks.load("bca", "type1", seed=0, max_steps=1001)
    env.reset()
    task = env.task
    centre, outward, _ = open_end_plane(task.aorta.asset)
    direction = task.aorta.entry_direction
    rng = np.random.default_rng(0)
    actions = list(rng.uniform(-1, 1, (500, 2))) + [np.array([1.0, 1.0])] * 500
    farthest_m = 0.0
    for step, action in enumerate(actions, 1):
        timestep = env.step(action)
        assert not task.escaped and not task.diverged, f"step {step}"
        assert timestep.mid() or step == len(actions)
        points = task.wire_points_m(env.physics) - centre
        below = points[points @ outward > 0]
        if len(below):
            off_axis = below - np.outer(below @ direction, direction)
            farthest_m = max(farthest_m, float(np.linalg.norm(off_axis, axis=1).max()))
    assert task.robot.insertion_m(env.physics) == pytest.approx(task.robot.stroke_m, abs=1e-3)
    # In the bore a wire centre sits within the clearance of the axis (measured: 0.47 mm).
    bore_corner_m = task.robot.channel_half_width_m * np.sqrt(2.0)
    assert farthest_m < bore_corner_m
    # A point beside the sheath below the open end is neither reached nor allowed.
    beside = centre + 3e-3 * outward + 6e-3 * np.cross(direction, [0.0, 0.0, 1.0])
    assert not task.containment.contains(beside[None])[0]


@pytest.mark.parametrize(
    "robot, match",
    [
        (dict(seal_half_width_m=None), "no seal plate"),
        (dict(seal_half_width_m=0.012), "does not cover the open end"),
        (dict(initial_insertion_m=0.015), "must exceed the wire's tip_length_m"),
    ],
)
def test_a_robot_that_cannot_seal_is_refused(robot, match):
    with pytest.raises(ValueError, match=match):
        tasks.build_task("bca", "type1", robot=robot)


def test_straight_tip_may_start_in_the_sheath():
    task = tasks.build_task("bca", "type1", guidewire=dict(tip_shape="straight"), robot=dict(initial_insertion_m=0.01))
    assert task.robot.initial_insertion_m == 0.01
