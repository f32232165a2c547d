"""Declared settings: every key of a scene table is a dataclass field made with ``setting``
(its default, kind and allowed values), and ``build_table`` checks a parsed TOML table against
such a dataclass. A bad value raises ``InputError`` naming the file (or the ``--set`` flag) and
the dotted key: an unknown key with the closest valid one suggested, a wrong type, a value out of
range.

The scene's sections (``config.scene``) and every effect's ``Settings`` (``effects/``) are
declared this way, so an effect brings its own scene table.
"""

import dataclasses
import difflib
import math
from dataclasses import field
from typing import Any

from taichi_cloth.errors import InputError


def setting(default: Any, kind: str, *, low: float | None = None, high: float | None = None,
            low_inclusive: bool = True, choices: tuple | None = None, length: int | None = None,
            doc: str = "", shorthand: str = ""):
    """A declared scene key: its default, its kind and its allowed values.

    kind: "float", "int", "str", "bool", "float_list", "int_list", "str_list", "dt", or "table"
    (a nested table; the default is an instance of its dataclass, and a bare string is taken as
    ``{shorthand = string}``). low/high bound numbers (every element of a list); choices bound
    strings (every element of a list); length fixes a list's length.
    """
    check = dict(kind=kind, low=low, high=high, low_inclusive=low_inclusive, choices=choices,
                 length=length, doc=doc, shorthand=shorthand)
    if isinstance(default, list):
        default = tuple(default)
    return field(default=default, metadata=check)


class SourceContext:
    """Where a value came from, for error messages: the file, or the flag that overrode it
    (``overridden``: dotted key → the flag as the user gave it, e.g. "--set cloth.shape" or
    "--arch cuda")."""

    def __init__(self, path: str, overridden: dict[str, str]):
        self.path = path
        self.overridden = overridden

    def error(self, dotted: str, problem: str) -> InputError:
        """The error at ``dotted``, naming the flag of the most specific overridden key that
        reaches it (or the file)."""
        matching = [key for key in self.overridden
                    if dotted == key or dotted.startswith(key + ".") or key.startswith(dotted + ".")]
        if matching:
            return InputError(f"{self.overridden[max(matching, key=len)]}: {problem}")
        return InputError(f"{self.path}: {dotted}: {problem}")


def _check_number(ctx, dotted, value, meta, integer):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (
            integer and not isinstance(value, int)):
        raise ctx.error(dotted, f"expected {'an integer' if integer else 'a number'}, "
                                f"got {value!r}")
    if not math.isfinite(value):
        raise ctx.error(dotted, f"must be finite, got {value!r}")
    low, high = meta["low"], meta["high"]
    unit = f" ({meta['doc']})" if meta["doc"] else ""
    if low is not None and (value < low or (value == low and not meta["low_inclusive"])):
        bound = f">= {low}" if meta["low_inclusive"] else f"> {low}"
        raise ctx.error(dotted, f"must be {bound}{unit}, got {value!r}")
    if high is not None and value > high:
        raise ctx.error(dotted, f"must be <= {high}{unit}, got {value!r}")
    return float(value) if not integer else value


def _check_choice(ctx, dotted, value, meta):
    if not isinstance(value, str):
        raise ctx.error(dotted, f"expected a string, got {value!r}")
    choices = meta["choices"]
    if choices is not None and value not in choices:
        listed = ", ".join(repr(c) for c in choices)
        raise ctx.error(dotted, f"unknown value {value!r}; valid: {listed}")
    return value


def _check_value(ctx, dotted, value, meta):
    kind = meta["kind"]
    if kind == "float":
        return _check_number(ctx, dotted, value, meta, integer=False)
    if kind == "int":
        return _check_number(ctx, dotted, value, meta, integer=True)
    if kind == "str":
        return _check_choice(ctx, dotted, value, meta)
    if kind == "bool":
        if not isinstance(value, bool):
            raise ctx.error(dotted, f"expected true or false, got {value!r}")
        return value
    if kind == "dt":
        if value == "auto":
            return value
        if isinstance(value, str):
            raise ctx.error(dotted, f"expected a number of seconds or \"auto\", got {value!r}")
        return _check_number(ctx, dotted, value, meta, integer=False)
    element_kind = kind.removesuffix("_list")
    if not isinstance(value, list):
        raise ctx.error(dotted, f"expected a list, got {value!r}")
    if meta["length"] is not None and len(value) != meta["length"]:
        raise ctx.error(dotted, f"expected a list of {meta['length']} values, got {value!r}")
    element_meta = dict(meta, kind=element_kind)
    return tuple(_check_value(ctx, f"{dotted}[{i}]", v, element_meta) for i, v in enumerate(value))


def build_table(ctx: SourceContext, cls, table: Any, dotted: str):
    """Validate a TOML table against dataclass ``cls`` and construct it."""
    if not isinstance(table, dict):
        raise ctx.error(dotted, f"expected a table, got {table!r}")
    declared = {f.name: f for f in dataclasses.fields(cls)}
    for key in table:
        if key not in declared:
            close = difflib.get_close_matches(key, list(declared), n=1)
            hint = f"; did you mean '{close[0]}'?" if close else \
                f"; valid keys: {', '.join(declared)}"
            raise ctx.error(f"{dotted}.{key}", f"unknown key '{key}' in [{dotted}]{hint}")
    values = {}
    for name, f in declared.items():
        if name not in table:
            continue
        child = f"{dotted}.{name}"
        if f.metadata["kind"] == "table":
            raw = table[name]
            if isinstance(raw, str) and f.metadata["shorthand"]:
                raw = {f.metadata["shorthand"]: raw}
            values[name] = build_table(ctx, type(f.default), raw, child)
        else:
            values[name] = _check_value(ctx, child, table[name], f.metadata)
    return cls(**values)


def numbers_in(value, dotted: str):
    """(dotted key, float) for every float inside ``value``: a settings dataclass (its fields),
    a dict (its items), a list or tuple (``key[i]``), or a float."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        for item in dataclasses.fields(value):
            yield from numbers_in(getattr(value, item.name), f"{dotted}.{item.name}")
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from numbers_in(item, f"{dotted}.{key}")
    elif isinstance(value, (list, tuple)):
        for index, item in enumerate(value):
            yield from numbers_in(item, f"{dotted}[{index}]")
    elif isinstance(value, float):
        yield dotted, value
