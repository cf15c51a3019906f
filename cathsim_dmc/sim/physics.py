"""Solver settings, contact forces between the wire and the vessel, and divergence detection.

MuJoCo fills ``data.contact`` and ``data.efc_force`` during ``mj_step`` *before* it
integrates, so right after a step they describe the previous state. `wire_contacts`
therefore runs ``mj_forward`` (position, velocity and constraint stages, no
integration) to read forces that belong to the current state. After dm_control's
(legacy) step, which ends with ``mj_step1``, the position and velocity stages are
already current: `forward_from_velocity_stage` then runs only the rest.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import mujoco
import numpy as np
from dm_control import mjcf

_WARNINGS_DIVERGENT = (
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQPOS,
)


@dataclass(frozen=True)
class PhysicsSettings:
    """MuJoCo solver settings of a scene, written into its MJCF ``option`` (`apply`).

    Every value is set explicitly: dm_control's arena template sets
    ``noslip_iterations=5`` and ``noslip_tolerance=0``, which a scene inherited
    silently before these settings existed.
    """

    solver: str  # MJCF keyword: "Newton", "CG" or "PGS"
    iterations: int  # solver iterations at most
    tolerance: float  # solver's relative cost-improvement tolerance (early stop)
    ls_iterations: int  # line-search iterations (Newton and CG)
    ls_tolerance: float
    jacobian: str  # "dense", "sparse" or "auto" (MuJoCo: sparse from 60 DOF on; the wire has 71)
    noslip_iterations: int  # post-solve friction projection (0: off)
    noslip_tolerance: float  # 0: always run all noslip iterations
    sleep: bool  # MuJoCo's sleeping of trees at rest (option/flag sleep)
    wall: str = "prisms"  # the vessel wall's representation (`Aorta(wall=...)`): "prisms" or "field"

    def apply(self, mjcf_root) -> None:
        """Writes the solver settings into `mjcf_root.option` (a dm_control MJCF root);
        the wall is the aorta's to build (`tasks.build_task` passes it on)."""
        values = asdict(self)
        values.pop("wall")
        sleep = values.pop("sleep")
        mjcf_root.option.set_attributes(**values)
        mjcf_root.option.flag.sleep = "enable" if sleep else "disable"


# `accurate`: what the scene compiled to before the settings were explicit (Newton with
# MuJoCo's defaults, noslip as dm_control's arena set it); trajectories are bit-identical.
# `fast` (issue 20's probe, about twice the speed in wall contact): PGS capped at
# 10 iterations, dense Jacobian, noslip off, sleep on. Rejected there: pyramidal cones
# (forces ~35% lower), condim 1, Newton at 3 iterations (diverged), tolerance 1e-3 (lost
# contacts). `fast_field`: the same solver with the wall as a distance field
# (`cathsim_dmc.sim.wall_field`; collision took most of a `fast` step), 1.6-1.9x the
# environment's speed; not the default: the default training recipe did worse under it
# on three seeds (docs/model.md). All keep the elliptic cones, implicitfast integrator
# and timestep set by the arena and the wire.
_PGS = dict(
    solver="PGS",
    iterations=10,
    tolerance=1e-8,
    ls_iterations=50,
    ls_tolerance=0.01,
    jacobian="dense",
    noslip_iterations=0,
    noslip_tolerance=0.0,
    sleep=True,
)
PHYSICS_SETTINGS = {
    "accurate": PhysicsSettings(
        solver="Newton",
        iterations=100,
        tolerance=1e-8,
        ls_iterations=50,
        ls_tolerance=0.01,
        jacobian="auto",
        noslip_iterations=5,
        noslip_tolerance=0.0,
        sleep=False,
    ),
    "fast": PhysicsSettings(**_PGS, wall="prisms"),
    "fast_field": PhysicsSettings(**_PGS, wall="field"),
}
# The PGS settings passed the fidelity gate against `accurate` (2026-11-25), the field wall
# against `fast` (2026-11-26): experiments/fidelity_gate.py; docs/model.md, "Solver settings".
# The default, "fast", is cathsim_dmc.core.task_defaults.PHYSICS (the command-line tools' too).


