"""The catheter over the wire: its stiffness and curve, its carriage, and the expert with it."""

import math

import numpy as np
import pytest

from cathsim_dmc import tasks
from cathsim_dmc.control.expert import CenterlineExpert
from cathsim_dmc.entities import Guidewire
from cathsim_dmc.entities.catheter import Catheter, CatheterOverWire
from cathsim_dmc.entities.guidewire import second_moment_of_area
from cathsim_dmc.evaluation import fidelity
from cathsim_dmc.suite.gym import CathSimEnv


def test_a_covered_cantilever_bends_as_the_wire_and_the_catheter_together():
    catheter = Catheter(curve_deg=0.0)  # a straight catheter over all of a straight wire
    deflection, analytic, at_rest = fidelity.cantilever_deflection(20, catheter=catheter)
    bare, bare_analytic, _ = fidelity.cantilever_deflection(20)
    assert at_rest
    # Beam theory with E I of the two summed, to the wire's own accuracy (within 1%).
    assert deflection == pytest.approx(analytic, rel=0.01)
    wire_ei = 40e9 * second_moment_of_area(0.5e-3)
    assert bare / deflection == pytest.approx(1 + catheter.bending_stiffness_nm2 / wire_ei, rel=0.02)


def _settled_tip_angle_deg(wire, tip_offset_m, catheter, from_segment=0):
    # Without sleep (`accurate`): a sleeping tree stops before its springs settle.
    physics = fidelity.bare_wire_physics(wire, "accurate")
    covering = CatheterOverWire(catheter, wire)
    covering.initialize(physics)
    covering.apply(physics, tip_offset_m)
    for _ in range(1500):
        physics.step()
    segments = physics.bind(wire.segments)
    shaft, tip = segments.xmat[from_segment].reshape(3, 3)[:, 2], segments.xmat[-1].reshape(3, 3)[:, 2]
    rest_y = covering.joint_values(tip_offset_m)[1][1::2]
    return math.degrees(math.acos(np.clip(shaft @ tip, -1.0, 1.0))), rest_y


def test_the_covered_tip_rests_at_the_stiffness_weighted_curve():
    # A straight wire whose 15 mm tip the catheter covers, flush: each tip hinge rests at
    # the catheter's curve over its 1.5 mm piece times the catheter's share of the summed
    # stiffness (coaxial beams at rest), and the chain settles there.
    wire = Guidewire(length_m=0.1, n_segments=10, tip_shape="straight")
    catheter = Catheter(curve_deg=90.0, curve_length_m=wire.tip_length_m)
    tip_ei = 8e9 * second_moment_of_area(wire.core_diameter_m)
    share = catheter.bending_stiffness_nm2 / (catheter.bending_stiffness_nm2 + tip_ei)
    measured, rest_y = _settled_tip_angle_deg(wire, 0.0, catheter)
    piece_deg = 90.0 * (wire.tip_length_m / 10) / wire.tip_length_m
    assert np.degrees(rest_y[-9:]) == pytest.approx(np.full(9, piece_deg * share), rel=1e-9)
    assert measured == pytest.approx(np.degrees(rest_y.sum()), abs=1.0)
    # The hinges carry all but the last half piece of the curve (85.5 of 90 degrees).
    assert measured == pytest.approx(85.5 * share, abs=2.0)
    # Pulled back by the tip's length, the catheter leaves the wire's soft tip straight
    # (its curve now bends the shaft behind it).
    wire = Guidewire(length_m=0.1, n_segments=10, tip_shape="straight")
    first_tip_segment = -10
    assert _settled_tip_angle_deg(wire, wire.tip_length_m, catheter, first_tip_segment)[0] < 2.0


def test_the_catheter_adds_nothing_inside_the_sheath():
    wire = Guidewire()
    covering = CatheterOverWire(Catheter(), wire)
    physics = fidelity.bare_wire_physics(wire)
    covering.initialize(physics)
    k_wire = physics.model.jnt_stiffness[physics.bind(wire.joints).element_id]
    parked_k, parked_rest = covering.joint_values(0.05, sheath_from_m=0.05)  # its tip at the sheath's
    assert np.array_equal(parked_k, k_wire) and np.array_equal(parked_rest, wire.rest_qpos)
    out_k, out_rest = covering.joint_values(0.05)  # the same offset with no sheath behind
    assert (out_k > k_wire).sum() > 10 and np.abs(out_rest - wire.rest_qpos).max() > 0.1


def test_a_parked_catheter_leaves_the_episode_unchanged():
    actions = [np.array([1.0, 0.3])] * 40 + [np.array([-0.5, -1.0])] * 10
    runs = []
    for catheter in (None, "angled_5f"):
        env = tasks.load("bca", "type1", seed=3, catheter=catheter)
        env.reset()
        runs.append(
            [
                env.step(a if catheter is None else np.append(a, 0.0)).observation["joint_pos"][:69].copy()
                for a in actions
            ]
        )
    assert np.array_equal(np.array(runs[0]), np.array(runs[1]))


