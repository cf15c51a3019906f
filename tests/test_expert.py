"""The scripted expert on the hardest shipped case (the BCA of the type III arch) and, in
the slow suite, on every shipped aorta and both targets."""

import numpy as np
import pytest

import cathsim_dmc  # noqa: F401  (selects the GL backend)
from cathsim_dmc.control.expert import CenterlineExpert
from cathsim_dmc.core.shipped import available_aortas
from cathsim_dmc.suite.gym import CathSimEnv


@pytest.fixture(scope="module")
def bca_type3():
    return CathSimEnv(task="bca", aorta="type3", obs="internal")


# Seeds whose tip reached the target's depth and then rode the BCA wall, ending 5.5 and
# 5.4 mm from the target at step 300, with the earlier end game (a rotation sweep at
# fixed depths).
@pytest.mark.parametrize("seed", [1, 3])
def test_expert_reaches_the_type3_bca(bca_type3, seed):
    env, expert = bca_type3, CenterlineExpert()
    observation, info = env.reset(seed=seed)
    distances = []
    for _ in range(env.task.max_steps):
        observation, reward, terminated, truncated, info = env.step(expert(observation, env))
        distances.append(info["target_distance_m"])
        if terminated or truncated:
            break
    assert terminated and info["success"], f"ended {1000 * info['target_distance_m']:.1f} mm from the target"
    assert reward == pytest.approx(10.0)
    # It got there by navigating: the tip started far from the target.
    assert distances[0] > 0.05


def test_expert_actions_stay_in_the_action_space(bca_type3):
    env, expert = bca_type3, CenterlineExpert()
    observation, _ = env.reset(seed=5)
    actions = []
    for _ in range(120):
        action = expert(observation, env)
        actions.append(action)
        observation, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            break
    actions = np.array(actions)
    assert actions.dtype == np.float32 and np.all(np.abs(actions) <= 1.0)
    # Both retraction and insertion are used: it backs off as well as advancing.
    assert actions[:, 0].min() < 0 < actions[:, 0].max()


def test_the_steady_expert_turns_only_in_the_arch_and_its_first_turn_follows_the_start_smoothly():
    # The default expert's first turn flips sign between nearby starts (pi+0.05: +1, pi+0.1:
    # -1); the steady one holds its rotation up the descending aorta and then turns in
    # proportion to the start's offset, reaching the target from each start.
    from cathsim_dmc.control.policies import make_policy

    first_turns = []
    for offset in (-0.2, 0.0, 0.2):
        env = CathSimEnv(
            task="lcca",
            aorta="type1",
            obs="internal",
            start_rotation_rad=np.pi + offset,
            start_rotation_jitter_rad=0.0,
            start_insertion_jitter_m=0.0,
        )
        expert = make_policy("expert_steady")
        observation, info = env.reset(seed=0)
        actions = []
        for _ in range(env.task.max_steps):
            actions.append(expert(observation, env))
            observation, _, terminated, truncated, info = env.step(actions[-1])
            if terminated or truncated:
                break
        assert info["success"], f"start pi{offset:+}: ended {1000 * info['target_distance_m']:.1f} mm away"
        rotations = np.array(actions)[:, 1]
        turning = np.flatnonzero(rotations)
        assert turning[0] >= 20  # none while the tip climbs the descending aorta
        first_turns.append(rotations[turning[0]])
    assert first_turns[0] > first_turns[1] > first_turns[2]


def test_aim_error_of_a_bend_towards_and_away_from_a_turning_line():
    # The expert turns the tip's bend by this error before it inserts.
    from cathsim_dmc.anatomy.paths import CenterlinePath

    # Up the z axis for 50 mm, then off along +x: a bend; the tip base sits at z = 40 mm.
    line = CenterlinePath([[0, 0, 0], [0, 0, 0.05], [0.05, 0, 0.05]], 0.005)
    base, shaft = np.array([0, 0, 0.04]), np.array([0, 0, 1.0])
    towards, off_axis = line.aim_error(base + [0.002, 0, 0.005], base, shaft, 0.04, 0.02)
    away, _ = line.aim_error(base + [-0.002, 0, 0.005], base, shaft, 0.04, 0.02)
    quarter, _ = line.aim_error(base + [0, 0.002, 0.005], base, shaft, 0.04, 0.02)
    assert towards == pytest.approx(0.0, abs=1e-9) and abs(away) == pytest.approx(np.pi)
    assert abs(quarter) == pytest.approx(np.pi / 2)
    assert off_axis == pytest.approx(10 / np.hypot(10, 10))  # aim 10 mm up and 10 mm across
    # Low on the straight stretch the look-ahead lies straight ahead: nothing to aim.
    assert line.aim_error(base - [0, 0, 0.03] + [0.002, 0, 0.005], base - [0, 0, 0.03], shaft, 0.01, 0.01)[1] < 1e-9


@pytest.fixture(scope="module")
def environments():
    built = {}
    yield lambda target, aorta: built.setdefault((target, aorta), CathSimEnv(task=target, aorta=aorta, obs="internal"))
    for env in built.values():
        env.close()


# docs/results.md: 239 of 240 such episodes (seeds 0-19) reached the target; the miss was
# the type II BCA, seed 9. Seeds 0-2 of every case: 36 episodes (80 s beside two training runs).
@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("target", ["bca", "lcca"])
@pytest.mark.parametrize("aorta", available_aortas())
def test_expert_reaches_every_target_of_every_aorta(environments, aorta, target, seed):
    env, expert = environments(target, aorta), CenterlineExpert()
    observation, info = env.reset(seed=seed)
    start_m = info["target_distance_m"]
    for _ in range(env.task.max_steps):
        observation, reward, terminated, truncated, info = env.step(expert(observation, env))
        if terminated or truncated:
            break
    assert terminated and info["success"], (
        f"step {info['step']}: {1000 * info['target_distance_m']:.1f} mm "
        f"from the target, diverged={info['diverged']}, escaped={info['escaped']}"
    )
    assert info["target_distance_m"] <= 0.004 and reward == pytest.approx(10.0)
    assert start_m > 0.1  # from the descending aorta, not a start near the target