def physics_settings(physics) -> PhysicsSettings:
    """The settings named `physics` (or `physics` itself, if it is a `PhysicsSettings`);
    ValueError naming the choices otherwise."""
    if isinstance(physics, PhysicsSettings):
        return physics
    if isinstance(physics, str) and physics in PHYSICS_SETTINGS:
        return PHYSICS_SETTINGS[physics]
    raise ValueError(f"physics={physics!r} is not a physics setting; choose one of {list(PHYSICS_SETTINGS)}")


@dataclass(frozen=True)
class ContactForces:
    """Wire-vessel contact forces at one instant (forces act on the vessel, newtons)."""

    forces_n: np.ndarray  # (n, 3) world-frame force of each contact (normal + friction)
    positions_m: np.ndarray  # (n, 3) contact points in metres
    wire_geom_ids: np.ndarray  # (n,) which wire geom touches

    @property
    def magnitudes_n(self) -> np.ndarray:
        return np.linalg.norm(self.forces_n, axis=1)

    @property
    def total_n(self) -> float:
        """Sum of contact force magnitudes: the total load the wire puts on the wall."""
        return float(self.magnitudes_n.sum())

    @property
    def max_n(self) -> float:
        return float(self.magnitudes_n.max()) if len(self.forces_n) else 0.0

    @property
    def count(self) -> int:
        return len(self.forces_n)


def _wire_contact_rows(data, is_wire_geom: np.ndarray, is_vessel_geom: np.ndarray | None):
    """(geom pairs, geom1-is-wire, keep) over ``data.contact[:ncon]``: the contacts
    between a wire geom and a non-wire (vessel, if given) geom that have constraint rows."""
    contact = data.contact
    geom = contact.geom[: data.ncon]
    wire1 = is_wire_geom[geom[:, 0]]
    keep = (wire1 ^ is_wire_geom[geom[:, 1]]) & (contact.efc_address[: data.ncon] >= 0)
    if is_vessel_geom is not None:
        keep &= is_vessel_geom[geom[:, 0]] | is_vessel_geom[geom[:, 1]]
    return geom, wire1, keep


def _local_forces(data, keep: np.ndarray) -> np.ndarray:
    """(n, 3) forces of the kept contacts in their contact frames (normal, tangential x2).

    Elliptic cones (the arena's setting): a contact's rows are its normal, then its
    tangential forces. A frictionless contact (dim 1) has only the normal row.
    """
    address = data.contact.efc_address[: data.ncon][keep]
    dim = data.contact.dim[: data.ncon][keep]
    local = np.zeros((len(address), 3))
    local[:, 0] = data.efc_force[address]
    has_friction = dim >= 3
    if has_friction.any():
        local[has_friction, 1] = data.efc_force[address[has_friction] + 1]
        local[has_friction, 2] = data.efc_force[address[has_friction] + 2]
    return local


def wire_contacts(
    physics, is_wire_geom: np.ndarray, recompute: bool = True, is_vessel_geom: np.ndarray | None = None
) -> ContactForces:
    """Contact forces between wire geoms and other geoms.

    Args:
      physics: a dm_control Physics.
      is_wire_geom: boolean array over all geom ids, True for the wire's geoms.
      recompute: run ``mj_forward`` first so that the forces match the current state.
      is_vessel_geom: boolean array over all geom ids; if given, only contacts with these
        geoms count (so the robot's guide channel, which is not tissue, is left out).
    """
    model, data = physics.model.ptr, physics.data.ptr
    if recompute:
        mujoco.mj_forward(model, data)
    empty = np.zeros((0, 3))
    if data.ncon == 0:
        return ContactForces(empty, empty, np.zeros(0, dtype=int))
    geom, wire1, keep = _wire_contact_rows(data, is_wire_geom, is_vessel_geom)
    if not keep.any():
        return ContactForces(empty, empty, np.zeros(0, dtype=int))
    frame = data.contact.frame[: data.ncon][keep].reshape(-1, 3, 3)
    forces = np.einsum("nij,ni->nj", frame, _local_forces(data, keep))
    # The contact normal points from geom1 to geom2: make every force the one acting on
    # the non-wire geom (the vessel), whichever side the wire is.
    sign = np.where(wire1[keep], 1.0, -1.0)
    forces *= sign[:, None]
    wire_ids = np.where(wire1[keep], geom[keep, 0], geom[keep, 1])
    return ContactForces(forces, data.contact.pos[: data.ncon][keep].copy(), wire_ids)