def test_the_carriage_moves_the_catheter_along_the_wire_within_its_limits():
    env = tasks.load("bca", "type1", seed=0, catheter="angled_5f")
    task = env.task
    assert env.action_spec().shape == (3,)
    env.reset()
    parked = task.catheter_offset_m
    assert parked == pytest.approx(task.robot.initial_insertion_m + task.robot.insertion_m(env.physics))
    for _ in range(5):  # the wire advances, the catheter stays at the sheath
        env.step(np.array([1.0, 0.0, 0.0]))
    assert task.catheter_offset_m == pytest.approx(task.robot.initial_insertion_m + task.robot.insertion_m(env.physics))
    before, wire_before = task.catheter_offset_m, task.robot.insertion_m(env.physics)
    env.step(np.array([0.0, 0.0, 1.0]))  # the catheter at full speed (the wire's servo still settling)
    step_m = task.catheter.max_speed_m_s * task.control_timestep
    wire_moved_m = task.robot.insertion_m(env.physics) - wire_before
    assert before - task.catheter_offset_m == pytest.approx(step_m - wire_moved_m, abs=1e-9)
    for _ in range(30):  # it stops at the wire's tip
        env.step(np.array([0.0, 0.0, 1.0]))
    assert task.catheter_offset_m == 0.0
    for _ in range(30):  # and back at the sheath
        env.step(np.array([0.0, 0.0, -1.0]))
    assert task.catheter_offset_m == pytest.approx(task.robot.initial_insertion_m + task.robot.insertion_m(env.physics))
    with pytest.raises(ValueError, match=r"expected shape \(3,\).*catheter"):
        env.step(np.array([1.0, 0.0]))


def test_an_unknown_catheter_is_refused_with_the_choices():
    with pytest.raises(ValueError, match="catheter='nope' is not a catheter; choose one of \\['angled_5f'\\]"):
        tasks.load("bca", "type1", catheter="nope")


@pytest.fixture(scope="module")
def reverse_angle_lcca():
    """A generated bovine arch whose LCCA leaves the shared trunk at a reverse angle
    (a wire alone stalled in its mouth: docs/results.md)."""
    from cathsim_dmc.tasks.randomized import anatomy_pool

    return str(anatomy_pool(pool_size=2, pool_seed=200, base="bovine", distribution="fixed_branches")[1])


def _expert_episode(aorta, catheter, seed=0):
    env = CathSimEnv("lcca", aorta, "internal", catheter=catheter)
    expert = CenterlineExpert()
    observation, info = env.reset(seed=seed)
    parked_m, offsets = info.get("catheter_offset_m"), []
    done = False
    while not done:
        observation, _, terminated, truncated, info = env.step(expert(observation, env))
        offsets.append(info.get("catheter_offset_m"))
        done = terminated or truncated
    return info, expert, parked_m, offsets


def test_the_expert_brings_the_catheter_up_where_the_wire_alone_stalls(reverse_angle_lcca):
    info, _, _, _ = _expert_episode(reverse_angle_lcca, None)
    assert not info["success"]  # the wire alone does not get up this branch
    info, expert, parked_m, offsets = _expert_episode(reverse_angle_lcca, "angled_5f")
    assert expert.uses_catheter
    assert min(offsets) < 0.01 < parked_m  # the catheter's tip came up to the wire's
    assert not info["escaped"]
    # How often it then reaches the target is a benchmark (docs/benchmarks.md#with-a-catheter).


def test_the_expert_leaves_the_catheter_parked_where_the_wire_alone_will_do():
    env = CathSimEnv("lcca", "type1", "internal", catheter="angled_5f")
    expert = CenterlineExpert()
    observation, info = env.reset(seed=0)
    parked_m = info["catheter_offset_m"]
    action = expert(observation, env)
    assert not expert.uses_catheter
    assert action.shape == (3,) and action[2] == 0.0
    _, _, _, _, info = env.step(action)
    assert info["catheter_offset_m"] > parked_m  # the wire went in, the catheter stayed at the sheath


def test_the_built_in_wire_policies_leave_the_catheter_parked():
    from cathsim_dmc.control.policies import BUILTIN_POLICIES

    env = CathSimEnv("bca", "type1", "internal", catheter="angled_5f")
    observation, _ = env.reset(seed=0)
    for name in ("forward", "adversarial"):
        action = BUILTIN_POLICIES[name]()(observation, env)
        assert action.shape == (3,) and action[2] == 0.0, name
    assert BUILTIN_POLICIES["random"](seed=1)(observation, env).shape == (3,)  # random drives the catheter too
    plain = CathSimEnv("bca", "type1", "internal")
    assert BUILTIN_POLICIES["forward"]()(observation, plain).shape == (2,)


