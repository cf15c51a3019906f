"""The paper's metrics on hand-made trajectories with known answers."""

import numpy as np
import pytest

from cathsim_dmc.evaluation import metrics


def test_straight_episode_known_values():
    # Tip moves 1 cm per step along +y for 4 steps; forces 0, 1, 3, 4 N; reached the target.
    start = np.zeros(3)
    tips = np.array([[0, 0.01 * k, 0] for k in range(1, 5)])
    forces = np.array([0.0, 1.0, 3.0, 4.0])
    m = metrics.episode_metrics(start, tips, forces, success=True, optimal_path_m=0.03)
    assert m.force_n == pytest.approx(2.0)
    assert m.path_length_cm == pytest.approx(4.0)
    assert m.episode_length == 4
    assert m.safety_pct == pytest.approx(50.0)  # 0 and 1 N are below 2 N; 3 and 4 are not
    assert m.success_pct == 100.0
    assert m.spl_pct == pytest.approx(75.0)  # 3 cm optimal over 4 cm travelled


def test_failure_has_zero_spl_and_back_and_forth_counts_both_ways():
    tips = np.array([[0, 0.01, 0], [0, 0.0, 0], [0, 0.01, 0]])
    m = metrics.episode_metrics(np.zeros(3), tips, np.ones(3), success=False, optimal_path_m=0.01)
    assert m.path_length_cm == pytest.approx(3.0)
    assert m.spl_pct == 0.0 and m.success_pct == 0.0
    assert m.safety_pct == 100.0


def test_shorter_than_optimal_path_caps_spl_at_100():
    m = metrics.episode_metrics(np.zeros(3), [[0, 0.005, 0]], [0.0], success=True, optimal_path_m=0.02)
    assert m.spl_pct == pytest.approx(100.0)


def test_remaining_centerline_length():
    # An L-shaped centerline: 3 cm up, then 4 cm along x.
    line = np.array([[0, 0, 0], [0, 0.03, 0], [0.04, 0.03, 0]])
    assert metrics.remaining_centerline_length_m(line, [0.001, 0.01, 0]) == pytest.approx(0.06)
    assert metrics.remaining_centerline_length_m(line, [0.02, 0.031, 0]) == pytest.approx(0.02)
    assert metrics.remaining_centerline_length_m(line, [0.05, 0.03, 0]) == pytest.approx(0.0)


def test_summarize_and_table():
    a = metrics.episode_metrics(np.zeros(3), [[0, 0.01, 0]], [1.0], True, 0.01)
    b = metrics.episode_metrics(np.zeros(3), [[0, 0.03, 0]], [3.0], False, 0.01)
    summary = metrics.summarize([a, b])
    assert summary["force_n"]["mean"] == pytest.approx(2.0) and summary["force_n"]["std"] == pytest.approx(1.0)
    assert summary["success_pct"]["mean"] == pytest.approx(50.0)
    assert summary["path_length_cm"]["mean"] == pytest.approx(2.0)
    table = metrics.markdown_table([({"Target": "BCA", "Policy": "test"}, summary)])
    lines = table.strip().splitlines()
    assert lines[0].startswith("| Target | Policy | Force (N)") and len(lines) == 3
    # The paper's six columns, then safe success (the success at 1 N is safe at 1.5 N).
    assert "| BCA | test | 2.00 ± 1.00 | 2.0 ± 1.0 | 1 ± 0 | 50 ± 50 | 50 ± 50 | 50 ± 50 | 50 ± 50 |" == lines[2]
    assert lines[0].endswith("| SPL (%) | Safe Success (%) |")


def test_trajectory_metrics_splits_episodes():
    arrays = {
        "episode": np.array([0, 0, 1]),
        "tip_position_m": np.array([[0, 0.01, 0], [0, 0.02, 0], [0.01, 0, 0]]),
        "contact_force_n": np.array([0.5, 2.5, 1.0]),
        "success": np.array([False, True, False]),
        "start_tip_position_m": np.zeros((2, 3)),
        "optimal_path_length_m": np.array([0.02, 0.05]),
    }
    first, second = metrics.trajectory_metrics(arrays)
    assert first.episode_length == 2 and first.success_pct == 100 and first.spl_pct == pytest.approx(100.0)
    assert second.episode_length == 1 and second.path_length_cm == pytest.approx(1.0) and second.spl_pct == 0
    # A file without the step mean (written before it existed): the end-of-step force.
    assert first.force_n == pytest.approx(1.5) and first.safety_pct == pytest.approx(50.0)