def forward_from_velocity_stage(physics) -> None:
    """``mj_forward`` for a state whose position and velocity stages are current.

    dm_control's legacy step (the composer default) ends every physics step with
    ``mj_step1``, which computes positions, contacts, constraint rows and velocities
    of the new state; only the actuation, acceleration and constraint-force stages are
    missing. This runs those (``mj_forwardSkip`` from ``mjSTAGE_VEL``, sensors
    included): the same data as ``mj_forward``, bit for bit, without the collision
    and position stages (0.35-0.45 of ``mj_forward``'s time, measured in the arch). On
    any other state it gives stale contacts: use ``mj_forward`` there.
    """
    mujoco.mj_forwardSkip(physics.model.ptr, physics.data.ptr, mujoco.mjtStage.mjSTAGE_VEL, 0)


class WallForceTotal:
    """`total_contact_force_n` for fixed geom masks, cheap enough for every physics step.

    `total_n(data)` reads the same contacts and gives the same float, bit for bit, with
    fewer NumPy calls (0.65-0.77 of the time per physics step, measured on an expert
    episode): one code per geom (1 wire, 2 vessel) marks the wire-vessel pairs with one
    look-up, and the rows of elliptic contacts with friction (normal, two tangents,
    consecutive) are gathered with one index.
    """

    _ROWS = np.arange(3)

    def __init__(self, is_wire_geom: np.ndarray, is_vessel_geom: np.ndarray):
        wire, vessel = np.asarray(is_wire_geom, dtype=bool), np.asarray(is_vessel_geom, dtype=bool)
        if (wire & vessel).any():
            raise ValueError("a geom cannot be both a wire geom and a vessel geom")
        # Only a wire-vessel pair sums to 3 (wire-wire 2, vessel-vessel 4, with others 0-2).
        self._code = wire.astype(np.int8) + 2 * vessel.astype(np.int8)

    def total_n(self, data) -> float:
        """Sum of the wire-vessel contact force magnitudes in `data` (a ``mujoco.MjData``)."""
        n = data.ncon
        if n == 0:
            return 0.0
        contact = data.contact
        pair = self._code[contact.geom[:n]]
        address = contact.efc_address[:n]
        keep = (pair[:, 0] + pair[:, 1] == 3) & (address >= 0)
        if not keep.any():
            return 0.0
        if contact.dim[:n][keep].min() >= 3:
            local = data.efc_force[address[keep][:, None] + self._ROWS]
        else:  # a frictionless contact has only its normal row
            local = _local_forces(data, keep)
        # np.linalg.norm(local, axis=1), spelled out (the same operations, a third of the calls).
        return float(np.sqrt((local * local).sum(axis=1)).sum())


class ConstraintSensingPhysics(mjcf.Physics):
    """An `mjcf.Physics` that can report the constraint forces of every physics step.

    dm_control's (legacy) step runs ``mj_step2`` (constraint solve, then integration)
    followed by ``mj_step1`` (collision for the new state). A task's ``after_substep``
    hook therefore sees the new contacts next to a stale, or freshly allocated,
    ``efc_force``; reading forces there gives garbage. This class calls
    ``after_constraint_solve(physics)``, when set, between the two halves, where
    ``data.contact`` and ``data.efc_force`` belong to the same (pre-integration)
    state. The sequence of MuJoCo calls is unchanged, so the dynamics are identical.
    """

    after_constraint_solve = None  # callable(physics), or None for the plain step
    _binding_writes = 0  # how many binding writes have marked this physics dirty
    _writes_before_last_step = -1

    def mark_as_dirty(self):
        self._binding_writes += 1
        super().mark_as_dirty()

    def step(self, nstep: int = 1) -> None:
        super().step(nstep)
        self._writes_before_last_step = self._binding_writes

    def complete_stepped_state(self) -> bool:
        """Computes the acceleration stage of the state the last step left; True if it did.

        dm_control's legacy step ends with ``mj_step1``: positions, contacts and velocities
        of the new state are current, accelerations and constraint forces are not. The
        rest of ``mj_forward`` (`forward_from_velocity_stage`) makes the whole state
        current, the same data bit for bit. It also clears the dirty flag that a binding
        write before the step (the drive's ``ctrl``, every control step) leaves behind:
        the flag outlives the step that consumed the write, and the next binding read
        would otherwise run a full ``mj_forward``, collision included. Nothing happens
        (False) after a non-legacy step or if anything was written through a binding
        since the step: then the full forward stays due, as before.
        """
        if not self.legacy_step or self._binding_writes != self._writes_before_last_step:
            return False
        forward_from_velocity_stage(self)
        # mjcf.Physics clears it only in forward(), the full mj_forward this saves (tests/test_upstream_internals.py).
        self._dirty = False
        return True

    # dm_control's legacy step is this private method (mj_step2, then mj_step1): the one place between the halves.
    def _step_with_up_to_date_position_velocity(self, nstep: int = 1) -> None:
        callback = self.after_constraint_solve
        if callback is None or self.model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4:
            super()._step_with_up_to_date_position_velocity(nstep)
            return
        model, data = self.model.ptr, self.data.ptr
        for _ in range(nstep):
            mujoco.mj_step2(model, data)
            callback(self)
            mujoco.mj_step1(model, data)


