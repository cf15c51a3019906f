"""The `roadmap` observation: the registered roadmap around the tracked tip, in the tip's frame."""

import numpy as np
import pytest

from cathsim_dmc.anatomy.paths import CenterlinePath, deepest_on_polyline
from cathsim_dmc.suite.gym import CathSimEnv
from cathsim_dmc.tasks.roadmap import AHEAD_MM, CM, ROADMAP_SIZE

# Offsets into the roadmap vector (tasks/roadmap.py's order).
TARGET = slice(3 * len(AHEAD_MM), 3 * len(AHEAD_MM) + 3)
BEND = slice(TARGET.stop, TARGET.stop + 3)
RADII = slice(BEND.stop, BEND.stop + 2)
REMAINING, OUTSIDE = BEND.stop + 2, BEND.stop + 3


def _line(env):
    task = env.task
    return CenterlinePath(*task.aorta.asset.centerlines[task.target_name])


def _drive(env, steps, action=(1.0, 0.3)):
    obs = None
    for _ in range(steps):
        obs, *_ = env.step(np.array(action, dtype=np.float32))
    return obs


@pytest.fixture(scope="module")
def env():
    env = CathSimEnv(task="bca", aorta="type1", obs="roadmap")
    yield env
    env.close()


def test_the_preset_holds_the_roadmap_and_the_robot_state_and_no_privileged_state(env):
    obs, info = env.reset(seed=0)
    assert set(obs) == {"roadmap", "robot_state"}
    assert obs["roadmap"].shape == (ROADMAP_SIZE,) and obs["robot_state"].shape == (5,)
    assert np.isfinite(obs["roadmap"]).all()


def test_distances_in_the_tip_frame_match_the_world(env):
    """A rotation keeps lengths: the target and the nearest roadmap point are as far from
    the tip as in world coordinates, and the remaining length is the line's."""
    env.reset(seed=1)
    obs = _drive(env, 25)
    task, physics = env.task, env.physics
    tip = task.tip_position_m(physics)
    road = obs["roadmap"].astype(float)
    assert np.linalg.norm(road[TARGET]) * CM == pytest.approx(task.target_distance_m(physics), rel=1e-4)
    line = _line(env)
    s, outside = line.locate(tip)
    assert np.linalg.norm(road[0:3]) * CM == pytest.approx(np.linalg.norm(line.at(s) - tip), rel=1e-3, abs=1e-6)
    assert road[REMAINING] * 10 * CM == pytest.approx(line.length_m - s, abs=1e-4)
    assert road[OUTSIDE] * CM == pytest.approx(outside, abs=1e-5)
    assert road[RADII][1] * CM == pytest.approx(line.radius_at(line.length_m))


def test_the_frame_points_z_along_the_shaft_and_x_towards_the_bend(env):
    env.reset(seed=2)
    obs = _drive(env, 10)
    bend = obs["roadmap"][BEND].astype(float)
    assert bend[0] > 0.1 and abs(bend[1]) < 1e-5  # the bend lies along +x, none across
    # The first path points lie ahead of the tip in the direction of insertion: up the shaft.
    points = obs["roadmap"][: 3 * len(AHEAD_MM)].reshape(-1, 3)
    assert points[-1, 2] > points[0, 2]


def test_the_tip_advancing_leaves_less_roadmap(env):
    obs, _ = env.reset(seed=3)
    before = obs["roadmap"][REMAINING]
    after = _drive(env, 20, action=(1.0, 0.0))["roadmap"][REMAINING]
    assert after < before - 0.3  # at least 3 cm of progress at full insertion for 2 s


