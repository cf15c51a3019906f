import os

import pytest

# Select the headless GL backend before any test module imports dm_control.
import cathsim_dmc  # noqa: F401,E402

# Keep torch and BLAS from oversubscribing the two cores while tests run in one process.
os.environ.setdefault("OMP_NUM_THREADS", "1")


@pytest.fixture(scope="session")
def repo_root():
    from pathlib import Path

    return Path(__file__).resolve().parents[1]
