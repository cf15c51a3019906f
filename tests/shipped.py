"""The shipped aortas as test parameters. Tests that build a whole environment per aorta
run the oblique variants only with `-m slow`: they are the type I-III arches turned about
the descending aorta (test_oblique.py checks them point for point against their plain
arch), so in the default suite they would repeat the plain arch's test at its cost."""

import pytest

from cathsim_dmc.paths import available_aortas


def aorta_params() -> list:
    return [pytest.param(name, marks=pytest.mark.slow) if name.endswith("_oblique") else name
            for name in available_aortas()]


def task_params(targets) -> list:
    return [pytest.param(target, name, marks=pytest.mark.slow) if name.endswith("_oblique") else (target, name)
            for target in targets for name in available_aortas()]
