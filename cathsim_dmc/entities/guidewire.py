"""Guidewire: a chain of capsule segments whose bending stiffness comes from its material.

The wire lies along its own +z axis, from the proximal end (the entity's origin, where a
robot holds it) to the distal tip. Each segment is joined to the previous one by two
hinges (bending about x and about y); there is no twist hinge, so the chain is
torsionally rigid and a rotation of the proximal end turns the tip 1:1, as a real,
torsionally stiff wire does.

Bending stiffness per joint is k = E I / l, with I = pi d^4 / 64 and l the length of
rod the joint stands for (half of each neighbouring segment; in series where the
modulus changes): a discrete Euler-Bernoulli rod, so a finer or coarser chain is the
same physical wire. The proximal segment is half length, which puts every joint at the
midpoint of the rod piece it represents (midpoint rule): a clamped cantilever then
deflects within ~0.1% of beam theory at 20 segments, instead of -1.5/n with the joints
at the piece ends. The distal ``tip_length_m`` is softer and pre-shaped through the spring
rest angles of its joints.
"""

from __future__ import annotations

import math

import numpy as np
from dm_control import composer, mjcf
from dm_control.composer.observation import observable

from cathsim_dmc.core.checks import check_number, check_parameters
from cathsim_dmc.entities.observables import JointObservables
from cathsim_dmc.sim import geom_groups

TIP_SHAPES = ("straight", "angled", "j")


def second_moment_of_area(diameter_m: float) -> float:
    """I = pi d^4 / 64 for a solid round section, in m^4."""
    return math.pi * diameter_m**4 / 64.0


def joint_rod_shares_m(segment_lengths_m) -> tuple[list, list]:
    """(before, after): the rod each bending joint stands for, in metres, on each side.

    Joint i (1..n-1) sits at the start of segment i and stands for half of each
    neighbouring segment, all of the held proximal one (the midpoint rule).
    """
    lengths = list(segment_lengths_m)
    before = [lengths[0] if i == 1 else lengths[i - 1] / 2 for i in range(1, len(lengths))]
    after = [length / 2 for length in lengths[1:]]
    return before, after


def quasi_static_armature(stiffness: float, timestep_s: float) -> float:
    """Joint armature (kg m^2) that bounds a spring joint's frequency to 0.5 / timestep.

    A chain of springs k has modes up to 2 sqrt(k / a); with a = 16 k dt^2 the fastest
    mode satisfies omega dt <= 0.5, well inside the explicit limit of 2. The armature
    only adds inertia to bending, which is negligible for a quasi-static wire in blood.
    """
    return 16.0 * stiffness * timestep_s**2


