"""Training rewards and robot signals: the geodesic distance, progress shaping and the
slack signal."""

import numpy as np
import pytest

from cathsim_dmc import tasks
from cathsim_dmc.anatomy import load_asset
from cathsim_dmc.anatomy.paths import CenterlineTree
from cathsim_dmc.core.shipped import resolve_asset


@pytest.fixture(scope="module")
def tree():
    return CenterlineTree.from_asset(load_asset(resolve_asset("type1")))


def _branch_end(tree, name):
    return tree.lines[name].points[-2]  # the site (the last point is the overshoot extension)


@pytest.mark.parametrize("target, wrong", [("bca", "lcca"), ("bca", "lsa"), ("lcca", "bca"), ("lcca", "lsa")])
def test_a_tip_deep_in_a_wrong_branch_is_farther_than_the_right_ostium(tree, target, wrong):
    line = tree.lines[target]
    ostium = line.at(tree.junction_arclength_m(target, wrong) + 0.01)  # 1 cm into the target's own way
    deep_wrong = _branch_end(tree, wrong)
    # The straight line ranks the wrong branch as closer (the trap of the paper's reward) ...
    target_point = _branch_end(tree, target)
    assert np.linalg.norm(deep_wrong - target_point) < np.linalg.norm(ostium - target_point) + 0.05
    # ... along the vessel it is the way back to the junction and on: clearly farther.
    assert tree.geodesic_distance_m(deep_wrong, target) > tree.geodesic_distance_m(ostium, target) + 0.02


@pytest.mark.parametrize("target", ["bca", "lcca"])
def test_geodesic_distance_falls_monotonically_along_the_path_to_the_target(tree, target):
    line = tree.lines[target]
    distances = [tree.geodesic_distance_m(p, target) for p in line.points[:-1]]
    assert np.all(np.diff(distances) < 0)
    assert distances[0] == pytest.approx(line.length_m, abs=1e-6)
    assert distances[-1] == pytest.approx(0.0, abs=1e-6)


def test_a_point_past_the_target_counts_its_overshoot(tree):
    line = tree.lines["bca"]
    past = line.at(line.length_m + 0.01)
    assert tree.geodesic_distance_m(past, "bca") == pytest.approx(0.01, abs=1e-4)


def test_a_point_outside_every_centerline_tube_adds_its_depth(tree):
    line = tree.lines["bca"]
    s = 0.5 * line.length_m  # descending aorta
    centre = line.at(s)
    radius = line.radius_at(s)
    outside = centre + np.array([0.0, 0.0, radius + 0.02])  # 2 cm beyond the wall, in z
    # Within a few mm: the vessel bends and tapers, so the deepest point shifts a little.
    assert tree.geodesic_distance_m(outside, "bca") == pytest.approx(line.length_m - s + 0.02, abs=4e-3)
    assert tree.geodesic_distance_m(outside, "bca") > tree.geodesic_distance_m(centre, "bca") + 0.015


def _run(env, actions):
    rewards, infos = [], []
    for action in actions:
        timestep = env.step(action)
        rewards.append(timestep.reward)
        infos.append(env.task.step_info(env.physics))
    return np.array(rewards), infos


def test_progress_reward_pays_for_insertion_and_charges_for_retraction(tree):
    env = tasks.load("bca", "type1", seed=0, reward="geodesic", progress_weight=1.0)
    env.reset()
    forward, infos = _run(env, [[1.0, 0.0]] * 10)
    # Straight up the descending aorta: each full-speed step gains close to its 4 mm
    # (the first from rest a little less), measured from the start pose.
    assert np.all(forward > 0.3) and np.all(forward[3:] > 0.5)
    backward, _ = _run(env, [[-1.0, 0.0]] * 5)
    assert np.all(backward[2:] < 0)
    # The distance term alone: minus the larger of the distance along the vessel (on this
    # test's own centerline tree of the asset) and the straight line, to the asset's site.
    plain = tasks.load("bca", "type1", seed=0, reward="geodesic")
    plain.reset()
    rewards, _ = _run(plain, [[1.0, 0.0]] * 3)
    tip = plain.physics.bind(plain.task.guidewire.tip_site).xpos
    along, straight = tree.geodesic_distance_m(tip, "bca"), np.linalg.norm(tip - _site("bca"))
    assert rewards[-1] == pytest.approx(-max(along, straight))


