"""FollowerRobot: a CathBot-style follower that inserts and rotates a guidewire.

Frame: the robot's origin is its *outlet*, the tip of its introducer sheath, where the
wire leaves the guide channel inside the vessel; +z is the insertion direction. Behind
the outlet lies the rail along -z, with a carriage on a prismatic joint (insertion)
carrying the guidewire rotary platform on a hinge about the wire axis (rotation). The
wire's proximal end is rigidly attached to that platform (perfect grip, no slip). A
catheter rotary platform and two clamps complete the CathBot layout; they have joints
but no actuators here.

Introducer sheath and seal. From the carriage to the outlet the wire runs in one
straight, square guide channel; its distal end is the introducer sheath, which goes in
through the vessel's access (the open lower end of the generated descending aorta; the
puncture of a real femoral artery) and ends `sheath_depth_m` inside the lumen. A square
seal plate around the sheath, its vessel side `sheath_depth_m` behind the outlet, closes
the access around it, as the artery wall closes around a real sheath. So the wire can
only go forward into the lumen or back into the channel, and a wire that buckles back
down the vessel meets the plate, not an exit. (Before the sheath, the channel ended 15
mm outside the open end; a pushed wire bowed out of that unguided gap and, looping, left
the anatomy: issue 17.) `Aorta.access_position_m` is where the seal goes: attach the
robot at `access_position_m + sheath_depth_m * entry_direction`.

The plate stands for a seal, not an object to see: it sits in the collision geom group,
which observation renders never draw. Channel and plate are frictionless (a lubricated
introducer) and carry the wire's contact parameters (`channel_solref`, `channel_solimp`);
their contacts are not tissue loads, and `Navigate` leaves them out of the wall force.

The wire's shaped tip must start outside the sheath (`initial_insertion_m` longer than
the tip): set at its rest shape inside the straight bore, a bent tip would start through
the channel's walls. Pulled into the sheath later, the elastic tip straightens, and it
takes its shape back when pushed out again.

Both actuated joints are integrated-velocity servos: the action sets a velocity, MuJoCo
integrates it into a set point (an actuator state limited to the joint's travel), and a
stiff, damped position servo follows it.
"""

from __future__ import annotations

import numpy as np
from dm_control import composer, mjcf
from dm_control.composer.observation import observable

from cathsim_dmc.core.checks import check_parameters
from cathsim_dmc.entities.observables import JointObservables
from cathsim_dmc.sim import geom_groups


