"""The wire against beam theory, its tip shape, and contact-force readings."""

import numpy as np
import pytest
from dm_control import mjcf

from cathsim_dmc.entities import Guidewire
from cathsim_dmc.evaluation import fidelity
from cathsim_dmc.sim import geom_groups
from cathsim_dmc.sim import physics as cs_physics

# The fidelity gate of the physics settings: the beam, tip, force and insertion checks hold under each.
SETTINGS = list(cs_physics.PHYSICS_SETTINGS)
# The bare wire touches no vessel wall: one setting per solver suffices for beam and tip.
SOLVERS = ["accurate", "fast"]


@pytest.mark.parametrize("physics_setting", SOLVERS)
@pytest.mark.parametrize("n_segments", [10, 40])
def test_cantilever_deflection_matches_euler_bernoulli(n_segments, physics_setting):
    deflection, analytic, at_rest = fidelity.cantilever_deflection(n_segments, physics_setting)
    assert at_rest
    # Within 1% (measured: -0.22% at 10 segments, -0.02% at 40; midpoint placement of the joints).
    assert deflection == pytest.approx(analytic, rel=0.01)


@pytest.mark.parametrize("physics_setting", SOLVERS)
@pytest.mark.parametrize("shape, angle_deg", [("angled", 45.0), ("angled", 70.0), ("j", 180.0)])
def test_tip_rests_at_its_configured_angle(shape, angle_deg, physics_setting):
    measured, tip_x = fidelity.tip_rest_angle(shape, angle_deg, physics_setting)
    assert measured == pytest.approx(angle_deg, abs=5.0)
    assert tip_x > 0  # the bend is in the wire's x-z plane, towards +x


@pytest.mark.parametrize("physics_setting", SETTINGS)
@pytest.mark.parametrize("margin_m", [0.0, 1e-3])
def test_contact_force_reads_the_push_against_a_wall(margin_m, physics_setting):
    """The insertion drive stalls at its force limit against a flat wall: the wall must
    read that force, pointing away from the wire. A wall with a contact margin, moved back
    by it as the vessel wall is (`Aorta.contact_margin_m`), reads the same and stops the
    wire at the same face."""
    push = fidelity.wall_push(margin_m, physics_setting, push_n=1.0)
    assert push.contacts >= 1
    assert push.total_n == pytest.approx(1.0, rel=0.05)
    np.testing.assert_allclose(push.net_n, [0, 0, 1.0], atol=0.05)
    # Sub-millimetre penetration: the tip's end cap stops at the wall face.
    assert abs(push.tip_end_m - fidelity.WALL_FACE_M) < 0.0005


@pytest.mark.parametrize("physics_setting", SETTINGS)
def test_the_tip_follows_the_carriage_into_the_arch_and_back(physics_setting):
    response = fidelity.insertion_response(physics_setting)
    # Measured (both settings): 1.018 inserting, 1.05-1.08 retracting (the wire leaves the
    # outer curve it took), slack at most 8.4 mm.
    assert response.insert_ratio == pytest.approx(1.0, abs=0.05)
    assert response.retract_ratio == pytest.approx(1.0, abs=0.15)
    assert response.max_slack_m < 0.015
    assert not (response.escaped or response.diverged)


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
    root.option.set_attributes(
        timestep=wire.physics_timestep_s, gravity=[0, 0, 0], integrator="implicitfast", cone="elliptic"
    )
    root.option.flag.multiccd = "disable"
    for i, piece in enumerate(moved_outward(pieces, margin_m)):
        mesh = root.asset.add("mesh", name=f"piece{i}", vertex=piece.ravel())
        root.worldbody.add(
            "geom",
            name=f"piece{i}",
            type="mesh",
            mesh=mesh,
            margin=margin_m,
            contype=geom_groups.WALL_CONTYPE,
            conaffinity=geom_groups.WALL_CONAFFINITY,
            solref=list(wire.contact_solref),
            solimp=list(wire.contact_solimp),
        )
    segment_m = wire.segment_lengths_m[1]
    body = root.worldbody.add("body", pos=[0, 0, wire.radius_m - depth_m])
    body.add("freejoint")
    body.add(
        "geom",
        name="segment",
        type="capsule",
        fromto=[-segment_m / 2, 0, 0, segment_m / 2, 0, 0],
        size=[wire.radius_m],
        contype=geom_groups.WIRE_CONTYPE,
        conaffinity=geom_groups.WIRE_CONAFFINITY,
        mass=float(wire.mass_scale * 6450.0 * np.pi * wire.radius_m**2 * segment_m),
        solref=list(wire.contact_solref),
        solimp=list(wire.contact_solimp),
    )
    physics = mjcf.Physics.from_mjcf_model(root)
    physics.data.qvel[2] = -approach_m_s
    is_wire = np.zeros(physics.model.ngeom, bool)
    is_wire[physics.model.name2id("segment", "geom")] = True
    contacts = cs_physics.wire_contacts(physics, is_wire, is_vessel_geom=~is_wire)
    return contacts.forces_n, physics.data.contact.frame[: physics.data.ncon, :3]


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