class Guidewire(composer.Entity):
    """A guidewire: torsionally rigid hinge chain, softer pre-shaped tip."""

    def _build(
        self,
        length_m: float = 0.35,
        diameter_m: float = 0.89e-3,  # 0.035 in, the most common peripheral guidewire
        core_diameter_m: float | None = 0.5e-3,  # nitinol core under the polymer jacket (assumed)
        n_segments: int = 24,  # 14 mm shaft pieces: beam error < 0.3% with midpoint joints
        n_tip_segments: int = 10,  # 1.5 mm tip pieces carry the shaped curve
        # nitinol, austenite 40-75 GPa (Duerig et al. 1999); low end for a jacketed core
        youngs_modulus_pa: float = 40e9,
        tip_youngs_modulus_pa: float = 8e9,  # tapered tip core: 5x softer than the shaft
        tip_length_m: float = 0.015,  # a 20 mm bent tip spans a branch and rides its wall (expert: 93/96 vs 95/96)
        tip_shape: str = "angled",
        tip_angle_deg: float = 45.0,
        density_kg_m3: float = 6450.0,  # nitinol
        friction: float = 0.1,  # hydrophilic-coated wire on wet vessel wall (~0.05-0.15)
        contact_solref: tuple | None = None,
        contact_solimp: tuple = (0.99, 0.999, 0.0005, 0.5, 2),
        mass_scale: float | None = None,
        physics_timestep_s: float = 0.005,
        damping_ratio: float = 1.0,
        name: str = "guidewire",
    ):
        """Builds the wire.

        Args:
          length_m: simulated wire length in metres (the distal part that can reach
            the vessel; the rest of a real wire stays outside the patient).
          diameter_m: outer diameter in metres (contact and drawing).
          core_diameter_m: diameter in metres of the load-bearing core that sets the
            bending stiffness (I = pi d_core^4 / 64); None for a solid wire. Hydrophilic
            0.035 in wires are a thin nitinol core in a soft polymer jacket: a solid
            0.89 mm nitinol rod is ~10x stiffer (EI 1.2e-3 vs 1.2e-4 N m^2) and, measured
            here, could not be steered into the branches of type II/III arches.
          n_segments: number of shaft segments.
          n_tip_segments: number of (shorter) tip segments.
          youngs_modulus_pa: shaft Young's modulus in Pa.
          tip_youngs_modulus_pa: tip Young's modulus in Pa.
          tip_length_m: length of the soft, shaped tip in metres.
          tip_shape: "straight", "angled" (bend of `tip_angle_deg` over the proximal
            half of the tip) or "j" (bend of `tip_angle_deg`, default 180 for a J,
            spread over the whole tip).
          tip_angle_deg: total rest bend of the tip in degrees.
          density_kg_m3: material density in kg/m^3.
          friction: sliding friction coefficient with the vessel wall.
          contact_solref: contact time constant (s) and damping ratio; default
            (2 timesteps, 1), the stiffest MuJoCo allows. MuJoCo mixes the two geoms'
            values, so the wall should carry the same.
          contact_solimp: contact impedance; near 1 keeps penetration sub-millimetre.
          mass_scale: quasi-static mass scaling of the segments. A wire in blood is
            overdamped and its inertia negligible; heavier segments make wall contacts
            stiff enough to stop snap-through tunnelling without changing statics.
            Default max(2500, 100 x (timestep / 2 ms)^2), x2500 at 5 and 10 ms:
            MuJoCo's contact stiffness scales with mass / solref^2 and solref is 2
            timesteps, so at least 100 x (dt / 2 ms)^2 keeps the contact as stiff as
            the escape-free 2 ms setting (measured at 10 ms: x2500 gave 0 escapes
            where x625 let the wire out). At 5 ms, x625 was escape-free too, but the
            lighter tip flicked past ostia: the scripted expert entered the type III
            LCCA in 0 of 4 episodes, against 4 of 4 with x2500.
          physics_timestep_s: the simulation timestep the wire is tuned for (sets
            armature, damping, contact time constant and mass scaling). 5 ms: with
            24 shaft segments about 15x faster in wall contact than 2 ms with 64, with
            the insertion response of the 2 ms wire. 10 ms is a fast option (about 2x
            faster again) whose 2500x heavier wire lags the 5 N insertion drive by
            ~2 mm after 1 s of full insertion and drifts from the 5 ms tip paths by
            10-20 mm RMS.
          damping_ratio: joint damping as a fraction of critical damping.
          name: model name.
        """
        if tip_shape not in TIP_SHAPES:
            raise ValueError(f"tip_shape={tip_shape!r} is not one of {TIP_SHAPES}")
        # A non-positive modulus or density compiles, and fails only at the first physics step.
        for key, value in (
            ("length_m", length_m),
            ("diameter_m", diameter_m),
            ("youngs_modulus_pa", youngs_modulus_pa),
            ("tip_youngs_modulus_pa", tip_youngs_modulus_pa),
            ("density_kg_m3", density_kg_m3),
            ("physics_timestep_s", physics_timestep_s),
        ):
            check_number(f"Guidewire {key}", value, 0.0, inclusive=False)
        # (MuJoCo reads a negative solref as stiffness and damping: only finiteness is checked)
        check_parameters(
            "Guidewire",
            positive=dict(core_diameter_m=core_diameter_m, mass_scale=mass_scale),
            non_negative=dict(friction=friction, damping_ratio=damping_ratio),
            finite=dict(tip_angle_deg=tip_angle_deg, contact_solref=contact_solref, contact_solimp=contact_solimp),
        )
        check_number("Guidewire n_segments", n_segments, 2, whole=True)
        check_number("Guidewire n_tip_segments", n_tip_segments, 1, whole=True)
        if not 0 < tip_length_m < length_m:
            raise ValueError(f"tip_length_m={tip_length_m} must lie in (0, length_m={length_m})")
        if n_segments < 2 or n_tip_segments < 1:
            raise ValueError("need n_segments >= 2 and n_tip_segments >= 1")

        self._mjcf_root = mjcf.RootElement(model=name)
        self._mjcf_root.compiler.angle = "radian"  # springref below is in radians
        self.length_m = float(length_m)
        self.diameter_m = float(diameter_m)
        self.radius_m = diameter_m / 2.0
        self.core_diameter_m = float(diameter_m if core_diameter_m is None else core_diameter_m)
        if not 0 < self.core_diameter_m <= self.diameter_m:
            raise ValueError(f"core_diameter_m={core_diameter_m} must lie in (0, diameter_m={diameter_m}]")
        self.tip_length_m = float(tip_length_m)
        self.physics_timestep_s = float(physics_timestep_s)
        if mass_scale is None:
            mass_scale = max(2500.0, 100.0 * (physics_timestep_s / 0.002) ** 2)
        if contact_solref is None:
            contact_solref = (2.0 * physics_timestep_s, 1.0)
        self.mass_scale = float(mass_scale)
        self.contact_solref = tuple(contact_solref)
        self.contact_solimp = tuple(contact_solimp)

        # Half-length proximal segment: see the module docstring (midpoint rule).
        shaft_l = (length_m - tip_length_m) / (n_segments - 0.5)
        tip_l = tip_length_m / n_tip_segments
        seg_lengths = [shaft_l / 2] + [shaft_l] * (n_segments - 1) + [tip_l] * n_tip_segments
        seg_moduli = [youngs_modulus_pa] * n_segments + [tip_youngs_modulus_pa] * n_tip_segments
        inertia_area = second_moment_of_area(self.core_diameter_m)
        self.bending_stiffness_nm2 = youngs_modulus_pa * inertia_area  # EI of the shaft
        self.tip_bending_stiffness_nm2 = tip_youngs_modulus_pa * inertia_area

        rest_angles = self._tip_rest_angles(tip_shape, math.radians(tip_angle_deg), n_tip_segments)

        default = self._mjcf_root.default
        default.geom.set_attributes(
            type="capsule",
            size=[self.radius_m],
            contype=geom_groups.WIRE_CONTYPE,
            conaffinity=geom_groups.WIRE_CONAFFINITY,
            condim=3,
            friction=[friction, 0.005, 0.0001],
            margin=0,
            solref=list(contact_solref),
            solimp=list(contact_solimp),
            group=geom_groups.WIRE,
            rgba=[0.95, 0.95, 0.9, 1],  # bright: it must stand out through the see-through vessel
        )
        default.joint.set_attributes(type="hinge", limited=False)

        self._segments = []
        self._joints = []
        self._stiffness = []
        parent = self._mjcf_root.worldbody
        shares_before, _ = joint_rod_shares_m(seg_lengths)
        for i, (seg_l, modulus) in enumerate(zip(seg_lengths, seg_moduli)):
            # gravcomp: the wire's weight is negligible against its stiffness and nearly
            # cancelled by buoyancy in blood; compensating it keeps the scaled mass from sagging.
            body = parent.add("body", name=f"seg{i}", pos=[0, 0, 0 if i == 0 else seg_lengths[i - 1]], gravcomp=1)
            # Real mass is ~2e-5 kg per 5 mm segment; see `mass_scale`.
            mass = density_kg_m3 * math.pi * self.radius_m**2 * seg_l * mass_scale
            body.add("geom", name=f"geom{i}", fromto=[0, 0, 0, 0, 0, seg_l], mass=mass)
            if i > 0:
                # The joint stands for half of each neighbouring segment (all of the
                # held proximal one), as two beam pieces in series.
                before = shares_before[i - 1]
                compliance = before / seg_moduli[i - 1] + (seg_l / 2) / modulus
                k = inertia_area / compliance
                armature = quasi_static_armature(k, physics_timestep_s)
                damping = damping_ratio * 2.0 * math.sqrt(k * armature)
                tip_index = i - n_segments  # >= 0 for joints inside the tip
                # The tip's rest bend is about y: the tip curves towards the wire's local +x.
                ref_y = rest_angles[tip_index] if tip_index >= 0 else 0.0
                for axis_name, axis, ref in (("x", [1, 0, 0], 0.0), ("y", [0, 1, 0], ref_y)):
                    joint = body.add(
                        "joint",
                        name=f"bend{i}_{axis_name}",
                        axis=axis,
                        stiffness=k,
                        springref=ref,
                        armature=armature,
                        damping=damping,
                    )
                    self._joints.append(joint)
                    self._stiffness.append(k)
            self._segments.append(body)
            parent = body
        self._rest_qpos = np.array([j.springref for j in self._joints], dtype=float)
        self._tip_site = parent.add(
            "site",
            name="tip",
            pos=[0, 0, seg_lengths[-1]],
            size=[self.radius_m * 1.2],
            rgba=[1, 0, 0, 1],
            group=geom_groups.MARKER,
        )
        # Where the tip's pre-shaped curve begins: a better steering reference than the
        # tip itself, whose offset is its own bend.
        self._tip_base_site = self._segments[n_segments].add(
            "site",
            name="tip_base",
            pos=[0, 0, 0],
            size=[self.radius_m],
            rgba=[0, 1, 0, 1],
            group=geom_groups.MARKER,
        )
        self.segment_lengths_m = np.array(seg_lengths)

    @staticmethod
    def _tip_rest_angles(shape: str, total_rad: float, n_tip: int) -> np.ndarray:
        """Rest angle of each tip joint (joint j sits at the start of tip segment j)."""
        angles = np.zeros(n_tip)
        if shape == "angled":
            n_bend = max(1, n_tip // 2)
            angles[1 : 1 + n_bend] = total_rad / n_bend
        elif shape == "j":
            angles[1:] = total_rad / max(1, n_tip - 1)
        return angles

    def _build_observables(self):
        return GuidewireObservables(self)

    @property
    def mjcf_model(self):
        return self._mjcf_root

    @property
    def segments(self):
        """Segment bodies, proximal to distal."""
        return tuple(self._segments)

    @property
    def joints(self):
        """Bending hinges, two per joint (x then y), proximal to distal."""
        return tuple(self._joints)

    @composer.cached_property
    def geoms(self):
        return tuple(self._mjcf_root.find_all("geom"))

    @property
    def tip_site(self):
        return self._tip_site

    @property
    def tip_base_site(self):
        return self._tip_base_site

    @property
    def rest_qpos(self) -> np.ndarray:
        """Joint angles (rad) of the unloaded wire: straight shaft, shaped tip."""
        return self._rest_qpos.copy()

    @property
    def joint_stiffness(self) -> np.ndarray:
        """Stiffness of each bending hinge in N m / rad (E I / l)."""
        return np.array(self._stiffness)

    def initialize_episode(self, physics, random_state):
        physics.bind(self._joints).qpos = self._rest_qpos
        physics.bind(self._joints).qvel = 0.0


class GuidewireObservables(JointObservables):
    """Bending angles and rates (joint_pos, joint_vel), tip and segment positions."""

    @composer.observable
    def tip_position(self):
        return observable.MJCFFeature("xpos", self._entity.tip_site)

    @composer.observable
    def segment_positions(self):
        return observable.MJCFFeature("xpos", self._entity.segments)
