import os

import pytest

# Select the headless GL backend before any test module imports dm_control.
import cathsim_dmc  # noqa: F401,E402

# Composing conf/ needs the config schemas in Hydra's ConfigStore, as the tools register them
# before they compose (cathsim_dmc/app/cli/_common.py); tests compose conf/ directly too.
from cathsim_dmc.app.tool_schemas import register_schemas  # noqa: E402

register_schemas()

# Keep torch and BLAS from oversubscribing the two cores while tests run in one process.
os.environ.setdefault("OMP_NUM_THREADS", "1")


@pytest.fixture(scope="session")
def repo_root():
    from pathlib import Path

    return Path(__file__).resolve().parents[1]


def load_script(path):
    """A script of scripts/ or experiments/ (not a package) as a module, to test its functions."""
    import importlib.util
    import sys

    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while it executes
    spec.loader.exec_module(module)
    return module


def expert_successes(aorta, target: str, episodes: int = 5) -> int:
    """Episodes (seeds 0, 1, ...) in which the scripted expert reaches `target` in the asset
    folder `aorta`, with the wire alone."""
    from cathsim_dmc.control.expert import CenterlineExpert
    from cathsim_dmc.suite.gym import CathSimEnv

    env = CathSimEnv(task=target, aorta=str(aorta), obs="internal")
    reached = 0
    try:
        for seed in range(episodes):
            observation, info = env.reset(seed=seed)
            expert = CenterlineExpert()
            for _ in range(env.task.max_steps):
                observation, _, terminated, truncated, info = env.step(expert(observation, env))
                if terminated or truncated:
                    break
            reached += bool(info["success"])
    finally:
        env.close()
    return reached
