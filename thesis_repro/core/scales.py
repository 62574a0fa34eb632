"""The kit's one scale table: ``smoke | small | full`` settings for every figure notebook.

The table itself is data (``thesis_repro/config/scales.yaml``). Notebooks call
:func:`figure_settings` in the cell after their ``parameters`` cell.

>>> s = figure_settings("_example", "smoke")
>>> s["train_seeds"], s["scale"]
(1, 'smoke')
>>> figure_settings("_example", "huge")
Traceback (most recent call last):
...
ValueError: unknown scale 'huge'; valid scales are: 'smoke', 'small', 'full'
"""

from __future__ import annotations

import copy
from functools import cache
from typing import Any

from thesis_repro.core import paths, yamlfile
from thesis_repro.core.validation import check_choice

SCALES: tuple[str, ...] = ("smoke", "small", "full")
#: What a table cell, and a verdict, says of an item a scale cannot afford (e.g. an off-policy row at small).
NOT_RUN = "not run at this scale"


@cache
def _table() -> dict[str, Any]:
    with open(paths.CONFIG / "scales.yaml") as fh:
        table = yamlfile.parse(fh)
    for key in ("scales", "defaults", "figures"):
        if key not in table:
            raise ValueError(f"scales.yaml is malformed: missing top-level key {key!r}")
    if tuple(table["scales"]) != SCALES:
        raise ValueError(f"scales.yaml must define exactly the scales {SCALES}")
    table["figures"] = table["figures"] or {}
    # A tiny built-in entry used by doctests and tests of the table machinery itself.
    table["figures"].setdefault("_example", {s: {} for s in SCALES})
    return table


def check_scale(scale: str) -> str:
    """Return ``scale`` if valid, else raise ``ValueError`` listing the valid scales."""
    return check_choice(scale, SCALES, "scale")


def figures() -> list[str]:
    """All figure ids with an entry in the scale table (``'_example'`` excluded)."""
    return sorted(f for f in _table()["figures"] if not f.startswith("_"))


def figure_settings(figure: str, scale: str, **overrides: Any) -> dict[str, Any]:
    """Resolved settings of ``figure`` at ``scale``: scale defaults, then the figure's block, then ``overrides``
    (the caller's word is last).

    Overrides may only name keys that already exist (a typo is an error, not a silent new key).
    The result also carries ``figure`` and ``scale``.
    """
    check_scale(scale)
    table = _table()
    check_choice(figure, list(table["figures"]), "figure")
    entry = table["figures"][figure]
    missing = [s for s in SCALES if s not in entry]
    if missing:
        raise ValueError(f"scales.yaml: figure {figure!r} has no block for scale(s) {missing}")
    settings: dict[str, Any] = copy.deepcopy(table["defaults"][scale])
    settings.update(copy.deepcopy(entry[scale] or {}))
    for key in overrides:
        check_choice(key, list(settings), f"setting of figure {figure}")
    settings.update(overrides)
    settings["figure"] = figure
    settings["scale"] = scale
    return settings
