"""Settings dataclasses whose fields carry their ranges: `setting(default, minimum=...)`
declares a field, `check_section` checks a dict (or a DictConfig) of values against them
and `with_defaults` fills in the ones a caller left out.

The learning layer declares its algorithm's settings this way (cathsim_dmc.learning.rl.settings);
the command-line tools' schemas (cathsim_dmc.app) are built from them and checked here too.
Needs neither a simulator nor a learning library.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import MISSING as NO_DEFAULT
from dataclasses import field, fields
from pathlib import Path

from cathsim_dmc.core.checks import check_number


def setting(default, minimum=None, maximum=None, above=None, whole=False, choices=None, below=None, prefix=None):
    """A dataclass field with its range: >= `minimum`, > `above`, <= `maximum`, < `below`,
    an int if `whole`, or one of `choices` (strings; or, with `prefix`, a string that starts
    with it). None as a default means the option may be off."""
    check = {
        "minimum": minimum,
        "maximum": maximum,
        "above": above,
        "whole": whole,
        "choices": choices,
        "below": below,
        "prefix": prefix,
    }
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=check)
    return field(default=default, metadata=check)


def count(default, minimum=0):
    """A whole-number field, >= `minimum`."""
    return setting(default, minimum=minimum, whole=True)


def check_section(name: str, schema, values: Mapping) -> None:
    """ValueError naming `name.key=value` for the first value of `values` (a dict or a
    DictConfig) outside its range in `schema` (`name` "": the top level). Keys `values`
    lacks are not checked: a Python caller may pass only the options it sets."""
    for spec in fields(schema):
        if not spec.metadata or spec.name not in values:
            continue
        value, check = values[spec.name], spec.metadata
        key = f"{name}.{spec.name}" if name else spec.name
        if check.get("folder"):  # an output folder: an existing file there would fail late
            if value is not None and Path(str(value)).exists() and not Path(str(value)).is_dir():
                raise ValueError(f"{key}={str(value)!r} is a file; give a folder (new or existing)")
            continue
        if value is None and type(None) in getattr(spec.type, "__args__", ()):
            continue  # an Optional option, off
        # a list option checks each item
        items = list(value) if isinstance(value, Sequence) and not isinstance(value, str) else [value]
        if check["choices"] is not None:
            prefix = check.get("prefix")
            for item in items:
                if str(item) not in check["choices"] and not (prefix and str(item).startswith(prefix)):
                    raise ValueError(f"{key}={value!r}; choose one of {list(check['choices'])}")
            continue
        for item in items:
            if check["above"] is not None:
                check_number(key, item, check["above"], whole=check["whole"], inclusive=False)
            number = check_number(key, item, check["minimum"], whole=check["whole"])
            if check["maximum"] is not None and not number <= check["maximum"]:
                raise ValueError(f"{key}={item!r} must lie in [{check['minimum']:g}, {check['maximum']:g}]")
            if check.get("below") is not None and not number < check["below"]:
                low = check["minimum"] if check["minimum"] is not None else check["above"]
                raise ValueError(
                    f"{key}={item!r} must lie in {'[' if check['minimum'] is not None else '('}"
                    f"{low:g}, {check['below']:g})"
                )


def with_defaults(schema, values: Mapping | None) -> dict:
    """`values` (a Python caller's dict may hold only the options it sets) over `schema`'s
    defaults: the trainer reads every option, and each default lives in its schema once."""
    defaults = {
        spec.name: spec.default_factory() if spec.default is NO_DEFAULT else spec.default
        for spec in fields(schema)
        if spec.default is not NO_DEFAULT or spec.default_factory is not NO_DEFAULT
    }
    return {**defaults, **dict(values or {})}
