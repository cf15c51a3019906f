"""cathsim-force: the network learns a synthetic image -> force relation; subsets, baselines, errors."""

import json
import subprocess
import sys

import numpy as np
import pytest
import torch

from cathsim_dmc.learning.supervised.force import ForceConfig, ForceNetwork, markdown, nested_subsets, train_force_sizes


def _synthetic(episodes=24, steps=10, seed=0):
    """A bright square whose area sets the force: f = 2 N x (side / 40 px)^2."""
    rng = np.random.default_rng(seed)
    n = episodes * steps
    images = np.zeros((n, 1, 80, 80), np.uint8)
    sides = rng.integers(4, 41, size=n)
    corners = rng.integers(0, 80 - sides + 1, size=(2, n))
    for i, (side, y, x) in enumerate(zip(sides, *corners)):
        images[i, 0, y : y + side, x : x + side] = 255
    force = (2.0 * (sides / 40.0) ** 2).astype(np.float32)
    return images, force, np.repeat(np.arange(episodes), steps)


def test_nested_subsets_grow_by_whole_episodes():
    episodes = np.repeat(np.arange(10), 5)
    train = np.arange(40)  # episodes 0..7
    subsets = nested_subsets(episodes, train, (12, 30, 100), seed=0)
    assert [len(rows) for _, rows in subsets] == [12, 30, 40]  # 100 asked, 40 exist
    assert np.array_equal(subsets[1][1][:12], subsets[0][1])
    assert set(episodes[subsets[2][1]]) == set(range(8))


def test_network_learns_a_synthetic_image_to_force_relation(tmp_path):
    torch.set_num_threads(1)
    images, force, episodes = _synthetic()
    cfg = ForceConfig(
        sizes=(40, 190), epochs=1, min_updates=150, batch_size=16, test_fraction=0.2, val_fraction=0.1, seed=0
    )  # measured test MSE: 0.033 N^2 (40 samples), 0.011 (190), train mean 0.37, before fine-tuning 1.12
    report = train_force_sizes(images, force, episodes, cfg, out_dir=tmp_path)
    small, large = report["sizes"]
    assert report["test_episodes"] == 5 and large["train_samples"] == 190
    # More data, lower test error; and far below both baselines.
    assert large["model"]["mse_n2"] < small["model"]["mse_n2"]
    assert large["model"]["mse_n2"] < 0.2 * large["train_mean"]["mse_n2"]
    assert large["model"]["mse_n2"] < 0.2 * large["before_fine_tuning"]["mse_n2"]
    assert (tmp_path / "force_model_190.pt").is_file()
    table = markdown(report)
    assert table.startswith("| Training samples |") and "| 190 |" in table


def test_test_outliers_are_also_scored_apart():
    images, force, episodes = _synthetic(episodes=10, steps=4)
    cfg = ForceConfig(sizes=(100,), epochs=1, min_updates=5, batch_size=16, test_fraction=0.2, outlier_n=10.0)
    from cathsim_dmc.learning.datasets import split_by_episode

    _, test_rows = split_by_episode(episodes, cfg.test_fraction, cfg.seed)
    force = force.copy()
    force[test_rows[0]] = 500.0  # one impulse-like label in the test set
    report = train_force_sizes(images, force, episodes, cfg)
    (only,) = report["sizes"]
    assert report["test_outliers"] == 1 and report["test_force_max_n"] == pytest.approx(500.0)
    kept = np.delete(force[test_rows], 0)
    assert only["without_outliers"]["train_mean"]["mse_n2"] < only["train_mean"]["mse_n2"] / 100
    train_mean = force[np.setdiff1d(np.arange(len(force)), test_rows)].mean()
    assert only["without_outliers"]["train_mean"]["mse_n2"] == pytest.approx(
        np.mean((kept - train_mean) ** 2), rel=1e-5
    )
    assert "Without the 1 test sample(s) above 10 N" in markdown(report)
    # No outlier: one table only.
    report = train_force_sizes(images, np.minimum(force, 5.0), episodes, cfg)
    assert "without_outliers" not in report["sizes"][0] and "Without the" not in markdown(report)


def test_z_head_is_trained_when_z_is_given():
    images, force, episodes = _synthetic(episodes=6, steps=4)
    z = np.random.default_rng(0).normal(size=(len(force), 8)).astype(np.float32)
    cfg = ForceConfig(sizes=(100,), epochs=1, min_updates=5, batch_size=16, test_fraction=0.2)
    report = train_force_sizes(images, force, episodes, cfg, z=z)
    assert report["uses_z"]
    net = ForceNetwork(z_dim=8)
    prediction, z_hat = net(torch.zeros(2, 1, 80, 80, dtype=torch.uint8))
    assert prediction.shape == (2,) and z_hat.shape == (2, 8)


def _force(args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "cathsim_dmc.app.cli.force", *args], cwd=cwd, capture_output=True, text=True, timeout=600
    )


def test_cli_reports_mse_per_size(tmp_path):
    from cathsim_dmc.agents.collect import collect

    collect(
        tmp_path / "data",
        "lcca",
        "type1",
        "forward",
        episodes=3,
        episodes_per_shard=2,
        seed=0,
        task_options={"max_steps": 8},
        show_progress=False,
    )
    result = _force(
        [
            f"data={tmp_path}/data",
            "force.sizes=[8,1000]",
            "force.epochs=1",
            "force.min_updates=2",
            "progress_bar=false",
            f"hydra.run.dir={tmp_path}/run",
        ],
        tmp_path,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    report = json.loads((tmp_path / "run" / "force.json").read_text())
    assert [r["train_samples"] for r in report["sizes"]] == [8, 16] and report["test_samples"] == 8
    for r in report["sizes"]:
        assert r["model"]["rmse_n"] == pytest.approx(r["model"]["mse_n2"] ** 0.5)
    assert "(all there is; 1,000 asked)" in (tmp_path / "run" / "force.md").read_text()


# A missing data=, a folder that does not exist or holds no dataset: cathsim-force reads its
# data= with cathsim-bc's code (dataset_paths, learning/datasets.py), whose refusals
# test_bc.py checks; each case here is a cathsim-force process (a torch import).
@pytest.mark.parametrize(
    "args, expected",
    [
        (["data={data}"], "not a readable"),
        (["data={data}", "image_key=depth"], "pixels"),
        (["data={data}", "force.sizes=[0]"], "force.sizes"),
        (["data={data}", "label=peak_force"], "mean_contact_force_n"),
        (["data={old}"], "label=mean_contact_force_n is not in the data"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, args, expected):
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "trajectories.npz").write_bytes(b"")
    # A trajectory file from before the step-mean force was recorded.
    (tmp_path / "old").mkdir()
    np.savez(
        tmp_path / "old" / "trajectories.npz",
        episode=np.zeros(3, np.int32),
        contact_force_n=np.zeros(3),
        obs_pixels=np.zeros((3, 1, 80, 80), np.uint8),
    )
    args = [a.format(data=tmp_path / "data", old=tmp_path / "old") for a in args]
    result = _force([*args, f"hydra.run.dir={tmp_path}/bad"], tmp_path)
    assert result.returncode == 2, result.stderr[-2000:]
    lines = [line for line in result.stderr.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and expected in lines[0] and "Traceback" not in result.stderr, result.stderr
