"""Small argument checks that raise clear, actionable errors."""

from __future__ import annotations

import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

#: Terminal colour and style codes (torch's messages carry some); an error line is plain text.
_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


def check_choice(value: Any, valid: Iterable[Any], what: str) -> Any:
    """Return ``value`` if it is one of ``valid``; otherwise raise ``ValueError`` listing the valid names.

    >>> check_choice("small", ["smoke", "small", "full"], "scale")
    'small'
    """
    options = list(valid)
    if value not in options:
        listed = ", ".join(repr(o) for o in options)
        raise ValueError(f"unknown {what} {value!r}; valid {plural(what)} are: {listed}")
    return value


def plural(what: str) -> str:
    """English plural of a short noun phrase, pluralising its head noun (the last word before " of ").

    >>> [plural(w) for w in ("scale", "family", "status", "test box", "panel of figure 4.1", "ArmConfig field")]
    ['scales', 'families', 'statuses', 'test boxes', 'panels of figure 4.1', 'ArmConfig fields']
    """
    head, sep, tail = what.partition(" of ")
    words = head.split(" ")
    word = words[-1]
    if word.endswith("y") and word[-2:-1] not in tuple("aeiou"):
        word = word[:-1] + "ies"
    elif word.endswith(("s", "x", "z", "ch", "sh")):
        word += "es"
    else:
        word += "s"
    return " ".join([*words[:-1], word]) + sep + tail


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


def read_yaml(path: str | Path) -> Any:
    r"""The YAML file ``path`` parsed; a one-line ``ValueError`` naming the file and line when it is not UTF-8 or
    not valid YAML (never a traceback of the parser).

    >>> import tempfile, pathlib
    >>> bad = pathlib.Path(tempfile.mkdtemp()) / "claims.yaml"
    >>> _ = bad.write_text("a: 1\nb: [2\n")
    >>> read_yaml(bad)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: .../claims.yaml:3: not valid YAML (expected ',' or ']', but got '<stream end>'); fix the file
    """
    import yaml

    path = Path(path)
    data = path.read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        line = data[: err.start].count(b"\n") + 1
        raise ValueError(
            f"{path}:{line}: not UTF-8 (byte 0x{data[err.start]:02x} at offset {err.start}); save it as UTF-8"
        ) from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark is not None else str(path)
        what = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise ValueError(f"{where}: not valid YAML ({what}); fix the file") from None


def one_line(err: BaseException, limit: int | None = None) -> str:
    """``err``'s message on one line, without terminal codes; cut to ``limit`` characters if given.

    >>> one_line(ValueError("do this \\x1b[1monly if you trust it\\x1b[0m.\\n  (see above)"))
    'do this only if you trust it. (see above)'
    >>> one_line(RuntimeError("x" * 200), limit=10)
    'xxxxxxx...'
    """
    text = " ".join(_ANSI.sub("", str(err)).split()) or type(err).__name__
    return text if limit is None or len(text) <= limit else text[: limit - 3] + "..."
