"""Small argument checks that raise clear, actionable errors."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any


def check_choice(value: Any, valid: Iterable[Any], what: str) -> Any:
    """Return ``value`` if it is one of ``valid``; otherwise raise ``ValueError`` listing the valid names.

    >>> check_choice("small", ["smoke", "small", "full"], "scale")
    'small'
    """
    options = list(valid)
    if value not in options:
        listed = ", ".join(repr(o) for o in options)
        raise ValueError(f"unknown {what} {value!r}; valid {what}s are: {listed}")
    return value


def check_nonneg(value: float, what: str) -> float:
    """Return ``value`` as float if it is finite and ``>= 0``; otherwise raise ``ValueError``."""
    try:
        v = float(value)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{what} must be a number >= 0, got {value!r}") from err
    if not v >= 0.0 or v == float("inf"):
        raise ValueError(f"{what} must be a finite number >= 0, got {value!r}")
    return v


def check_positive(value: float, what: str) -> float:
    """Return ``value`` as float if it is finite and ``> 0``; otherwise raise ``ValueError``."""
    v = check_nonneg(value, what)
    if v == 0.0:
        raise ValueError(f"{what} must be > 0, got {value!r}")
    return v