def test_force_and_safety_use_the_step_mean():
    """The end-of-step force samples one physics step in twenty (zero here, as in most
    steps); Force and Safety read the step's mean."""
    arrays = {
        "episode": np.array([0, 0, 0, 0]),
        "tip_position_m": np.array([[0, 0.01 * k, 0] for k in range(1, 5)]),
        "contact_force_n": np.array([0.0, 0.0, 0.0, 9.0]),
        "mean_contact_force_n": np.array([1.0, 3.0, 2.5, 1.5]),
        "success": np.array([False, False, False, True]),
        "start_tip_position_m": np.zeros((1, 3)),
        "optimal_path_length_m": np.array([0.04]),
    }
    (episode,) = metrics.trajectory_metrics(arrays)
    assert episode.force_n == pytest.approx(2.0)
    assert episode.safety_pct == pytest.approx(50.0)  # 1 and 1.5 N are below 2 N


def test_trajectory_dataset_round_trip(tmp_path):
    """Recorder -> npz -> dataset: images scaled to [0, 1], held-out split by whole episodes."""
    from cathsim_dmc.evaluation.trajectory import TrajectoryRecorder
    from cathsim_dmc.learning.datasets import TrajectoryDataset, split_by_episode

    recorder = TrajectoryRecorder("bca", "type1", np.zeros(3), policy="test", record_observations=True)
    for episode in range(4):
        recorder.start_episode(np.zeros(3), 0.1)
        for step in range(1, 4):
            info = {
                "step": step,
                "tip_position_m": np.zeros(3),
                "contact_force_n": float(step),
                "target_distance_m": 0.1,
                "success": False,
            }
            image = np.full((1, 8, 8), 51 * episode, dtype=np.uint8)
            recorder.record(np.array([0.5, -0.5]), -0.1, info, False, step == 3, {"pixels": image})
    path = recorder.save(tmp_path / "trajectories.npz")
    data = TrajectoryDataset(path, inputs=("obs_pixels",), targets=("action", "contact_force_n"))
    assert len(data) == 12
    image, action, force = data[4]  # episode 1, step 2
    assert image.shape == (1, 8, 8) and float(image.max()) == pytest.approx(51 / 255)
    assert action.tolist() == [0.5, -0.5] and force.item() == 2.0
    train, test = split_by_episode(data.episode, 0.25, seed=0)
    assert len(test) == 3 and len(set(data.episode[test])) == 1
    assert not set(data.episode[test]) & set(data.episode[train])
    with pytest.raises(ValueError, match="save_observations"):
        TrajectoryDataset(path, inputs=("obs_guidewire_mask",))


def test_safe_success_needs_every_step_at_or_under_the_threshold():
    tips = [[0, 0.01, 0], [0, 0.02, 0], [0, 0.03, 0]]
    gentle = metrics.episode_metrics(np.zeros(3), tips, [0.4, 1.5, 0.9], success=True, optimal_path_m=0.03)
    rough = metrics.episode_metrics(np.zeros(3), tips, [0.4, 1.6, 0.9], success=True, optimal_path_m=0.03)
    missed = metrics.episode_metrics(np.zeros(3), tips, [0.1, 0.1, 0.1], success=False, optimal_path_m=0.03)
    assert metrics.SAFE_SUCCESS_FORCE_N == 1.5
    assert gentle.safe_success_pct == 100.0 and rough.safe_success_pct == 0.0 and missed.safe_success_pct == 0.0
    # The paper's metrics do not change with it: one step of 1.6 N is still "safe" at the paper's 2 N.
    assert rough.success_pct == 100.0 and rough.safety_pct == 100.0 and rough.force_n == pytest.approx(2.9 / 3)
    lenient = metrics.episode_metrics(np.zeros(3), tips, [0.4, 1.6, 0.9], True, 0.03, safe_force_n=2.0)
    assert lenient.safe_success_pct == 100.0


def test_safe_success_reads_the_threshold_the_trajectory_file_records():
    arrays = {
        "episode": np.array([0, 0, 1]),
        "tip_position_m": np.array([[0, 0.01, 0], [0, 0.02, 0], [0.01, 0, 0]]),
        "contact_force_n": np.zeros(3),
        "mean_contact_force_n": np.array([0.5, 1.8, 0.2]),
        "success": np.array([False, True, True]),
        "start_tip_position_m": np.zeros((2, 3)),
        "optimal_path_length_m": np.array([0.02, 0.01]),
    }
    first, second = metrics.trajectory_metrics(arrays)
    assert (first.safe_success_pct, second.safe_success_pct) == (0.0, 100.0)  # 1.8 N > the default 1.5 N
    first, _ = metrics.trajectory_metrics({**arrays, "safe_force_n": np.float32(2.0)})
    assert first.safe_success_pct == 100.0


def test_reports_written_before_safe_success_still_summarize():
    old = {k: 1.0 for k in metrics.METRIC_COLUMNS}  # a per-episode row of an older metrics.json
    episode = metrics.EpisodeMetrics(**old)
    summary = metrics.summarize([episode, episode])
    assert set(summary) == set(metrics.METRIC_COLUMNS)
    row = metrics.markdown_table([({"Policy": "old"}, summary)]).strip().splitlines()[2]
    assert row.endswith("| 1 ± 0 | - |")
