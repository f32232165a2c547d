"""Comma-list flags of the command line (``--meshes obj,ply``, ``--integrators rk4,implicit``,
``--dts 0.002,0.001``, ``--sizes 32,64``): one parser, each bad item an ``InputError`` that names
the flag."""

import math

from taichi_cloth.errors import InputError


def comma_items(text: str) -> tuple[str, ...]:
    """The non-empty, stripped items of a comma list, first occurrences only, in order."""
    return tuple(dict.fromkeys(item.strip() for item in text.split(",") if item.strip()))


def choice_list(text: str, flag: str, choices, what: str) -> tuple[str, ...]:
    """A comma list whose items are each one of ``choices`` (``what`` names one, e.g.
    "integrator"); at least one."""
    items = comma_items(text.lower())
    unknown = [item for item in items if item not in choices]
    if unknown or not items:
        problem = f"unknown {what} {unknown[0]!r}" if unknown else f"no {what} given"
        raise InputError(f"{flag} {text}: {problem} (choose from {', '.join(choices)})")
    return items


def number_list(text: str, flag: str, kind=float, minimum: float = 0.0,
                unit: str = "seconds") -> tuple:
    """A comma list of finite numbers of ``kind`` above ``minimum`` (``unit`` for messages)."""
    values = []
    for item in (part.strip() for part in text.split(",")):
        try:
            value = kind(item)
        except ValueError:
            raise InputError(f"{flag} {text}: {item!r} is not a number of {unit}") from None
        if not (math.isfinite(value) and value > minimum):
            raise InputError(f"{flag} {text}: {item} must be a number of {unit} above {minimum:g}")
        values.append(value)
    return tuple(values)
