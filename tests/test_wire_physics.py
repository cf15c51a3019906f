"""The wire against beam theory, its tip shape, and contact-force readings."""

import mujoco
import numpy as np
import pytest
from dm_control import mjcf

from cathsim_dmc import geom_groups
from cathsim_dmc import physics as cs_physics
from cathsim_dmc.arena import OperatingArena
from cathsim_dmc.entities import FollowerRobot, Guidewire


def _bare_physics(wire):
    root = mjcf.RootElement()
    root.option.set_attributes(gravity=[0, 0, 0], integrator="implicitfast", timestep=wire.physics_timestep_s)
    root.worldbody.attach(wire.mjcf_model)  # proximal segment welded at the origin, wire along +z
    return mjcf.Physics.from_mjcf_model(root)


@pytest.mark.parametrize("n_segments", [10, 40])
def test_cantilever_deflection_matches_euler_bernoulli(n_segments):
    length, force, modulus = 0.1, 1e-3, 40e9
    wire = Guidewire(length_m=length, n_segments=n_segments, n_tip_segments=1, tip_length_m=length / n_segments,
                     youngs_modulus_pa=modulus, tip_youngs_modulus_pa=modulus, tip_shape="straight",
                     damping_ratio=20.0)  # overdamped: settles sooner; the static deflection is the same
    physics = _bare_physics(wire)
    model, data = physics.model.ptr, physics.data.ptr
    tip_body = physics.bind(wire.segments[-1]).element_id
    tip_site = physics.bind(wire.tip_site).element_id
    for step in range(30_000):  # damped to rest under a constant transverse tip load
        data.qfrc_applied[:] = 0
        mujoco.mj_applyFT(model, data, np.array([force, 0, 0]), np.zeros(3), data.site_xpos[tip_site].copy(),
                          tip_body, data.qfrc_applied)
        mujoco.mj_step(model, data)
        if step > 100 and np.abs(data.qvel).max() < 1e-8:
            break
    assert np.abs(data.qvel).max() < 1e-8, "not at rest"
    deflection = data.site_xpos[tip_site][0]
    analytic = force * length**3 / (3 * modulus * np.pi * wire.core_diameter_m**4 / 64)
    # Within 1% (measured: -0.22% at 10 segments, -0.02% at 40; midpoint placement of the joints).
    assert deflection == pytest.approx(analytic, rel=0.01)


@pytest.mark.parametrize("shape, angle_deg", [("angled", 45.0), ("angled", 70.0), ("j", 180.0)])
def test_tip_rests_at_its_configured_angle(shape, angle_deg):
    wire = Guidewire(length_m=0.1, n_segments=10, tip_shape=shape, tip_angle_deg=angle_deg)
    physics = _bare_physics(wire)
    wire.initialize_episode(physics, None)
    for _ in range(500):
        physics.step()
    segments = physics.bind(wire.segments)
    shaft_axis = segments.xmat[0].reshape(3, 3)[:, 2]
    tip_axis = segments.xmat[-1].reshape(3, 3)[:, 2]
    measured = np.degrees(np.arccos(np.clip(shaft_axis @ tip_axis, -1, 1)))
    assert measured == pytest.approx(angle_deg, abs=5.0)
    # The bend is in the wire's x-z plane, towards +x.
    assert physics.bind(wire.tip_site).xpos[0] > 0


@pytest.mark.parametrize("margin_m", [0.0, 1e-3])
def test_contact_force_reads_the_push_against_a_wall(margin_m):
    """The insertion drive stalls at its force limit against a flat wall: the wall must
    read that force, pointing away from the wire. A wall with a contact margin, moved back
    by it as the vessel wall is (`Aorta.contact_margin_m`), reads the same and stops the
    wire at the same face."""
    push_n = 1.0
    arena = OperatingArena()
    # A solid (stiffer) wire: a soft one bends where it leaves the channel and leans on
    # the outlet edge, which then takes part of the push.
    wire = Guidewire(length_m=0.12, n_segments=20, n_tip_segments=4, tip_shape="straight", core_diameter_m=None)
    robot = FollowerRobot(wire_length_m=0.12, stroke_m=0.05, max_insertion_force_n=push_n)
    arena.attach(robot)  # insertion along world +z; the tip starts 25 mm past the outlet
    robot.attach(wire, robot.wire_attachment_site)
    arena.mjcf_model.option.gravity = [0, 0, 0]
    wall = arena.mjcf_model.worldbody.add(
        "geom", type="box", size=[0.02, 0.02, 0.002], pos=[0, 0, 0.037 + margin_m], contype=geom_groups.WALL_CONTYPE,
        conaffinity=geom_groups.WALL_CONAFFINITY, solref=[0.004, 1], solimp=[0.99, 0.999, 0.0005, 0.5, 2],
        margin=margin_m)
    physics = mjcf.Physics.from_mjcf_model(arena.mjcf_model)
    wire.initialize_episode(physics, None)
    is_wire = np.zeros(physics.model.ngeom, bool)
    is_wire[physics.bind(wire.geoms).element_id] = True
    for _ in range(1000):
        robot.apply_action(physics, [1.0, 0.0])
        physics.step()
    is_wall = np.zeros(physics.model.ngeom, bool)
    is_wall[physics.bind(wall).element_id] = True  # the guide channel is not the wall
    contacts = cs_physics.wire_contacts(physics, is_wire, is_vessel_geom=is_wall)
    assert contacts.count >= 1
    assert contacts.total_n == pytest.approx(push_n, rel=0.05)
    np.testing.assert_allclose(contacts.forces_n.sum(axis=0), [0, 0, push_n], atol=0.05 * push_n)
    # Sub-millimetre penetration: the tip's end cap stops at the wall face (z = 0.035 m).
    tip_end = physics.bind(wire.tip_site).xpos[2] + wire.radius_m
    assert 0.035 - 0.0005 < tip_end < 0.035 + 0.0005


