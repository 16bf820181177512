"""A setting's value from a string, a TOML or a JSON value: converted to the field's type and
checked against its range, one line (:class:`~layercam.core.errors.LayercamError`) when wrong."""

from __future__ import annotations

import math
import types
import typing
from typing import Any, Literal

from layercam.core.errors import LayercamError


INT_MAX = 2**31 - 1  # every integer setting fits a C int (OpenCV, torch's sizes and seeds): a larger one is refused

def _alternatives(hint) -> list:
    """``int | Literal["auto"]`` -> ``[int, Literal["auto"]]``; a plain type -> ``[type]``."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return list(typing.get_args(hint))
    return [hint]


def _describe(hint) -> str:
    """``Literal["a", "b"]`` -> "one of a, b"; ``int | Literal["auto"]`` -> "an integer or auto"."""
    kinds, choices = [], []
    for alt in _alternatives(hint):
        if typing.get_origin(alt) is Literal:
            choices += [str(c) for c in typing.get_args(alt)]
        else:
            kinds.append({bool: "true/false (on/off)", int: "an integer", float: "a number",
                          str: "text"}.get(alt, str(alt)))
    if not kinds:
        return "one of " + ", ".join(choices)
    return " or ".join(kinds + choices)


def _as(value: Any, typ) -> Any:
    """``value`` (a string from ``--set`` or a TOML/JSON value) as ``typ``; ValueError when it is not."""
    if typing.get_origin(typ) is Literal:
        for c in typing.get_args(typ):
            if value == c and type(value) is type(c):
                return c
            if isinstance(value, str) and str(c) == value.strip():
                return c
        raise ValueError
    if typ is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str):
            v = value.strip().lower()
            if v in ("1", "true", "yes", "on"):
                return True
            if v in ("0", "false", "no", "off"):
                return False
        raise ValueError
    if isinstance(value, bool):  # bool is an int to Python, never to a setting
        raise ValueError
    if typ is int:
        if isinstance(value, int):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
        if isinstance(value, str):
            f = float(value)
            if f.is_integer():
                return int(f)
        raise ValueError
    if typ is float:
        if isinstance(value, (int, float)):
            return float(value)
        if isinstance(value, str):
            return float(value)
        raise ValueError
    if typ is str:
        if isinstance(value, str):
            return value
        raise ValueError
    raise ValueError


def check_value(key: str, value: Any, hint, meta: dict | None = None) -> Any:
    """``value`` converted to ``hint`` and checked against the field's range: one line on failure."""
    meta = meta or {}
    alts = sorted(_alternatives(hint), key=lambda a: typing.get_origin(a) is not Literal)  # choices first
    for alt in alts:
        try:
            v = _as(value, alt)
            break
        except (ValueError, TypeError, OverflowError):
            continue
    else:
        raise LayercamError(f"{key}: expected {_describe(hint)}, got {value!r}")
    if isinstance(v, float) and not math.isfinite(v):
        raise LayercamError(f"{key}: must be a finite number, got {value!r}")
    if isinstance(v, int) and not isinstance(v, bool) and abs(v) > INT_MAX:
        raise LayercamError(f"{key}: must be an integer of at most {INT_MAX}, got {value!r}")
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        lo, hi, above, below = meta.get("lo"), meta.get("hi"), meta.get("above"), meta.get("below")
        if lo is not None and v < lo:
            raise LayercamError(f"{key}: must be >= {lo:g}, got {v:g}")
        if hi is not None and v > hi:
            raise LayercamError(f"{key}: must be <= {hi:g}, got {v:g}")
        if above is not None and not v > above:
            raise LayercamError(f"{key}: must be > {above:g}, got {v:g}")
        if below is not None and not v < below:
            raise LayercamError(f"{key}: must be < {below:g}, got {v:g}")
    if meta.get("check") is not None:
        msg = meta["check"](v)
        if msg:
            raise LayercamError(f"{key}: {msg}, got {value!r}")
    return v