def test_noise_is_seeded_and_the_registration_offset_holds_for_an_episode():
    env = CathSimEnv(task="bca", aorta="type1", obs="roadmap", tracking_noise_m=0.0, registration_error_m=0.002)
    clean = CathSimEnv(task="bca", aorta="type1", obs="roadmap")
    try:
        first, _ = env.reset(seed=4)
        again, _ = env.reset(seed=4)
        other, _ = env.reset(seed=5)
        exact, _ = clean.reset(seed=4)
        assert np.array_equal(first["roadmap"], again["roadmap"])
        assert not np.array_equal(first["roadmap"], other["roadmap"])
        assert not np.allclose(first["roadmap"], exact["roadmap"])
        # One offset for the whole episode: the target as seen from the tip stays off by the
        # same world vector from step to step (the tip frame turns; lengths do not change).
        env.reset(seed=4)
        clean.reset(seed=4)
        gaps = []
        for _ in range(5):
            noisy_obs, *_ = env.step(np.array([1.0, 0.0], np.float32))
            clean_obs, *_ = clean.step(np.array([1.0, 0.0], np.float32))
            gaps.append(np.linalg.norm(noisy_obs["roadmap"][TARGET] - clean_obs["roadmap"][TARGET]))
        assert np.ptp(gaps) < 1e-3 and gaps[0] > 0.01
    finally:
        env.close()
        clean.close()


def test_tracking_noise_changes_every_step():
    env = CathSimEnv(task="bca", aorta="type1", obs="roadmap", tracking_noise_m=0.001)
    try:
        obs, _ = env.reset(seed=0)
        physics, task = env.physics, env.task
        errors = []
        for _ in range(4):
            obs, *_ = env.step(np.array([0.0, 0.0], np.float32))
            exact = task.target_distance_m(physics)
            errors.append(np.linalg.norm(obs["roadmap"][TARGET]) * CM - exact)
        assert len(set(np.round(errors, 9))) == 4 and max(map(abs, errors)) < 0.01
    finally:
        env.close()


def test_a_negative_noise_is_refused_in_one_line():
    with pytest.raises(ValueError, match="tracking_noise_m=-0.001 must be a finite number >= 0"):
        CathSimEnv(task="bca", aorta="type1", obs="roadmap", tracking_noise_m=-0.001)


def _expert_beside_the_roadmap_preset(env, plain, seed=0):
    """An expert episode in `env`, and `plain` (obs=roadmap, the same task) driven by the
    same actions beside it: yields (observation, expert) after the expert's action at each
    step, once the two roadmaps are checked equal."""
    from cathsim_dmc.control.expert import CenterlineExpert

    expert = CenterlineExpert()
    obs, _ = env.reset(seed=seed)
    plain_obs, _ = plain.reset(seed=seed)
    for _ in range(300):
        np.testing.assert_array_equal(obs["roadmap"], plain_obs["roadmap"])
        action = expert(obs, env)
        yield obs, expert
        obs, _, terminated, truncated, _ = env.step(action)
        plain_obs, *_ = plain.step(action)
        if terminated or truncated:
            return


def test_the_depth_clock_counts_the_steps_the_expert_times_its_end_game_by():
    """obs=roadmap_timed: target_depth_time is the expert's own count of steps at the
    target's depth (until the expert's first retreat, where it starts its count afresh),
    and the roadmap beside it is the roadmap preset's."""
    from cathsim_dmc.tasks.roadmap import DEPTH_CLOCK_STEPS

    env = CathSimEnv(task="bca", aorta="type3", obs="roadmap_timed")
    plain = CathSimEnv(task="bca", aorta="type3", obs="roadmap")
    clocks = []
    for obs, expert in _expert_beside_the_roadmap_preset(env, plain):
        assert set(obs) == {"roadmap", "robot_state", "target_depth_time"}
        if expert._retreat_to is not None:
            break
        clocks.append((round(float(obs["target_depth_time"][0]) * DEPTH_CLOCK_STEPS), expert._at_depth))
        # The count is the task's; reading the observable again neither moves nor changes it.
        again = env.task.observables["target_depth_time"](env.physics)
        assert clocks[-1][0] == env.task.steps_at_target_depth and np.float32(again[0]) == obs["target_depth_time"][0]
    assert [clock for clock, _ in clocks] == [count for _, count in clocks]
    assert max(clock for clock, _ in clocks) > expert.settle_steps  # the end game was played
    env.close()
    plain.close()