class FollowerRobot(composer.Entity):
    """Rail, carriage (insertion), guidewire rotary platform (rotation), clamps."""

    def _build(
        self,
        wire_length_m: float = 0.35,
        stroke_m: float = 0.30,
        initial_insertion_m: float = 0.017,  # the 15 mm shaped tip plus 2 mm of straight shaft
        max_insertion_speed_m_s: float = 0.04,  # CathBot-class followers: tens of mm/s
        max_rotation_speed_rad_s: float = np.pi,  # half a turn per second
        max_insertion_force_n: float = 5.0,  # manual pushes stay below ~2 N; a robot stalls beyond
        channel_clearance_m: float = 0.3e-3,
        wire_radius_m: float = 0.445e-3,
        servo_stiffness_n_m: float = 2e4,
        servo_stiffness_nm_rad: float = 50.0,
        channel_solref: tuple = (0.01, 1.0),  # 2 timesteps at the 5 ms default
        channel_solimp: tuple = (0.99, 0.999, 0.0005, 0.5, 2),
        sheath_depth_m: float = 0.003,  # a few mm: the wire leaves the sheath inside the lumen, clear of the seal
        seal_half_width_m: float | None = 0.02,  # covers an aorta's 12 mm open end and its 2 mm wall
        seal_thickness_m: float = 0.002,  # as thick as the vessel wall, which stops the wire tunnelling
        name: str = "follower",
    ):
        """Builds the robot.

        Args:
          wire_length_m: length of the wire it holds, in metres (sets the rail length).
          stroke_m: insertion travel of the carriage in metres.
          initial_insertion_m: how far the wire tip starts past the outlet (the sheath's
            tip), along the wire, in metres; longer than the wire's shaped tip, which
            must start outside the channel.
          max_insertion_speed_m_s: insertion speed at action +1, in m/s.
          max_rotation_speed_rad_s: rotation rate at action +1, in rad/s.
          max_insertion_force_n: force limit of the insertion drive, in newtons: a
            blocked wire stalls the carriage instead of being pushed without bound.
          channel_clearance_m: radial play between the wire and the guide channel.
          wire_radius_m: radius of the held wire, in metres (sizes the channel).
          servo_stiffness_n_m: insertion servo stiffness, N/m.
          servo_stiffness_nm_rad: rotation servo stiffness, N m/rad.
          channel_solref, channel_solimp: contact parameters of the guide channel;
            give it the wire's values (MuJoCo mixes the two geoms'), or the channel
            is softer than the vessel wall. The seal plate carries them too.
          sheath_depth_m: how far the sheath's tip reaches past the seal plate's vessel
            side, in metres: place the seal on the vessel's access (see
            `Aorta.access_position_m`) and the outlet lies this deep in the lumen.
          seal_half_width_m: half-width of the square seal plate around the sheath, in
            metres; at least the access's radius plus the wall thickness, so that the
            plate covers the wall's end. None: no plate (a bare channel).
          seal_thickness_m: thickness of the seal plate along the wire, in metres.
          name: model name.
        """
        check_parameters(
            "FollowerRobot",
            positive=dict(
                wire_length_m=wire_length_m,
                stroke_m=stroke_m,
                max_insertion_speed_m_s=max_insertion_speed_m_s,
                max_rotation_speed_rad_s=max_rotation_speed_rad_s,
                max_insertion_force_n=max_insertion_force_n,
                wire_radius_m=wire_radius_m,
                servo_stiffness_n_m=servo_stiffness_n_m,
                servo_stiffness_nm_rad=servo_stiffness_nm_rad,
                seal_half_width_m=seal_half_width_m,
            ),
            non_negative=dict(channel_clearance_m=channel_clearance_m),
            finite=dict(
                initial_insertion_m=initial_insertion_m, channel_solref=channel_solref, channel_solimp=channel_solimp
            ),
        )
        if stroke_m >= wire_length_m - initial_insertion_m:
            raise ValueError(
                f"stroke_m={stroke_m} must be shorter than the wire behind the outlet "
                f"({wire_length_m - initial_insertion_m} m) or the carriage hits the outlet"
            )
        if not sheath_depth_m >= 0 or not seal_thickness_m > 0:
            raise ValueError(
                f"sheath_depth_m={sheath_depth_m} must be >= 0 and seal_thickness_m={seal_thickness_m} > 0 (metres)"
            )
        self._mjcf_root = mjcf.RootElement(model=name)
        self._mjcf_root.compiler.angle = "radian"
        self.max_insertion_speed_m_s = float(max_insertion_speed_m_s)
        self.max_rotation_speed_rad_s = float(max_rotation_speed_rad_s)
        self.stroke_m = float(stroke_m)
        self.initial_insertion_m = float(initial_insertion_m)

        root = self._mjcf_root
        root.default.geom.set_attributes(contype=0, conaffinity=0, group=geom_groups.VISUAL, rgba=[0.6, 0.6, 0.65, 1])
        # Wire base at the start of the stroke: the tip then sits initial_insertion_m past the outlet.
        base_z = initial_insertion_m - wire_length_m
        rail_len = wire_length_m + 0.04
        wb = root.worldbody
        wb.add(
            "geom",
            name="rail",
            type="box",
            size=[0.01, 0.004, rail_len / 2],
            pos=[0, -0.012, base_z + rail_len / 2 - 0.04],
        )

        self._carriage = wb.add("body", name="carriage", pos=[0, 0, base_z])
        self._insertion = self._carriage.add(
            "joint",
            name="insertion",
            type="slide",
            axis=[0, 0, 1],
            range=[0, stroke_m],
            limited=True,
            damping=5.0,
            armature=1.0,
        )
        self._carriage.add(
            "geom", name="carriage", type="box", size=[0.012, 0.004, 0.01], pos=[0, -0.008, -0.012], mass=0.2
        )
        self._platform = self._carriage.add("body", name="wire_platform")
        self._rotation = self._platform.add(
            "joint",
            name="rotation",
            type="hinge",
            axis=[0, 0, 1],
            limited=False,
            damping=0.05,
            armature=0.01,
        )
        self._platform.add(
            "geom", name="wire_platform", type="cylinder", size=[0.008, 0.004], pos=[0, 0, -0.005], mass=0.05
        )
        self._wire_site = self._platform.add("site", name="wire_attachment", pos=[0, 0, 0], size=[0.001])

        # Catheter rotary platform and the two clamps (CathBot layout; not actuated here).
        cath = wb.add("body", name="catheter_platform", pos=[0, 0, base_z - 0.03])
        self._catheter_rotation = cath.add(
            "joint", name="catheter_rotation", type="hinge", axis=[0, 0, 1], damping=1.0, armature=0.01
        )
        cath.add("geom", name="catheter_platform", type="cylinder", size=[0.008, 0.004], mass=0.05)
        self._clamps = []
        for side, x in (("left", 0.006), ("right", -0.006)):
            clamp = self._carriage.add("body", name=f"clamp_{side}", pos=[x, 0, 0.008])
            joint = clamp.add(
                "joint",
                name=f"clamp_{side}",
                type="slide",
                axis=[1, 0, 0],
                range=[-0.003, 0.003],
                limited=True,
                damping=5.0,
                armature=0.01,
            )
            clamp.add("geom", name=f"clamp_{side}", type="box", size=[0.002, 0.003, 0.002], mass=0.01)
            self._clamps.append(joint)

        # Guide channel and introducer sheath: four thin walls around the wire path, from
        # the carriage's start to the outlet (the sheath's tip).
        half = wire_radius_m + channel_clearance_m
        wall = 0.5e-3
        channel_len = -base_z
        self.channel_length_m = float(channel_len)  # from the carriage's start to the outlet
        self.channel_half_width_m = float(half)  # of the square bore
        self.channel_outer_half_width_m = float(half + 2 * wall)  # of the walls' square outline
        introducer = dict(
            contype=geom_groups.WALL_CONTYPE,
            conaffinity=geom_groups.WALL_CONAFFINITY,
            solref=list(channel_solref),
            solimp=list(channel_solimp),
            # A lubricated introducer: frictionless (priority makes its condim win
            # over the wire's), so pinching in the channel does not eat the drive force.
            priority=1,
            condim=1,
        )
        self._guide_geoms = []
        for i, (dx, dy) in enumerate(((1, 0), (-1, 0), (0, 1), (0, -1))):
            size = [wall, half + 2 * wall, channel_len / 2] if dx else [half + 2 * wall, wall, channel_len / 2]
            self._guide_geoms.append(
                wb.add(
                    "geom",
                    name=f"guide{i}",
                    type="box",
                    size=size,
                    pos=[dx * (half + wall), dy * (half + wall), base_z / 2],
                    rgba=[0.45, 0.45, 0.5, 0.5],
                    **introducer,
                )
            )

        # Seal plate: a square plate with a square hole the bore's size, its vessel-side
        # face sheath_depth_m behind the outlet. Its four pieces reach in to the bore,
        # overlapping the channel walls (fixed geoms never collide with each other), so
        # no seam is left between plate and sheath. Collision group: a model of the
        # puncture's seal, not drawn in observations.
        self.sheath_depth_m = float(sheath_depth_m)
        self.seal_half_width_m = None if seal_half_width_m is None else float(seal_half_width_m)
        self.seal_thickness_m = float(seal_thickness_m)
        self._seal_geoms = []
        if seal_half_width_m is not None:
            outer = float(seal_half_width_m)
            if outer <= self.channel_outer_half_width_m:
                raise ValueError(
                    f"seal_half_width_m={seal_half_width_m} must exceed the sheath's outer "
                    f"half-width {self.channel_outer_half_width_m:.4g} m"
                )
            z = -sheath_depth_m - seal_thickness_m / 2
            t = seal_thickness_m / 2
            side = (outer - half) / 2  # half-size of a piece beside the bore
            pieces = (
                ([side, outer, t], [half + side, 0, z]),
                ([side, outer, t], [-(half + side), 0, z]),
                ([half, side, t], [0, half + side, z]),
                ([half, side, t], [0, -(half + side), z]),
            )
            for i, (size, pos) in enumerate(pieces):
                self._seal_geoms.append(
                    wb.add(
                        "geom",
                        name=f"seal{i}",
                        type="box",
                        size=size,
                        pos=pos,
                        group=geom_groups.COLLISION,
                        rgba=[0.45, 0.45, 0.5, 0.3],
                        **introducer,
                    )
                )

        # Integrated-velocity servos: d(setpoint)/dt = ctrl (joint units per second).
        self._insertion_actuator = root.actuator.add(
            "general",
            name="insertion",
            joint=self._insertion,
            dyntype="integrator",
            gainprm=[servo_stiffness_n_m],
            biastype="affine",
            biasprm=[0, -servo_stiffness_n_m, -2 * np.sqrt(servo_stiffness_n_m * 1.2)],
            ctrllimited=True,
            ctrlrange=[-max_insertion_speed_m_s, max_insertion_speed_m_s],
            actlimited=True,
            actrange=[0, stroke_m],
            forcelimited=True,
            forcerange=[-max_insertion_force_n, max_insertion_force_n],
        )
        self._rotation_actuator = root.actuator.add(
            "general",
            name="rotation",
            joint=self._rotation,
            dyntype="integrator",
            gainprm=[servo_stiffness_nm_rad],
            biastype="affine",
            biasprm=[0, -servo_stiffness_nm_rad, -2 * np.sqrt(servo_stiffness_nm_rad * 0.012)],
            ctrllimited=True,
            ctrlrange=[-max_rotation_speed_rad_s, max_rotation_speed_rad_s],
            actlimited=True,
            actrange=[-1e3, 1e3],
        )

    def _build_observables(self):
        return FollowerRobotObservables(self)

    @property
    def mjcf_model(self):
        return self._mjcf_root

    @property
    def wire_attachment_site(self):
        """Site on the guidewire rotary platform where the wire's proximal end is held."""
        return self._wire_site

    @property
    def joints(self):
        """The actuated joints: (insertion, rotation)."""
        return (self._insertion, self._rotation)

    @property
    def actuators(self):
        return (self._insertion_actuator, self._rotation_actuator)

    @property
    def guide_geoms(self):
        """The guide channel's walls (its distal part is the introducer sheath)."""
        return tuple(self._guide_geoms)

    @property
    def seal_geoms(self):
        """The seal plate's pieces (empty without a plate)."""
        return tuple(self._seal_geoms)

    def apply_action(self, physics, action):
        """Sets servo velocities from an action in [-1, 1]^2 (insertion, rotation)."""
        action = np.clip(np.asarray(action, dtype=float), -1.0, 1.0)
        physics.bind(self.actuators).ctrl = action * [self.max_insertion_speed_m_s, self.max_rotation_speed_rad_s]

    def insertion_m(self, physics) -> float:
        """Carriage travel from the start of the stroke, in metres."""
        return float(np.ravel(physics.bind(self._insertion).qpos)[0])

    def drive_force_n(self, physics) -> float:
        """Force the insertion drive applies to the carriage, in newtons (positive pushes)."""
        return float(np.ravel(physics.bind(self._insertion_actuator).force)[0])

    def pose_features(self, physics) -> np.ndarray:
        """[insertion / stroke, sin(rotation), cos(rotation)]: bounded and without wrap-around."""
        insertion, rotation = physics.bind(self.joints).qpos
        return np.array([insertion / self.stroke_m, np.sin(rotation), np.cos(rotation)])

    def rate_features(self, physics) -> np.ndarray:
        """Joint rates as fractions of the drive's maximum speeds (in [-1, 1] when driven)."""
        rates = physics.bind(self.joints).qvel
        return rates / [self.max_insertion_speed_m_s, self.max_rotation_speed_rad_s]

    def set_pose(self, physics, insertion_m: float = 0.0, rotation_rad: float = 0.0):
        """Puts the carriage at `insertion_m` and the platform at `rotation_rad`, at rest.

        Servo set points (actuator states) move with the joints, so the robot holds
        the new pose. A reset (``mj_resetData``) leaves the robot at (0, 0).
        """
        pose = np.array([insertion_m, rotation_rad], dtype=float)
        physics.bind(self.joints).qpos = pose
        physics.bind(self.joints).qvel = 0.0
        physics.bind(self.actuators).act = pose
        physics.bind(self.actuators).ctrl = 0.0


class FollowerRobotObservables(JointObservables):
    """joint_pos: insertion depth (m) and rotation angle (rad); joint_vel: their rates."""

    @composer.observable
    def pose_features(self):
        """[insertion / stroke, sin(rotation), cos(rotation)] (see `FollowerRobot.pose_features`)."""
        return observable.Generic(self._entity.pose_features)

    @composer.observable
    def rate_features(self):
        """Joint rates as fractions of the maximum drive speeds."""
        return observable.Generic(self._entity.rate_features)

    @composer.observable
    def drive_force(self):
        """Insertion drive force in newtons, as the robot measures it at its motor."""
        return observable.Generic(lambda physics: np.array([self._entity.drive_force_n(physics)]))
