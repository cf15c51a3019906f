"""The wheel carries tasks/, conf/ and assets/: install it elsewhere and load a task."""

import os
import subprocess
import sys


def test_wheel_installs_and_loads_a_task(tmp_path, repo_root):
    dist = tmp_path / "dist"
    # -v shows the build backend's own output, where setuptools prints its packaging warnings.
    built = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-v",
            "-w",
            str(dist),
            str(repo_root),
        ],
        check=True,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert "would be ignored" not in built.stdout + built.stderr, "a data folder is missing from pyproject's packages"
    wheel = next(dist.glob("cathsim_dmc-*.whl"))
    # Install the wheel alone into its own folder; its dependencies come from this
    # environment. That folder is first on the path, so every module below must come
    # from the wheel, not from the source tree (checked by file location).
    target = tmp_path / "site"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(target), str(wheel)],
        check=True,
        capture_output=True,
        timeout=600,
    )
    code = (
        "import numpy as np, cathsim_dmc, cathsim_dmc.tasks as tasks\n"
        "from cathsim_dmc.core.shipped import assets_root, conf_root\n"
        "for where in (cathsim_dmc.__file__, tasks.__file__, str(assets_root()), str(conf_root())):\n"
        "    assert where.startswith(%r), where\n"
        "assert (conf_root() / 'eval.yaml').is_file()\n"
        "env = tasks.load('bca', 'type1'); env.reset(); env.step(np.zeros(2))\n"
        "print('ok')\n"
    ) % str(target)
    result = subprocess.run(
        [sys.executable, "-c", code],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "PYTHONPATH": str(target)},
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().endswith("ok")
    # A tool from the wheel composes its config, shared Hydra settings included.
    tool = subprocess.run(
        [
            sys.executable,
            "-m",
            "cathsim_dmc.app.cli.eval",
            "policy=forward",
            "episodes=1",
            "task.max_steps=2",
            "video=false",
            f"hydra.run.dir={tmp_path / 'eval'}",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "PYTHONPATH": str(target)},
    )
    assert tool.returncode == 0, tool.stderr[-2000:]
    assert (tmp_path / "eval" / "metrics.json").is_file()