def test_the_wrong_branch_heading_is_the_one_the_expert_turns_away_from():
    """obs=roadmap_memory: at every step of an LCCA episode in which the wire enters the LSA
    and comes back past its ostium, wrong_branch_heading is flagged exactly when the expert
    turns its aim away from a branch it remembers, and holds that branch's heading in the
    tip's frame; the roadmap beside it is the roadmap preset's."""
    env = CathSimEnv(task="lcca", aorta="type2", obs="roadmap_memory")
    plain = CathSimEnv(task="lcca", aorta="type2", obs="roadmap")
    flagged = []
    for obs, expert in _expert_beside_the_roadmap_preset(env, plain):
        assert set(obs) == {"roadmap", "robot_state", "wrong_branch_heading"}
        away = expert._avoid.heading_near(expert._s, expert._line.radius_at(expert._s))
        memory = obs["wrong_branch_heading"].astype(float)
        flagged.append(memory[0] == 1.0)
        if away is None:
            np.testing.assert_array_equal(memory, np.zeros(4))
        else:
            base_site = env.physics.bind(env.task.guidewire.tip_base_site)
            shaft = base_site.xmat.reshape(3, 3)[:, 2]
            bend = env.task.tip_position_m(env.physics) - base_site.xpos
            x = bend - (bend @ shaft) * shaft
            x /= np.linalg.norm(x)
            frame = np.stack([x, np.cross(shaft, x), shaft])
            np.testing.assert_allclose(memory, np.concatenate([[1.0], frame @ away]), atol=1e-6)
    assert any(flagged) and not flagged[0]  # remembered only after the wire has been in a branch
    env.close()
    plain.close()


def test_a_step_has_one_roadmap_measurement_however_often_it_is_read():
    """The task measures the roadmap at the end of each step (its noise drawn then); the
    observable reads that measurement, so a second read returns the step's observation."""
    env = CathSimEnv(task="bca", aorta="type1", obs="roadmap", tracking_noise_m=0.001)
    try:
        obs, _ = env.reset(seed=0)
        roadmap = env.task.observables["roadmap"]
        for _ in range(3):
            state = env.dm_env.random_state.get_state()[1].copy()
            for _ in range(2):
                np.testing.assert_array_equal(np.float32(roadmap(env.physics)), obs["roadmap"])
            assert np.array_equal(env.dm_env.random_state.get_state()[1], state)  # no noise drawn by a read
            obs, *_ = env.step(np.array([1.0, 0.0], np.float32))
    finally:
        env.close()


def test_a_tracking_window_inside_one_long_segment_still_locates_the_tip():
    """The tip tracked from step to step: a window within one long straight segment, with the
    tip's nearest point on it behind the window (pulled back faster than the window's
    back margin), gives the window's near end and a finite depth, in 3-D and in the image."""
    line = CenterlinePath([[0.0, 0.0, 0.0], [0.0, 0.0, 0.10], [0.0, 0.01, 0.11]], 0.01)
    tip = np.array([0.002, 0.0, 0.02])
    s, outside = line.locate(tip, 0.05, 0.07)
    assert s == pytest.approx(0.05) and np.isfinite(outside)
    assert outside == pytest.approx(np.linalg.norm(line.at(0.05) - tip) - 0.01)
    # Unwindowed, the same point is found where it lies.
    assert line.locate(tip)[0] == pytest.approx(0.02)
    road_2d = line.points[:, 1:]  # the line seen along x
    s_2d, outside_2d = deepest_on_polyline(road_2d, line.arclength, line.radius, tip[1:], 0.05, 0.07)
    assert s_2d == pytest.approx(0.05) and np.isfinite(outside_2d)


def test_a_window_that_holds_no_part_of_the_line_is_refused():
    line = CenterlinePath([[0.0, 0.0, 0.0], [0.0, 0.0, 0.10]], 0.01)
    with pytest.raises(ValueError, match="holds no part of the line"):
        line.locate([0.0, 0.0, 0.05], 0.5, 0.6)