def _catheter_flags(task, aorta, seed, catheter="angled_5f"):
    """(the observed catheter_called, the expert's uses_catheter) at each step of an expert episode."""
    env = CathSimEnv(task, aorta, "roadmap_memory_carriage", catheter=catheter)
    expert = CenterlineExpert()
    observation, _ = env.reset(seed=seed)
    flags = []
    try:
        for _ in range(300):
            action = expert(observation, env)
            flags.append((bool(observation["catheter_called"][0]), getattr(expert, "uses_catheter", False)))
            observation, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                break
    finally:
        env.close()
    return flags


def test_catheter_called_is_raised_when_the_expert_brings_the_catheter_up(reverse_angle_lcca):
    """obs=roadmap_memory_carriage: catheter_called is the expert's own rule on the tracked tip.
    Where the wire stalls short of a reverse-angle LCCA it is raised at the step the expert
    brings the catheter up and stays raised; where the BCA's end game runs out (type III
    oblique), within a few steps of the expert; without a catheter, never."""
    observed, expert = zip(*_catheter_flags("lcca", reverse_angle_lcca, 0))
    assert any(expert) and observed == expert
    observed, expert = zip(*_catheter_flags("bca", "type3_oblique", 1))
    raised, brought_up = observed.index(True), expert.index(True)
    assert all(observed[raised:]) and all(expert[brought_up:])
    assert 0 <= brought_up - raised <= 3
    assert not any(observed for observed, _ in _catheter_flags("lcca", reverse_angle_lcca, 0, catheter=None))


def test_the_image_tracker_keeps_the_same_memories_as_the_3d_tracker(reverse_angle_lcca):
    """obs=tracking_2d_memory_carriage in an LAO 30 view, driven by the expert's actions beside
    roadmap_memory_carriage: the wrong-branch flag agrees at nearly every step, its heading is
    a unit vector in the image pointing cranially (the supra-aortic branches), and the
    catheter's call comes at the same step."""
    env = CathSimEnv("lcca", reverse_angle_lcca, "roadmap_memory_carriage", catheter="angled_5f")
    image = CathSimEnv("lcca", reverse_angle_lcca, "tracking_2d_memory_carriage", catheter="angled_5f", lao_deg=30)
    expert = CenterlineExpert()
    observation, _ = env.reset(seed=0)
    seen, _ = image.reset(seed=0)
    flags, headings, called = [], [], []
    try:
        for _ in range(300):
            action = expert(observation, env)
            flags.append((observation["wrong_branch_heading"][0], seen["wrong_branch_heading_2d"][0]))
            if seen["wrong_branch_heading_2d"][0]:
                headings.append(seen["wrong_branch_heading_2d"][1:])
            called.append((observation["catheter_called"][0], seen["catheter_called_2d"][0]))
            observation, _, terminated, truncated, _ = env.step(action)
            seen, *_ = image.step(action)
            if terminated or truncated:
                break
    finally:
        env.close()
        image.close()
    flags, headings, called = np.array(flags), np.array(headings), np.array(called)
    assert np.mean(flags[:, 0] == flags[:, 1]) >= 0.95 and len(headings) > 20
    np.testing.assert_allclose(np.linalg.norm(headings, axis=1), 1.0, atol=1e-5)
    assert (headings[:, 1] > 0.5).all()
    assert called[:, 0].any() and np.argmax(called[:, 0]) == np.argmax(called[:, 1])


def test_the_carriage_rate_is_what_it_moved_over_its_full_speed():
    """catheter_rate (obs=roadmap_memory_carriage): the commanded speed while the carriage is
    free, zero where the sheath holds it, the share it moved where the wire's tip stops it."""
    env = CathSimEnv("lcca", "type1", "roadmap_memory_carriage", catheter="angled_5f")
    observation, _ = env.reset(seed=0)
    assert observation["catheter_rate"][0] == 0.0
    observation, *_ = env.step(np.array([0.0, 0.0, -1.0], np.float32))  # parked: the sheath holds it
    assert observation["catheter_rate"][0] == 0.0
    for _ in range(5):
        observation, *_ = env.step(np.array([1.0, 0.0, 0.0], np.float32))
    observation, _, _, _, info = env.step(np.array([0.0, 0.0, 0.5], np.float32))
    assert observation["catheter_rate"][0] == pytest.approx(0.5)
    step_m = env.task.catheter.max_speed_m_s * env.task.control_timestep
    rates = []
    while info["catheter_offset_m"] > 0.0 and len(rates) < 30:  # up to the wire's tip, the wire held
        offset_m = info["catheter_offset_m"]
        observation, _, _, _, info = env.step(np.array([0.0, 0.0, 1.0], np.float32))
        rates.append((float(observation["catheter_rate"][0]), min(1.0, offset_m / step_m)))
    assert info["catheter_offset_m"] == 0.0 and rates[-1][1] < 1.0  # the last move was cut short
    np.testing.assert_allclose(*zip(*rates), atol=1e-3)  # the held wire still settles by microns
    env.close()
