"""Numbers the kit did not compute: the thesis's own, transcribed under ``data/thesis/``, and published baselines.

The thesis's tables and settings are tidy CSVs under ``data/thesis/`` (see its README.md; :func:`load`,
:func:`thesis_table`); other projects' published results are ``data/public/baselines.csv`` (:func:`published`).
(``data/reference/`` is something else: the kit's own shipped runs.)

Every frame carries ``source="thesis"`` so notebooks can concatenate it with ``source="reproduced"`` rows.

>>> from thesis_repro.core import thesis_numbers
>>> thesis_numbers.thesis_table("table3_4", env="Walker2d", test="obs", method="sac")[["mean", "std"]].values.tolist()
[[1565.4, 544.9]]
"""

from __future__ import annotations

from collections.abc import Collection, Sequence

import pandas as pd

from thesis_repro.core import paths
from thesis_repro.core.validation import check_choice

ENVS: tuple[str, ...] = ("Walker2d", "Hopper", "HalfCheetah", "InvertedPendulum", "InvertedDoublePendulum")
TESTS: tuple[str, ...] = ("obs", "act", "env", "dom")
_AUC = ("env", "test", "method", "mean", "std")
_SETTINGS = ("parameter", "condition", "value", "ref", "note")

#: table name (CSV stem) -> required columns, in file order.
TABLES: dict[str, tuple[str, ...]] = {
    "fig3_3c": ("env", "test", "value"),
    "table3_3a": ("train_condition", "train_sigma", "noise_type", "mean", "std"),
    "table3_3b": ("noise_type", "sigma_te", "train_sigma", "mean", "std"),
    "table3_4": _AUC,
    "table3_5": _AUC,
    "table3_6": _AUC,
    "table3_7": _AUC,
    "chapter3_settings": _SETTINGS,
    "chapter4_conditions": ("figure", "panel", "action_penalty", "wind_low", "wind_high"),
    "chapter4_settings": _SETTINGS,
    "chapter5_settings": _SETTINGS,
}
#: columns that may be empty (free-text notes)
_OPTIONAL = {"note"}
#: columns read as strings even when they look numeric (figure ids such as "4.1")
_STRINGS = {"figure": str, "panel": str, "condition": str, "ref": str, "note": str}


def _check_columns(frame: pd.DataFrame, label: str, required: Sequence[str], optional: Collection[str]) -> None:
    """``ValueError`` if ``frame`` lacks a ``required`` column or has a missing value outside ``optional``."""
    missing = [c for c in required if c not in frame.columns]
    if missing:
        raise ValueError(f"{label} lacks columns {missing}; expected {list(required)}")
    checked = [c for c in required if c not in optional]
    if frame[checked].isna().any().any():
        raise ValueError(f"{label} has missing values in {checked}")


def load(name: str) -> pd.DataFrame:
    """Load ``data/thesis/<name>.csv`` with a ``source="thesis"`` column.

    Raises ``ValueError`` for an unknown name (listing :data:`TABLES`), a missing column or a missing value.

    >>> load("fig3_3c").shape
    (20, 4)
    """
    check_choice(name, TABLES, "thesis table")
    frame = pd.read_csv(paths.thesis_table_path(name), dtype=_STRINGS, keep_default_na=False, na_values=[""])
    _check_columns(frame, f"thesis table {name!r}", TABLES[name], _OPTIONAL)
    if "note" in frame.columns:
        frame["note"] = frame["note"].fillna("")
    frame["source"] = "thesis"
    return frame


def thesis_table(name: str, env: str | None = None, test: str | None = None, method: str | None = None) -> pd.DataFrame:
    """Rows of table ``name`` matching the given ``env``/``test``/``method`` (``None`` = all), re-indexed.

    Unknown filter values raise ``ValueError`` listing the values present in that table.

    >>> thesis_table("table3_7", env="InvertedDoublePendulum", test="dom", method="ppo-reptile-dg")["mean"].item()
    8293.3
    """
    frame = load(name)
    for column, value in (("env", env), ("test", test), ("method", method)):
        if value is None:
            continue
        if column not in frame.columns:
            raise ValueError(f"thesis table {name!r} has no {column!r} column; its columns are {list(frame.columns)}")
        check_choice(value, sorted(frame[column].unique()), column)
        frame = frame[frame[column] == value]
    return frame.reset_index(drop=True)


#: Columns of ``data/public/baselines.csv``, in file order (see its README.md).
PUBLISHED_COLUMNS: tuple[str, ...] = ("source", "algo", "env", "steps", "mean", "std", "env_version", "url", "note")
#: Columns of the published table that may be empty (no spread across seeds published; no note).
_PUBLISHED_OPTIONAL = {"std", "note"}


def published() -> pd.DataFrame:
    """Other projects' published results on the kit's tasks (``data/public/baselines.csv``: CleanRL's PPO, the
    SB3 zoo's SAC), with ``kind="published"``: neither the thesis's numbers nor reproduced ones. ``std`` is NaN
    where the source publishes no spread across seeds. A missing column or value is a ``ValueError``.

    >>> p = published()
    >>> row = p[(p.source == "CleanRL") & (p.env == "Hopper")].iloc[0]
    >>> row["algo"], int(row["steps"]), float(row["mean"]), float(row["std"]), row["kind"]
    ('ppo', 1000000, 2382.86, 271.74, 'published')
    """
    path = paths.PUBLIC_DATA / "baselines.csv"
    frame = pd.read_csv(path, dtype={"env_version": str, "note": str}, keep_default_na=False, na_values=[""])
    _check_columns(frame, path.name, PUBLISHED_COLUMNS, _PUBLISHED_OPTIONAL)
    unknown = sorted(set(frame["env"]) - set(ENVS))
    if unknown:
        raise ValueError(f"{path.name}: unknown envs {unknown}; valid envs are: {', '.join(ENVS)}")
    frame["steps"] = frame["steps"].astype(int)
    frame["note"] = frame["note"].fillna("")
    frame["kind"] = "published"
    return frame
