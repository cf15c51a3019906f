"""Force validation: Mann-Whitney on synthetic samples, and one-line errors on bad input."""

import json
import subprocess
import sys

import numpy as np
import pytest

from cathsim_dmc.app.cli.forcecheck import CDF_PLOT, RESULT_JSON, RESULT_MD, force_check, simulated_forces
from cathsim_dmc.evaluation.trajectory import TrajectoryRecorder


def _trajectory(path, forces, step_mean=True):
    """A trajectory whose steps' wall forces (step means) are `forces`; the end-of-step
    force is zero, as it is in most simulated steps. `step_mean=False`: an older file
    with the end-of-step force only, set to `forces`."""
    recorder = TrajectoryRecorder("bca", "type1", np.zeros(3), policy="synthetic")
    recorder.start_episode(np.zeros(3), 0.1)
    for step, force in enumerate(forces, 1):
        info = {
            "step": step,
            "tip_position_m": np.zeros(3),
            "contact_force_n": 0.0 if step_mean else force,
            "target_distance_m": 0.1,
            "success": False,
        }
        if step_mean:
            info["mean_contact_force_n"] = force
        recorder.record(np.zeros(2), 0.0, info, False, False)
    return recorder.save(path)


@pytest.fixture
def simulated(tmp_path):
    forces = np.random.default_rng(1).normal(0.5, 0.1, size=400)
    return _trajectory(tmp_path / "trajectories.npz", forces)


def test_same_distribution_is_not_rejected(simulated, tmp_path):
    result = force_check([simulated], tmp_path / "out", mean_n=0.5, std_n=0.1, seed=2)
    assert result["p_value"] > 0.05
    assert {p.name for p in (tmp_path / "out").iterdir()} == {RESULT_JSON, RESULT_MD, CDF_PLOT}
    assert json.loads((tmp_path / "out" / RESULT_JSON).read_text())["u_statistic"] == result["u_statistic"]


def test_files_without_the_step_mean_give_their_end_of_step_force(tmp_path):
    forces = np.random.default_rng(1).normal(0.5, 0.1, size=400)
    older = _trajectory(tmp_path / "older.npz", forces, step_mean=False)
    np.testing.assert_allclose(simulated_forces([older]), forces.astype(np.float32))
    np.testing.assert_allclose(simulated_forces([_trajectory(tmp_path / "new.npz", forces)]), forces.astype(np.float32))


def test_shifted_distribution_is_rejected(simulated, tmp_path):
    assert force_check([simulated], tmp_path / "out", mean_n=0.6, std_n=0.1, seed=2)["p_value"] < 1e-10


def test_csv_reference_by_column_name(simulated, tmp_path):
    measured = np.random.default_rng(3).normal(0.5, 0.1, size=300)
    csv = tmp_path / "measured.csv"
    csv.write_text("time_s,force_n\n" + "".join(f"{i * 0.01},{f}\n" for i, f in enumerate(measured)))
    result = force_check([simulated], tmp_path / "out", reference_csv=csv, column="force_n")
    assert result["reference"]["n"] == 300 and result["p_value"] > 0.05


def _cli(tmp_path, *args):
    return subprocess.run(
        [sys.executable, "-m", "cathsim_dmc.app.cli.forcecheck", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )


def test_cli_takes_hydra_overrides_and_writes_the_report(simulated, tmp_path):
    run = _cli(
        tmp_path,
        f"trajectories=[{simulated},{simulated}]",
        "mean_n=0.5",
        "std_n=0.2",
        "contact_only=true",
        f"out={tmp_path / 'out'}",
    )
    assert run.returncode == 0, run.stderr[-2000:]
    result = json.loads((tmp_path / "out" / RESULT_JSON).read_text())
    assert result["contact_only"] and len(result["trajectories"]) == 2
    assert result["reference_source"].startswith("normal, mean 0.5 N, std 0.2 N")
    assert (tmp_path / "out" / CDF_PLOT).is_file() and "Mann-Whitney" in run.stdout


@pytest.mark.parametrize(
    "case",
    [
        "missing_file",
        "empty_trajectory",
        "empty_csv",
        "no_reference",
        "bad_std",
        "no_trajectories",
        "mean_not_a_number",
        "unknown_column",
    ],
)
def test_bad_input_is_one_line_and_exit_2(case, simulated, tmp_path):
    empty_csv = tmp_path / "empty.csv"
    empty_csv.write_text("force_n\n")
    args = {
        "missing_file": [f"trajectories={tmp_path / 'nope.npz'}", "mean_n=1", "std_n=1"],
        "empty_trajectory": [f"trajectories={_trajectory(tmp_path / 'empty.npz', [])}", "mean_n=1", "std_n=1"],
        "empty_csv": [f"trajectories={simulated}", f"reference={empty_csv}"],
        "no_reference": [f"trajectories={simulated}"],
        "bad_std": [f"trajectories={simulated}", "mean_n=1", "std_n=0"],
        "no_trajectories": ["mean_n=1", "std_n=1"],
        "mean_not_a_number": [f"trajectories={simulated}", "mean_n=abc", "std_n=1"],
        "unknown_column": [f"trajectories={simulated}", f"reference={empty_csv}", "column=nope"],
    }[case]
    run = _cli(tmp_path, *args, f"out={tmp_path / 'out'}")
    assert run.returncode == 2
    assert run.stderr.startswith("error: ") and run.stderr.count("\n") == 1, run.stderr
