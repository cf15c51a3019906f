"""Checks of user-given numbers, shared by the API and the command-line tools.

Hydra passes `seed=abc` through as the string "abc", and `float("abc")` fails with a
message that does not say which setting was wrong: these name it and the valid range.
"""

from __future__ import annotations

import math
import numbers
import os


def check_number(name: str, value, minimum: float | None = None, whole: bool = False, inclusive: bool = True):
    """`value` as a finite number (>= or > `minimum` if given; an int if `whole`), or a
    ValueError naming the parameter: one wording for every tool."""
    kind = "a whole number" if whole else "a finite number"
    bound = "" if minimum is None else f" {'>=' if inclusive else '>'} {minimum:g}"
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = None
    valid = not isinstance(value, (bool, str)) and number is not None and math.isfinite(number)
    valid = valid and not (whole and not isinstance(value, numbers.Integral))  # 2.0 episodes: a slip
    if valid and minimum is not None:
        valid = number >= minimum if inclusive else number > minimum
    if not valid:
        raise ValueError(f"{name}={value!r} must be {kind}{bound}")
    return int(number) if whole else number


def available_memory_bytes() -> int:
    """MemAvailable from /proc/meminfo (what can be allocated without swapping)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")


def check_parameters(owner: str, positive: dict = None, non_negative: dict = None, finite: dict = None) -> None:
    """ValueError naming `owner key=value` unless every value (or each item of a tuple) of
    `positive` is > 0, of `non_negative` >= 0 and of `finite` a finite number; None passes.
    An entity checks its parameters with it at construction: NaN compiles into a model
    whose every step is non-finite."""
    for minimum, inclusive, values in ((0.0, False, positive), (0.0, True, non_negative), (None, True, finite)):
        for key, value in (values or {}).items():
            for item in value if isinstance(value, (tuple, list)) else () if value is None else (value,):
                check_number(f"{owner} {key}", item, minimum, inclusive=inclusive)
