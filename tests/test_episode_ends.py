"""Where episodes end: tip paths walked along type I's real centerlines."""

import numpy as np
import pytest

from cathsim_dmc.anatomy.asset import load_asset
from cathsim_dmc.anatomy.paths import CenterlineTree
from cathsim_dmc.core.shipped import resolve_asset
from cathsim_dmc.evaluation.episode_ends import (
    BESIDE_TARGET,
    OFF_CENTERLINES,
    PAST_TARGET,
    REACHED,
    SHORT_OF_TARGET,
    episode_ends,
    failures_table,
)


@pytest.fixture(scope="module")
def tree():
    return CenterlineTree.from_asset(load_asset(resolve_asset("type1")))


def _walk(line, start_m, stop_m, step_m=0.002, offset_m=None):
    """Tip positions along `line` from arc length start_m to stop_m (up to 30 mm past its end,
    the line's straight extension), shifted by offset_m."""
    points = np.array([line.at(s) for s in np.arange(start_m, stop_m, step_m)] + [line.at(stop_m)])
    return points + (0 if offset_m is None else np.asarray(offset_m))


def _arrays(tree, target, paths, successes=None):
    """A trajectory file's arrays for tip paths (one per episode)."""
    target_m = tree.lines[target].at(tree.lines[target].length_m)
    episode = np.concatenate([np.full(len(p), e) for e, p in enumerate(paths)])
    tips = np.vstack(paths)
    distance = np.linalg.norm(tips - target_m, axis=1)
    success = (
        distance <= 0.004
        if successes is None
        else np.concatenate([np.full(len(p), s) for p, s in zip(paths, successes)])
    )
    return {
        "task": np.str_(target),
        "aorta": np.str_("type1"),
        "episode": episode,
        "step": np.concatenate([np.arange(1, len(p) + 1) for p in paths]),
        "tip_position_m": tips,
        "target_distance_m": distance,
        "success": success,
        "contact_force_n": np.linspace(0, 1, len(tips)),
        "start_tip_position_m": np.array([p[0] for p in paths]),
    }


def _across(line, s_m, distance_m):
    """A vector of `distance_m` across `line` at arc length s_m."""
    along = line.at(s_m + 0.001) - line.at(s_m - 0.001)
    across = np.cross(along, [0.0, 0.0, 1.0])
    return distance_m * across / np.linalg.norm(across)


def test_each_way_of_failing_is_told_apart(tree):
    bca, lsa = tree.lines["bca"], tree.lines["lsa"]
    end = bca.length_m
    paths = [
        _walk(lsa, 0.0, lsa.length_m),  # turns into the LSA and is pushed to its end
        _walk(bca, 0.0, end + 0.012),  # overshoots the BCA's target by 12 mm
        _walk(bca, 0.0, end, offset_m=_across(bca, end, 0.005)),  # at the target's depth, 5 mm off its axis
        _walk(bca, 0.0, 0.08),  # stalls in the descending aorta
        _walk(bca, 0.0, end),  # reaches the target
    ]
    # (the overshoot passes through the target: here its success is decided as if beside it)
    ends = episode_ends(_arrays(tree, "bca", paths, [False] * 4 + [True]), lambda aorta: tree)
    assert [e.ended for e in ends] == ["in the LSA", PAST_TARGET, BESIDE_TARGET, SHORT_OF_TARGET, REACHED]
    assert [e.success for e in ends] == [False, False, False, False, True]
    into_lsa = ends[0]
    assert into_lsa.other_branches == ("LSA",)
    # It enters where it leaves the BCA line's tube: after the lines part, before the LSA's end.
    step = into_lsa.entered_last_branch_step
    junction_step = tree.junction_arclength_m("lsa", "bca") / 0.002
    assert junction_step < step < lsa.length_m / 0.002
    assert into_lsa.end_along_vessel_mm == pytest.approx(
        1e3
        * ((lsa.length_m - tree.junction_arclength_m("lsa", "bca")) + (end - tree.junction_arclength_m("bca", "lsa"))),
        abs=2,
    )
    assert ends[1].end_along_vessel_mm == pytest.approx(12, abs=0.5)
    assert 4.9 < ends[2].closest_to_target_mm < 5.1 and ends[2].end_along_vessel_mm < 1
    assert ends[3].end_along_vessel_mm == pytest.approx(1e3 * (end - 0.08), abs=0.5)
    # A tip on the BCA's own centerline is never placed in another branch.
    assert all(e.other_branches == () for e in ends[1:])


def test_a_tip_outside_every_centerline_is_off_them(tree):
    bca = tree.lines["bca"]
    s = 0.05  # in the descending aorta, which every line shares
    path = _walk(bca, 0.0, s)
    path[-1] = bca.at(s) + _across(bca, s, bca.radius_at(s) + 0.005)
    (end,) = episode_ends(_arrays(tree, "bca", [path]), lambda aorta: tree)
    assert end.ended == OFF_CENTERLINES


def test_failures_are_grouped_most_common_first(tree):
    bca, lsa = tree.lines["bca"], tree.lines["lsa"]
    paths = [_walk(lsa, 0.0, lsa.length_m - d) for d in (0.0, 0.01)]
    paths += [_walk(bca, 0.0, 0.08), _walk(bca, 0.0, bca.length_m)]
    ends = episode_ends(_arrays(tree, "bca", paths), lambda aorta: tree)
    table = failures_table(ends).splitlines()
    assert table[0] == "Failed episodes: 3 of 4, by where the tip ended."
    rows = [line.split(" | ") for line in table[4:]]
    assert [row[0] for row in rows] == ["| in the LSA", f"| {SHORT_OF_TARGET}"]
    assert rows[0][1] == "2" and rows[1][1] == "1"
    steps = {e.entered_last_branch_step for e in ends[:2]}
    assert rows[0][2] == str(steps.pop())  # both enter the LSA at the same step
    assert failures_table(ends[3:]) == ""  # nothing failed: no table