def _site(name):
    return load_asset(resolve_asset("type1")).sites[name]


def test_euclidean_reward_is_the_papers():
    env = tasks.load("bca", "type1", seed=0)
    env.reset()
    rewards, _ = _run(env, [[1.0, 0.3]] * 3)
    tip = env.physics.bind(env.task.guidewire.tip_site).xpos
    assert rewards[-1] == pytest.approx(-np.linalg.norm(tip - _site("bca")))
    assert rewards[-1] < -0.1  # the tip is still in the descending aorta


def test_bad_reward_options_name_the_choices():
    with pytest.raises(ValueError, match="euclidean"):
        tasks.load("bca", "type1", reward="manhattan")
    with pytest.raises(ValueError, match="progress_weight"):
        tasks.load("bca", "type1", progress_weight=-1)
    with pytest.raises(ValueError, match="wire_slack"):
        tasks.load("bca", "type1", extra_observations=("nope",))


def test_slack_grows_when_the_tip_stalls_and_the_drive_pushes():
    env = tasks.load("bca", "type1", seed=0, extra_observations=("wire_slack", "drive_force"))
    timestep = env.reset()
    assert {"wire_slack", "drive_force"} <= set(timestep.observation)
    assert abs(timestep.observation["wire_slack"][0]) < 1e-3  # measured from the start pose
    _, infos = _run(env, [[1.0, 0.0]] * 15)
    # Free in the descending aorta: the tip follows the carriage.
    assert abs(infos[-1].slack_m) < 0.01
    _, infos = _run(env, [[1.0, 0.0]] * 85)
    # Full stroke without steering: the tip is stopped in the arch and the shaft takes up the rest.
    assert infos[-1].insertion_m > 0.25
    assert infos[-1].slack_m > 0.05
    timestep = env.step([1.0, 0.0])
    assert timestep.observation["wire_slack"][0] == pytest.approx(env.task.slack_m(env.physics))


def test_every_reward_term_is_found_by_name_and_an_unknown_one_names_the_choices():
    from cathsim_dmc.tasks import rewards

    assert set(rewards.DISTANCES) | set(rewards.SHAPING) == {"euclidean", "geodesic", "progress"}
    for name in rewards.DISTANCES + rewards.SHAPING:
        assert callable(rewards.get_reward(name))
    with pytest.raises(ValueError, match="geodesic"):
        rewards.get_reward("manhattan")


def test_the_distances_ask_for_the_way_along_the_vessel_only_when_they_use_it():
    from cathsim_dmc.tasks import rewards

    tip, target = np.array([0.0, 0.0, 0.0]), np.array([0.03, 0.04, 0.0])  # 50 mm apart

    def not_needed():
        raise AssertionError("the straight line needs no centerline")

    assert rewards.get_reward("euclidean")(tip, target, not_needed) == pytest.approx(0.05)
    # Along the vessel, or the straight line where that is longer (near the target, off its axis).
    assert rewards.get_reward("geodesic")(tip, target, lambda: 0.08) == pytest.approx(0.08)
    assert rewards.get_reward("geodesic")(tip, target, lambda: 0.01) == pytest.approx(0.05)


def test_a_reward_is_its_terms_added_up():
    from cathsim_dmc.tasks.rewards import NavigationReward

    step_m = 0.004
    shaped = NavigationReward(kind="geodesic", progress_weight=1.0)
    # 4 mm of progress (one full step: +1) at 30 mm from the target.
    assert shaped.step_reward(0.034, 0.030, False, step_m) == pytest.approx(-0.030 + 1.0)
    assert shaped.step_reward(0.034, 0.003, True, step_m) == 10.0  # success: the success reward alone
    sparse = NavigationReward(dense=False, progress_weight=0.5)
    assert sparse.step_reward(0.030, 0.034, False, step_m) == pytest.approx(-0.5)  # 4 mm away: -weight
    with pytest.raises(ValueError, match="euclidean"):
        NavigationReward(kind="manhattan")