def test_blood_drag_option_resists_wire_motion():
    from cathsim_dmc import tasks

    drag = {}
    for blood in (False, True):
        env = tasks.load("bca", "type1", seed=0, blood_drag=blood)
        env.reset()
        env.step(np.array([1.0, 0.5]))
        data = env.physics.data
        # Fluid forces oppose the motion of the moving wire and carriage: negative power.
        drag[blood] = float(data.qfrc_fluid @ data.qvel)
        assert env.physics.model.opt.density == (1055.0 if blood else 0.0)
    assert drag[False] == 0.0 and drag[True] < 0.0


def _seam_contacts(margin_m, depth_m=0.6e-3, approach_m_s=0.09):
    """A wire segment along the seam between two flat wall prisms (lumen surface z = 0,
    lumen above), `depth_m` past the surface and moving into it, as in the 3,568 N step
    of issue 17: its contacts' forces (N) and normals (pointing into the wall)."""
    from cathsim_dmc.entities.aorta import moved_outward

    wire = Guidewire()
    mm, thickness = 1e-3, 2e-3
    pieces = []
    for side in (-1, 1):  # two triangles sharing the edge along x at y = 0
        inner = np.array([[-10 * mm, 0, 0], [10 * mm, 0, 0], [0, side * 10 * mm, 0]])
        pieces.append(np.vstack([inner, inner - [0, 0, thickness]]))
    root = mjcf.RootElement()
    root.option.set_attributes(timestep=wire.physics_timestep_s, gravity=[0, 0, 0], integrator="implicitfast",
                               cone="elliptic")
    root.option.flag.multiccd = "disable"
    for i, piece in enumerate(moved_outward(pieces, margin_m)):
        mesh = root.asset.add("mesh", name=f"piece{i}", vertex=piece.ravel())
        root.worldbody.add("geom", name=f"piece{i}", type="mesh", mesh=mesh, margin=margin_m,
                           contype=geom_groups.WALL_CONTYPE, conaffinity=geom_groups.WALL_CONAFFINITY,
                           solref=list(wire.contact_solref), solimp=list(wire.contact_solimp))
    segment_m = wire.segment_lengths_m[1]
    body = root.worldbody.add("body", pos=[0, 0, wire.radius_m - depth_m])
    body.add("freejoint")
    body.add("geom", name="segment", type="capsule", fromto=[-segment_m / 2, 0, 0, segment_m / 2, 0, 0],
             size=[wire.radius_m], contype=geom_groups.WIRE_CONTYPE, conaffinity=geom_groups.WIRE_CONAFFINITY,
             mass=float(wire.mass_scale * 6450.0 * np.pi * wire.radius_m**2 * segment_m),
             solref=list(wire.contact_solref), solimp=list(wire.contact_solimp))
    physics = mjcf.Physics.from_mjcf_model(root)
    physics.data.qvel[2] = -approach_m_s
    is_wire = np.zeros(physics.model.ngeom, bool)
    is_wire[physics.model.name2id("segment", "geom")] = True
    contacts = cs_physics.wire_contacts(physics, is_wire, is_vessel_geom=~is_wire)
    return contacts.forces_n, physics.data.contact.frame[:physics.data.ncon, :3]


def test_a_wire_deep_in_a_seam_between_wall_pieces_reads_its_load():
    """Without a margin, the two pieces' side faces become the contact normals (they are
    nearer than the lumen face once the segment is deeper than its radius), opposite to
    each other, and the solver drives them against each other: thousands of newtons that
    cancel. With the wall's margin and the pieces moved back by it, the normals are the
    surface's and the force is the segment's load (about 0.14 kg stopped within a step)."""
    forces, normals = _seam_contacts(margin_m=0.0)
    assert np.linalg.norm(forces, axis=1).sum() > 100.0  # the artefact the margin removes
    assert np.abs(normals[:, 2]).max() < 0.5  # side faces: horizontal normals
    forces, normals = _seam_contacts(margin_m=0.5e-3)
    total = np.linalg.norm(forces, axis=1).sum()
    assert 0.5 < total < 10.0
    assert total == pytest.approx(np.linalg.norm(forces.sum(axis=0)), rel=0.05)  # nothing cancels
    assert np.abs(normals[:, 2]).min() > np.cos(np.radians(30))
