"""A shaped catheter over the guidewire, modelled as the stiffer part of one coaxial rod.

Where a catheter covers the wire, the two bend together: each bending joint of the wire
chain that the catheter covers gets the catheter's stiffness added (k = k_wire + k_cath,
springs in parallel, with k_cath = E_cath I_cath / l over the joint's share l of the rod)
and a rest angle that is the stiffness-weighted mean of the wire's and the catheter's
(the equilibrium of two coaxial beams with different rest curvatures). Joint armature
and damping scale with k, as the wire's own do (`Guidewire`: both linear in k), so the
covered chain keeps the wire's time constants. This is the combined-beam treatment of
coaxial instruments used in interventional simulators (one beam whose properties vary
where instruments overlap); the chain is not remeshed, so the catheter's curve is
resolved by the joints under it: the wire's 1.5 mm tip pieces while the catheter is
flush with the tip, its 14 mm shaft pieces once the wire has been pushed 15 mm or more
out of it.

Simplifications, stated: the catheter's axial position is kinematic (a carriage sets it
relative to the wire; no catheter-wall friction or drive force is simulated); it turns
with the wire (its curve lies in the plane of the wire's own tip bend); and contacts keep
the wire's radius (a 5 F catheter is 1.67 mm across, the wire 0.89 mm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cathsim_dmc.core.checks import check_number
from cathsim_dmc.entities.guidewire import joint_rod_shares_m


@dataclass(frozen=True)
class Catheter:
    """A shaped catheter by its material and its tip curve (SI units).

    The default is a 5 F diagnostic catheter with a 90-degree curve over its last 15 mm
    (a headhunter-like shape): a braided polymer shaft whose effective modulus (assumed)
    gives a bending stiffness of 3.0e-4 N m^2, 12x the wire's soft tip and 2.5x its
    shaft. It takes a 0.035 in (0.89 mm) wire.
    """

    outer_diameter_m: float = 1.67e-3  # 5 F
    inner_diameter_m: float = 0.97e-3  # 0.038 in lumen
    youngs_modulus_pa: float = 0.89e9  # effective, braided polymer shaft (assumed)
    curve_deg: float = 90.0  # total rest bend of the distal curve
    curve_length_m: float = 0.015  # the curve is spread evenly over this distal length
    max_speed_m_s: float = 0.04  # the catheter carriage's speed at action +1 (as the wire's)

    def __post_init__(self):
        for key in ("outer_diameter_m", "youngs_modulus_pa", "curve_length_m", "max_speed_m_s"):
            check_number(f"Catheter {key}", getattr(self, key), 0.0, inclusive=False)
        check_number("Catheter inner_diameter_m", self.inner_diameter_m, 0.0)
        if not self.inner_diameter_m < self.outer_diameter_m:
            raise ValueError(
                f"Catheter inner_diameter_m={self.inner_diameter_m} must be smaller than "
                f"outer_diameter_m={self.outer_diameter_m}"
            )
        if not abs(check_number("Catheter curve_deg", self.curve_deg)) <= 180.0:
            raise ValueError(f"Catheter curve_deg={self.curve_deg!r} must lie in [-180, 180]")

    @property
    def bending_stiffness_nm2(self) -> float:
        """E I of the tube, I = pi (D^4 - d^4) / 64, in N m^2."""
        return self.youngs_modulus_pa * math.pi * (self.outer_diameter_m**4 - self.inner_diameter_m**4) / 64.0


# Named catheters for configs (`task.catheter=<name>`).
CATHETERS = {
    "angled_5f": Catheter(),
}


def catheter_named(name) -> Catheter:
    """The catheter `name` (a key of `CATHETERS`), or `name` itself if it is a `Catheter`."""
    if isinstance(name, Catheter):
        return name
    if isinstance(name, str) and name in CATHETERS:
        return CATHETERS[name]
    raise ValueError(f"catheter={name!r} is not a catheter; choose one of {sorted(CATHETERS)} (or null for none)")


class CatheterOverWire:
    """Applies a `Catheter` to a `Guidewire`'s joints in a compiled physics.

    `apply(physics, tip_offset_m)` covers the wire from `tip_offset_m` behind its tip
    back to its proximal end. Call `initialize(physics)` once per physics (it reads the
    wire's own joint values); `apply` then rewrites the covered joints' stiffness, rest
    angle, armature and damping in ``physics.model`` (the model arrays directly: nothing
    of the state changes, so no forward pass is due).
    """

    def __init__(self, catheter: Catheter, guidewire):
        self.catheter = catheter
        self._guidewire = guidewire
        lengths = np.asarray(guidewire.segment_lengths_m, dtype=float)
        n = len(lengths)
        # Two hinges per joint, x then y; joint i sits at the start of segment i.
        from_tip = np.array([lengths[i:].sum() for i in range(1, n)])
        before, after = (np.array(share) for share in joint_rod_shares_m(lengths))
        self._from_tip_m = np.repeat(from_tip, 2)
        self._before_m = np.repeat(before, 2)
        self._after_m = np.repeat(after, 2)
        self._bends_y = np.tile([False, True], n - 1)  # the wire's tip curve is about y
        self._ids = None

    def initialize(self, physics) -> None:
        """Reads the wire's own joint values from `physics` (once per compiled model)."""
        model = physics.model
        ids = np.asarray(physics.bind(self._guidewire.joints).element_id)
        if len(ids) != len(self._from_tip_m):
            raise ValueError(f"the wire has {len(ids)} bending hinges; expected {len(self._from_tip_m)}")
        self._ids = ids
        self._qpos_adr = model.jnt_qposadr[ids]
        self._dof_adr = model.jnt_dofadr[ids]
        self._k0 = model.jnt_stiffness[ids].copy()
        self._ref0 = model.qpos_spring[self._qpos_adr].copy()
        self._armature0 = model.dof_armature[self._dof_adr].copy()
        self._damping0 = model.dof_damping[self._dof_adr].copy()

    def joint_values(self, tip_offset_m: float, sheath_from_m: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """(stiffness, rest angle) of every wire hinge with the catheter's tip `tip_offset_m` behind the wire's tip.

        The wire from `sheath_from_m` behind its tip backwards lies in the introducer sheath,
        which holds wire and catheter straight and coaxial: the catheter adds nothing there
        (pressed into the straight sheath, its curve pinched the wire and stalled the drive;
        its stiffness alone changed how the wire buckles in the channel's clearance, which
        models nothing real). A parked catheter therefore leaves the wire as it is.
        """
        # Each hinge's share of rod in catheter coordinates (from the catheter's tip, backwards).
        lo = self._from_tip_m - self._after_m - tip_offset_m
        hi = self._from_tip_m + self._before_m - tip_offset_m
        span = hi - lo
        outside_sheath_m = sheath_from_m - tip_offset_m  # the catheter's length out of the sheath
        covered_m = np.clip(np.minimum(hi, outside_sheath_m) - np.maximum(lo, 0.0), 0.0, None)
        k_catheter = covered_m * self.catheter.bending_stiffness_nm2 / span**2
        # The catheter's rest bend on a hinge: its curve's angle over the hinge's covered share
        # (only the hinges about y bend). Its spring moment is then E I / span x that angle,
        # as for a beam piece with that rest curvature.
        curve_end_m = min(self.catheter.curve_length_m, outside_sheath_m)
        in_curve_m = np.clip(np.minimum(hi, curve_end_m) - np.maximum(lo, 0.0), 0.0, None)
        curve_rad = np.where(
            self._bends_y, math.radians(self.catheter.curve_deg) * in_curve_m / self.catheter.curve_length_m, 0.0
        )
        stiffness = self._k0 + k_catheter
        covered = k_catheter > 0
        rest = np.where(
            covered,
            (self._k0 * self._ref0 + self.catheter.bending_stiffness_nm2 / span * curve_rad) / stiffness,
            self._ref0,
        )
        return stiffness, rest

    def apply(self, physics, tip_offset_m: float, sheath_from_m: float = np.inf) -> None:
        """Covers the wire from `tip_offset_m` (>= 0, metres) behind its tip back to
        `sheath_from_m` behind it, where the sheath begins (see `joint_values`)."""
        if self._ids is None:
            raise RuntimeError("CatheterOverWire.initialize(physics) was not called")
        stiffness, rest = self.joint_values(max(0.0, float(tip_offset_m)), sheath_from_m)
        model = physics.model.ptr
        scale = stiffness / self._k0
        model.jnt_stiffness[self._ids] = stiffness
        model.qpos_spring[self._qpos_adr] = rest
        model.dof_armature[self._dof_adr] = self._armature0 * scale
        model.dof_damping[self._dof_adr] = self._damping0 * scale


class CatheterDrive:
    """The catheter's carriage on a `FollowerRobot`: where the catheter lies along the wire.

    The catheter starts each episode parked, its tip at the sheath's (the robot's outlet),
    the wire's shaped tip out of it. Each control step the wire moves under it (the
    catheter keeps its place) and the carriage moves it by its command (+1:
    `Catheter.max_speed_m_s` forwards); it can pass neither the wire's tip nor go back
    into the sheath. Its position covers the wire through `CatheterOverWire`.
    """

    def __init__(self, catheter: Catheter, guidewire, robot):
        self.catheter = catheter
        self._over_wire = CatheterOverWire(catheter, guidewire)
        self._robot = robot
        self._model_key = None  # the compiled model the wire's own joint values were read from
        self._out_m = 0.0  # the catheter's tip past the sheath's tip, along the wire
        self._offset_m = 0.0
        self._command = 0.0
        self._rate = 0.0

    @property
    def offset_m(self) -> float:
        """How far the catheter's tip lies behind the wire's tip, along the wire, in metres (0: flush)."""
        return self._offset_m

    @property
    def rate(self) -> float:
        """The carriage's speed over the last control step as its encoder measures it: the
        distance it moved over `Catheter.max_speed_m_s` times the step (0 where a limit held it)."""
        return self._rate

    def initialize_episode(self, physics) -> None:
        """Parks the catheter (its tip at the sheath's) and covers the wire accordingly."""
        if self._model_key != id(physics.model.ptr):  # a new compiled model: read the wire's own joints
            self._over_wire.initialize(physics)
            self._model_key = id(physics.model.ptr)
        self._out_m = 0.0
        self._command = 0.0
        self._rate = 0.0
        self._cover(physics)

    def set_command(self, command: float) -> None:
        """The carriage's speed for the coming control step, as a fraction of `max_speed_m_s` (clipped to [-1, 1])."""
        self._command = float(np.clip(command, -1.0, 1.0))

    def move(self, physics, duration_s: float) -> None:
        """The carriage's move over a control step of `duration_s` seconds, then the wire covered anew."""
        moved_m = self._command * self.catheter.max_speed_m_s * duration_s
        out_m = float(np.clip(self._out_m + moved_m, 0.0, self._wire_out_of_sheath_m(physics)))
        full_m = self.catheter.max_speed_m_s * duration_s
        self._rate = (out_m - self._out_m) / full_m if full_m > 0 else 0.0
        self._out_m = out_m
        self._cover(physics)

    def _wire_out_of_sheath_m(self, physics) -> float:
        """How far the wire's tip lies past the sheath's tip, along the wire: its start
        length plus the carriage's travel."""
        return self._robot.initial_insertion_m + self._robot.insertion_m(physics)

    def _cover(self, physics) -> None:
        wire_out_m = self._wire_out_of_sheath_m(physics)
        self._offset_m = max(0.0, wire_out_m - self._out_m)
        self._over_wire.apply(physics, self._offset_m, sheath_from_m=wire_out_m)
