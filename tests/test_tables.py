"""scripts/paper_tables.py: the imitation and force tables from run folders; bad input."""

import json
import subprocess
import sys

from cathsim_dmc.metrics import METRIC_COLUMNS


def _table(args, repo_root, cwd):
    return subprocess.run([sys.executable, str(repo_root / "scripts" / "paper_tables.py"), *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120)


def test_tables_from_runs(tmp_path, repo_root):
    summary = {key: {"mean": 1.0, "std": 0.5, "n": 2} for key in METRIC_COLUMNS}
    summary["success_pct"] = {"mean": 85.0, "std": 35.7, "n": 20}
    report = {"task": "bca", "aorta": "type1", "policy": "bc-pixels", "summary": summary, "per_episode": [{}] * 20}
    (tmp_path / "bc" / "eval").mkdir(parents=True)
    (tmp_path / "bc" / "eval" / "metrics.json").write_text(json.dumps(report))
    sizes = [{"size_requested": n, "train_samples": n, **{k: {"mse_n2": m, "rmse_n": m ** 0.5} for k, m in
                                                             (("model", 0.04), ("train_mean", 0.16),
                                                              ("before_fine_tuning", 0.25))}} for n in (1000, 10000)]
    for r, mse in zip(sizes, (0.03, 0.01)):  # scores without one outlier test sample
        r["without_outliers"] = {"model": {"mse_n2": mse, "rmse_n": mse ** 0.5},
                                 **{k: {"mse_n2": 0.09, "rmse_n": 0.3} for k in ("train_mean", "before_fine_tuning")}}
    (tmp_path / "force").mkdir()
    (tmp_path / "force" / "force.json").write_text(json.dumps(
        {"sizes": sizes, "test_samples": 10, "test_episodes": 2, "test_force_mean_n": 0.2, "test_force_std_n": 0.4,
         "uses_z": False, "outlier_n": 10.0, "test_outliers": 1, "test_force_std_without_outliers_n": 0.3}))
    result = _table(["--bc", f"bca={tmp_path}/bc", "--force", f"{tmp_path}/force", "--out", f"{tmp_path}/out"],
                    repo_root, tmp_path)
    assert result.returncode == 0, result.stderr
    lines = (tmp_path / "out" / "imitation.md").read_text().splitlines()
    assert len(lines) == 2 + 6
    bc_row = next(line for line in lines if line.startswith("| BCA | Image w. expert |"))
    assert "| 85 ± 36 |" in bc_row and "| 20 |" in bc_row
    assert lines[2].startswith("| BCA | Expert | not run |")
    force = (tmp_path / "out" / "force.md").read_text().splitlines()
    assert force[0] == "| Test MSE (N²) [RMSE (N)] | 1,000 samples | 10,000 samples |"
    assert force[2] == "| Force network | 0.0400 [0.200] | 0.0400 [0.200] |"
    assert force[5].startswith("| *Without the 1 test sample(s) above 10 N:* |")
    assert force[6] == "| Force network | 0.0300 [0.173] | 0.0100 [0.100] |"
    assert force[7] == "| Train-set mean | 0.0900 [0.300] | 0.0900 [0.300] |"


def test_bad_folder_is_one_line_and_exit_2(tmp_path, repo_root):
    for args, expected in ((["--bc", f"bca={tmp_path}"], "metrics.json"), (["--bc", f"aorta={tmp_path}"], "lcca"),
                           (["--force", str(tmp_path)], "force.json")):
        result = _table([*args, "--out", f"{tmp_path}/out"], repo_root, tmp_path)
        assert result.returncode == 2
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and expected in lines[0], result.stderr
