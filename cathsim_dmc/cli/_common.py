"""Shared by the Hydra entry points: validate choices before Hydra starts.

Hydra reports an unknown config-group option as a multi-line error with exit status 1.
Our tools promise one line naming the valid choices and exit status 2, so the
command-line overrides for the axes we know are checked first.
"""

from __future__ import annotations

import sys
from typing import Callable, Mapping, Sequence

USAGE_ERROR = 2


def fail(message: str) -> "NoReturn":  # noqa: F821
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(USAGE_ERROR)


def check_overrides(argv: Sequence[str], choices: Mapping[str, Callable[[], Sequence[str]]],
                    paths_allowed: Sequence[str] = ()) -> None:
    """Exit with status 2 if `key=value` (or `key=a,b` in a sweep) names an unknown choice.

    For keys in `paths_allowed` an existing file or folder is accepted too (a checkpoint).
    """
    from pathlib import Path

    for arg in argv:
        if arg.startswith("-") or "=" not in arg:
            continue
        key, _, value = arg.lstrip("+~").partition("=")
        if key not in choices:
            continue
        valid = list(choices[key]())
        for item in value.split(","):
            if item in valid:
                continue
            if key in paths_allowed:
                if not Path(item).exists():
                    fail(f"{key}={item!r} is neither one of {valid} nor an existing checkpoint path")
            else:
                fail(f"{key}={item!r} is not valid; choose one of {valid}")


def run_hydra(task_function, config_name: str, argv_choices: Mapping[str, Callable[[], Sequence[str]]],
              paths_allowed: Sequence[str] = ()):
    """Validate argv, then run `task_function` as a Hydra app on the shipped conf/."""
    import hydra

    from cathsim_dmc.paths import conf_root

    check_overrides(sys.argv[1:], argv_choices, paths_allowed)

    def guarded(cfg):
        # Hydra prints a traceback for exceptions from the task; a bad value in the
        # config is the user's input, so it gets our one-line error (SystemExit passes).
        try:
            return task_function(cfg)
        except (ValueError, FileNotFoundError, MemoryError) as error:
            fail(str(error))

    guarded.__name__ = getattr(task_function, "__name__", "app")
    guarded.__module__ = getattr(task_function, "__module__", __name__)
    app = hydra.main(version_base="1.3", config_path=str(conf_root()), config_name=config_name)(guarded)
    return app()
