"""Physical checks of the model, each a measurement under a chosen solver setting.

The same functions back the tests (which assert on them) and `experiments/fidelity_gate.py`
(which prints them side by side for every setting in `physics.PHYSICS_SETTINGS`), so a
solver setting is judged by exactly what the tests check:

* `cantilever_deflection`: a straight wire clamped at one end under a transverse tip
  load, against Euler-Bernoulli (delta = F L^3 / 3 E I);
* `tip_rest_angle`: a shaped tip relaxes to its configured angle;
* `wall_push`: the insertion drive stalls against a flat wall at its force limit, and the
  wall reads that force;
* `insertion_response`: how the tip follows the carriage up the descending aorta and back.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from dm_control import mjcf

from cathsim_dmc.core import task_defaults
from cathsim_dmc.entities import FollowerRobot, Guidewire
from cathsim_dmc.entities.catheter import CatheterOverWire
from cathsim_dmc.entities.guidewire import second_moment_of_area
from cathsim_dmc.sim import geom_groups
from cathsim_dmc.sim import physics as cs_physics
from cathsim_dmc.sim.arena import OperatingArena


def bare_wire_physics(wire: Guidewire, physics_setting=task_defaults.PHYSICS) -> mjcf.Physics:
    """The wire alone, its proximal segment welded at the origin, pointing along +z, no gravity."""
    root = mjcf.RootElement()
    root.option.set_attributes(gravity=[0, 0, 0], integrator="implicitfast", timestep=wire.physics_timestep_s)
    cs_physics.physics_settings(physics_setting).apply(root)
    root.worldbody.attach(wire.mjcf_model)
    return mjcf.Physics.from_mjcf_model(root)


def cantilever_deflection(
    n_segments: int,
    physics_setting=task_defaults.PHYSICS,
    length_m: float = 0.1,
    force_n: float = 1e-3,
    youngs_modulus_pa: float = 40e9,
    catheter=None,
) -> tuple[float, float, bool]:
    """(measured, analytic tip deflection in metres, came to rest) of a uniform straight wire
    under a constant transverse tip load, damped to rest; with `catheter` (a `Catheter`)
    covering all of it, the two bending together (analytic: E I of both summed)."""
    wire = Guidewire(
        length_m=length_m,
        n_segments=n_segments,
        n_tip_segments=1,
        tip_length_m=length_m / n_segments,
        youngs_modulus_pa=youngs_modulus_pa,
        tip_youngs_modulus_pa=youngs_modulus_pa,
        tip_shape="straight",
        damping_ratio=20.0,
    )  # overdamped: settles sooner, same static answer
    physics = bare_wire_physics(wire, physics_setting)
    stiffness_nm2 = youngs_modulus_pa * second_moment_of_area(wire.core_diameter_m)
    if catheter is not None:
        covering = CatheterOverWire(catheter, wire)
        covering.initialize(physics)
        covering.apply(physics, 0.0)
        stiffness_nm2 += catheter.bending_stiffness_nm2
    model, data = physics.model.ptr, physics.data.ptr
    tip_body = physics.bind(wire.segments[-1]).element_id
    tip_site = physics.bind(wire.tip_site).element_id
    at_rest = False
    for step in range(30_000):
        data.qfrc_applied[:] = 0
        mujoco.mj_applyFT(
            model,
            data,
            np.array([force_n, 0, 0]),
            np.zeros(3),
            data.site_xpos[tip_site].copy(),
            tip_body,
            data.qfrc_applied,
        )
        mujoco.mj_step(model, data)
        if step > 100 and np.abs(data.qvel).max() < 1e-8:
            at_rest = True
            break
    analytic = force_n * length_m**3 / (3 * stiffness_nm2)
    return float(data.site_xpos[tip_site][0]), float(analytic), at_rest


def tip_rest_angle(shape: str, angle_deg: float, physics_setting=task_defaults.PHYSICS) -> tuple[float, float]:
    """(angle between shaft and tip in degrees, x of the tip in metres) of a 10-segment wire
    with a shaped tip after 500 physics steps from its rest shape; the bend points to +x."""
    wire = Guidewire(length_m=0.1, n_segments=10, tip_shape=shape, tip_angle_deg=angle_deg)
    physics = bare_wire_physics(wire, physics_setting)
    wire.initialize_episode(physics, None)
    for _ in range(500):
        physics.step()
    segments = physics.bind(wire.segments)
    shaft_axis = segments.xmat[0].reshape(3, 3)[:, 2]
    tip_axis = segments.xmat[-1].reshape(3, 3)[:, 2]
    measured = float(np.degrees(np.arccos(np.clip(shaft_axis @ tip_axis, -1, 1))))
    return measured, float(physics.bind(wire.tip_site).xpos[0])


@dataclass
class WallPush:
    total_n: float  # sum of the wall's contact force magnitudes, newtons
    net_n: np.ndarray  # (3,) vector sum of the wall's contact forces, newtons
    contacts: int
    tip_end_m: float  # z of the tip's end cap; the wall face is at WALL_FACE_M


WALL_FACE_M = 0.035  # where `wall_push`'s wall face lies along the insertion axis, metres


def wall_push(
    margin_m: float = 0.0, physics_setting=task_defaults.PHYSICS, push_n: float = 1.0, steps: int = 1000
) -> WallPush:
    """A solid wire driven along +z at the robot's force limit `push_n` into a flat wall
    (faces at z = 0.035 m; a wall with a contact margin is moved back by it, as the vessel
    wall is), read after `steps` physics steps."""
    arena = OperatingArena(physics=physics_setting)
    # A solid (stiffer) wire: a soft one bends where it leaves the channel and leans on
    # the outlet edge, which then takes part of the push.
    wire = Guidewire(length_m=0.12, n_segments=20, n_tip_segments=4, tip_shape="straight", core_diameter_m=None)
    robot = FollowerRobot(wire_length_m=0.12, stroke_m=0.05, max_insertion_force_n=push_n)
    arena.attach(robot)  # insertion along world +z; the tip starts 25 mm past the outlet
    robot.attach(wire, robot.wire_attachment_site)
    arena.mjcf_model.option.gravity = [0, 0, 0]
    contact = dict(
        contype=geom_groups.WALL_CONTYPE,
        conaffinity=geom_groups.WALL_CONAFFINITY,
        solref=[0.004, 1],
        solimp=[0.99, 0.999, 0.0005, 0.5, 2],
        margin=margin_m,
    )
    root = arena.mjcf_model
    if cs_physics.physics_settings(physics_setting).wall == "field":
        # The same face as a distance field (`Aorta(wall="field")`'s contact test): a
        # 40 mm square facing the wire, its "lumen" on the wire's side. The field is too
        # large for an MJCF attribute, so it joins the model through a spec.
        from dm_control.mujoco import wrapper

        from cathsim_dmc.sim import wall_field

        corners = np.array([[-0.02, -0.02], [0.02, -0.02], [0.02, 0.02], [-0.02, 0.02]])
        face = np.column_stack([corners, np.full(4, WALL_FACE_M)])
        field = wall_field.build_field(np.stack([face[[0, 1, 2]], face[[0, 2, 3]]]), shift_m=margin_m)
        box = [
            [x, y, z] for x in (-0.02, 0.02) for y in (-0.02, 0.02) for z in (WALL_FACE_M - 0.003, WALL_FACE_M + 0.003)
        ]
        spec = mujoco.MjSpec.from_string(root.to_xml_string(), assets=root.get_assets())
        spec.add_numeric(name="wall", data=field, size=len(field))
        spec.add_mesh(name="wall").uservert = np.ravel(box)
        geom = spec.worldbody.add_geom(name="wall", type=mujoco.mjtGeom.mjGEOM_SDF, meshname="wall")
        for key, value in contact.items():
            setattr(geom, key, value)
        physics = mjcf.Physics.from_model(wrapper.MjModel(spec.compile()))
        wall_id = mujoco.mj_name2id(physics.model.ptr, mujoco.mjtObj.mjOBJ_GEOM, "wall")
    else:
        wall = root.worldbody.add(
            "geom", type="box", size=[0.02, 0.02, 0.002], pos=[0, 0, WALL_FACE_M + 0.002 + margin_m], **contact
        )
        physics = mjcf.Physics.from_mjcf_model(root)
        wall_id = int(physics.bind(wall).element_id)
    wire.initialize_episode(physics, None)
    is_wire = np.zeros(physics.model.ngeom, bool)
    is_wire[physics.bind(wire.geoms).element_id] = True
    for _ in range(steps):
        robot.apply_action(physics, [1.0, 0.0])
        physics.step()
    is_wall = np.zeros(physics.model.ngeom, bool)
    is_wall[wall_id] = True  # the guide channel is not the wall
    contacts = cs_physics.wire_contacts(physics, is_wire, is_vessel_geom=is_wall)
    return WallPush(
        total_n=float(contacts.total_n),
        net_n=contacts.forces_n.sum(axis=0),
        contacts=int(contacts.count),
        tip_end_m=float(physics.bind(wire.tip_site).xpos[2] + wire.radius_m),
    )


@dataclass
class InsertionResponse:
    insert_ratio: float  # tip advance along the vessel over carriage advance, while inserting
    retract_ratio: float  # the same while retracting
    max_slack_m: float  # largest carriage-minus-tip advance during the run, metres
    final_slack_m: float
    tip_m: np.ndarray  # (3,) where the tip ended, metres
    escaped: bool
    diverged: bool


def insertion_response(
    physics_setting=task_defaults.PHYSICS,
    aorta: str = "type1",
    insert_steps: int = 50,
    retract_steps: int = 15,
    rotation: float = 0.2,
    seed: int = 0,
) -> InsertionResponse:
    """Full-speed insertion from the start pose with a slow rotation (`cathsim-bench`'s
    motion: up the descending aorta and into the arch, in wall contact), then retraction:
    how closely the tip (measured along the vessel, `Navigate.slack_m`) follows the carriage."""
    from cathsim_dmc import tasks  # deferred: building the suite needs the assets

    env = tasks.load("bca", aorta, obs="internal", physics=physics_setting)
    env.random_state.seed(seed)
    env.reset()
    task = env.task
    info = task.step_info(env.physics)
    slacks, escaped, diverged, ratios, ended = [], False, False, [], False
    for action, steps in (([1.0, rotation], insert_steps), ([-1.0, rotation], retract_steps)):
        carriage, slack = info.insertion_m, info.slack_m
        for _ in range(steps):
            if ended:  # another step would start a new episode
                raise RuntimeError(
                    f"the episode ended after {task.step_count} steps (success, escape or divergence): "
                    "the insertion response needs the whole motion"
                )
            ended = env.step(np.asarray(action, np.float32)).last()
            info = task.step_info(env.physics)
            slacks.append(info.slack_m)
            escaped |= info.escaped
            diverged |= info.diverged
        carriage_advance = info.insertion_m - carriage
        ratios.append((carriage_advance - (info.slack_m - slack)) / carriage_advance)  # slack: carriage - tip
    env.close()
    return InsertionResponse(
        insert_ratio=float(ratios[0]),
        retract_ratio=float(ratios[1]),
        max_slack_m=float(np.max(np.abs(slacks))),
        final_slack_m=float(slacks[-1]),
        tip_m=np.asarray(info.tip_position_m, dtype=float).copy(),
        escaped=escaped,
        diverged=diverged,
    )
