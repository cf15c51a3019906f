"""The shipped aortas as test parameters. Tests that build a whole environment per aorta
run the oblique variants only with `-m slow`: they are the type I-III arches turned about
the descending aorta (test_oblique.py checks them point for point against their plain
arch), so in the default suite they would repeat the plain arch's test at its cost."""

import pytest

from cathsim_dmc import tasks
from cathsim_dmc.core.shipped import available_aortas


def _slow_if_oblique(aorta: str, *values):
    # pytest.param for every case: a bare 1-tuple would reach the test as a tuple.
    return pytest.param(*values, marks=pytest.mark.slow if aorta.endswith("_oblique") else ())


def aorta_params() -> list:
    """Every shipped aorta's name."""
    return [_slow_if_oblique(name, name) for name in available_aortas()]


def task_params() -> list:
    """Every (target, aorta) pair of the suite, `tasks.ALL_TASKS`."""
    return [_slow_if_oblique(aorta, target, aorta) for target, aorta in tasks.ALL_TASKS]
