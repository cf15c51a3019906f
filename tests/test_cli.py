"""cathsim-eval end to end, and its one-line errors."""

import subprocess
import sys

import imageio.v3 as iio
import numpy as np

from cathsim_dmc.trajectory import load_trajectories


def _run(args, cwd):
    return subprocess.run([sys.executable, "-m", "cathsim_dmc.cli.eval", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=600)


def test_eval_writes_trajectories_and_video(tmp_path):
    result = _run(["task=lcca", "aorta=type1", "policy=forward", "episodes=1", "task.max_steps=12",
                   f"hydra.run.dir={tmp_path}/run"], tmp_path)
    assert result.returncode == 0, result.stderr
    data = load_trajectories(tmp_path / "run" / "trajectories.npz")
    assert len(data["step"]) == 12 and data["truncated"][-1]
    assert np.all(data["action"][:, 0] == 1.0)
    # Full-speed insertion: the tip climbs the descending aorta.
    assert data["tip_position_m"][-1, 1] > data["start_tip_position_m"][0, 1] + 0.01
    gif = tmp_path / "run" / "video.gif"
    # The wire moves every step, so the GIF keeps (nearly) one frame per step.
    assert iio.improps(gif, index=None).n_images >= 10


def test_unknown_choice_is_one_line_and_exit_2(tmp_path):
    for bad, valid in (("task=xyz", "bca"), ("aorta=xyz", "type1"), ("policy=xyz", "forward")):
        result = _run([bad, f"hydra.run.dir={tmp_path}/bad"], tmp_path)
        assert result.returncode == 2, result.stderr
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and valid in lines[0] and "Traceback" not in result.stderr