class ControlStepForce:
    """The wall force of each control step: the mean and the largest of its physics steps' totals (N).

    A control step runs many physics steps (twenty by default) and an impact can last one
    of them, so the force at the step's end says little about the step. Per episode,
    `start(physics, is_wire_geom, is_vessel_geom, total_n)` sets the masks and the start
    state's total, and hooks `add` into a `ConstraintSensingPhysics` (called after every
    physics step's constraint solve, where contacts and forces belong to one state). Per
    control step, `begin_step()` before it and `end_step(end_total_n)` after it; in a
    physics without the hook, the mean and the peak fall back to `end_total_n()`.
    """

    def __init__(self):
        self.mean_n = self.peak_n = 0.0  # of the last control step (at reset: the start state's total)
        self._wall_force = None
        self._sum_n, self._samples, self._largest_n = 0.0, 0, 0.0

    def start(self, physics, is_wire_geom: np.ndarray, is_vessel_geom: np.ndarray, total_n: float) -> None:
        """A new episode in `physics`, whose start state's wall force is `total_n`."""
        self._wall_force = WallForceTotal(is_wire_geom, is_vessel_geom)
        self.mean_n = self.peak_n = total_n
        if isinstance(physics, ConstraintSensingPhysics):
            physics.after_constraint_solve = self.add

    def begin_step(self) -> None:
        self._sum_n, self._samples, self._largest_n = 0.0, 0, 0.0

    def add(self, physics) -> None:
        """Counts one physics step's total (the `ConstraintSensingPhysics.after_constraint_solve` hook)."""
        total = self._wall_force.total_n(physics.data.ptr)
        self._sum_n += total
        self._samples += 1
        if total > self._largest_n:
            self._largest_n = total

    def end_step(self, end_total_n) -> None:
        """Closes the control step; `end_total_n()`: the total at its end, read only if no physics step was counted."""
        if self._samples:
            self.mean_n, self.peak_n = self._sum_n / self._samples, self._largest_n
        else:
            self.mean_n = self.peak_n = end_total_n()


def total_contact_force_n(physics, is_wire_geom: np.ndarray, is_vessel_geom: np.ndarray) -> float:
    """`wire_contacts(...).total_n` without ``mj_forward`` and without rotating to world.

    The cheap path for once-per-physics-step use: reads ``data.contact`` and
    ``data.efc_force`` as they are, so call it where they belong to the same state
    (`ConstraintSensingPhysics.after_constraint_solve`). A force's magnitude is the same
    in the (orthonormal) contact frame. For the same masks at every physics step,
    `WallForceTotal` gives the same value for less.
    """
    data = physics.data.ptr
    if data.ncon == 0:
        return 0.0
    _, _, keep = _wire_contact_rows(data, is_wire_geom, is_vessel_geom)
    if not keep.any():
        return 0.0
    return float(np.linalg.norm(_local_forces(data, keep), axis=1).sum())


def is_diverged(physics) -> bool:
    """True if the state holds NaN/inf or MuJoCo flagged an unstable step."""
    data = physics.data
    if not (np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))):
        return True
    warnings = data.ptr.warning
    return any(warnings[w].number > 0 for w in _WARNINGS_DIVERGENT)
