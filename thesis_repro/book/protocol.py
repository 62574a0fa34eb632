"""The book page "Protocol: thesis beside kit", generated from ONE data file, ``data/protocol.yaml``.

Each row of the file is one protocol item: the thesis's words (section, line), the kit's setting (file), and a
status: ``match``, ``stated choice`` (the thesis is silent; ``reason`` says what we chose and why) or
``deviation`` (``reason`` says why). ``settings`` lists the settings a row covers, as glob patterns over the
setting ids of :func:`setting_ids`; ``tests/test_protocol_table.py`` fails when a setting has no row.

Setting ids:

* ``hp:<entry>:<key path>``: every key an entry of ``config/hyperparams.yaml`` itself defines (nested keys such
  as ``sb3.n_steps`` or ``arpl.delta`` dotted);
* ``run:<key>``: the run settings every training config carries (``learners.config.RUN_DEFAULTS``);
* ``scales:<figure id | defaults>/<key path>``: every key of ``config/scales.yaml``'s ``defaults`` and figure
  blocks (dicts of named settings such as a figure's ``source`` block dotted; learner overrides kept whole);
* ``arm:<source | target | curriculum | policy>.<key>``: chapter 5's job defaults and policy network.

A pattern also covers every id below it (``hp:ppo:net_arch`` covers ``hp:ppo:net_arch.pi``).

>>> covers("hp:ppo:net_arch", "hp:ppo:net_arch.pi"), covers("scales:*/seeds", "scales:5.6/seeds")
(True, True)
>>> covers("hp:ppo:sb3.n", "hp:ppo:sb3.n_steps")
False
"""

from __future__ import annotations

import dataclasses
import html
import re
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from fnmatch import fnmatchcase
from functools import cache
from pathlib import Path
from typing import Any

from thesis_repro.core import paths, scales, yamlfile

#: The data file of the page (outside ``data/thesis``, whose files are part of every notebook's execution key:
#: editing the table must not re-execute the book's notebooks, which never read it).
PROTOCOL_FILE: Path = paths.ROOT / "data" / "protocol.yaml"
#: Row statuses, in the page's order.
STATUSES: tuple[str, ...] = ("match", "stated choice", "deviation")
#: Keys of a row (``reason`` required unless the status is ``match``).
ROW_KEYS: tuple[str, ...] = ("group", "item", "thesis", "kit", "status", "reason", "settings")
#: Keys of scales.yaml whose values are learner overrides (kept whole: their keys are learner settings).
_WHOLE = {"train_overrides", "algo_overrides", "timesteps", "problems"}
PAGE = "protocol"
TITLE = "Protocol: thesis beside kit"


@cache
def rows(path: str | Path | None = None) -> tuple[dict[str, Any], ...]:
    """The rows of the protocol file, checked (unknown keys, statuses and missing fields are errors)."""
    data = yamlfile.parse(Path(path or PROTOCOL_FILE).read_text())
    out = data.get("rows") if isinstance(data, dict) else None
    if not out:
        raise ValueError(f"{path or PROTOCOL_FILE}: expected a `rows:` list")
    for i, row in enumerate(out):
        where = f"protocol row {i + 1} ({row.get('item', '?')!r})"
        unknown = set(row) - set(ROW_KEYS)
        if unknown:
            raise ValueError(f"{where}: unknown keys {sorted(unknown)}; valid keys are {', '.join(ROW_KEYS)}")
        for key in ("group", "item", "thesis", "kit", "status"):
            if not str(row.get(key) or "").strip():
                raise ValueError(f"{where}: `{key}` is empty")
        if row["status"] not in STATUSES:
            raise ValueError(f"{where}: status {row['status']!r} is not one of {', '.join(STATUSES)}")
        if row["status"] != "match" and not str(row.get("reason") or "").strip():
            raise ValueError(f"{where}: a {row['status']!r} row needs its `reason`")
        if not isinstance(row.get("settings", []), list):
            raise ValueError(f"{where}: `settings` must be a list of patterns")
    return tuple(out)


# ---------------------------------------------------------------------------------------- setting ids
def _flat(prefix: str, value: Any, whole: Iterable[str] = ()) -> Iterable[str]:
    whole = set(whole)
    if isinstance(value, Mapping) and value and prefix.rsplit(".", 1)[-1].rsplit("/", 1)[-1] not in whole:
        for k, v in value.items():
            yield from _flat(f"{prefix}.{k}" if not prefix.endswith(("/", ":")) else f"{prefix}{k}", v, whole)
    else:
        yield prefix


def hyperparams_ids(table: Mapping[str, Any] | None = None) -> set[str]:
    """``hp:<entry>:<path>`` for every key each entry of hyperparams.yaml defines itself."""
    if table is None:
        table = yamlfile.parse((paths.CONFIG / "hyperparams.yaml").read_text())
    return {i for entry, body in table.items() for i in _flat(f"hp:{entry}:", body)}


def scales_ids(table: Mapping[str, Any] | None = None) -> set[str]:
    """``scales:<figure | defaults>/<path>`` for every setting of scales.yaml (all scales)."""
    if table is None:
        table = yamlfile.parse((paths.CONFIG / "scales.yaml").read_text())
    ids: set[str] = set()
    for block in table.get("defaults", {}).values():
        ids |= set(_flat("scales:defaults/", block, _WHOLE))
    for fig, by_scale in table.get("figures", {}).items():
        for block in by_scale.values():
            ids |= set(_flat(f"scales:{fig}/", block, _WHOLE))
    return ids


def run_ids() -> set[str]:
    """``run:<key>`` for every run setting of :data:`thesis_repro.learners.config.RUN_DEFAULTS`."""
    from thesis_repro.learners.config import RUN_DEFAULTS  # local: the learners package loads torch and SB3

    return {f"run:{k}" for k in RUN_DEFAULTS}


def arm_ids() -> set[str]:
    """``arm:<block>.<key>`` for chapter 5's job defaults and the RBF-PD policy's fields."""
    # local: the arm modules load cma's and the simulator's stack; only the setting ids need them
    from thesis_repro.arm.baselines import TARGET_DEFAULTS
    from thesis_repro.arm.curriculum import CURRICULUM_DEFAULTS
    from thesis_repro.arm.learn import SOURCE_DEFAULTS
    from thesis_repro.arm.policy import RBFPolicy

    blocks = {
        "source": SOURCE_DEFAULTS,
        "target": TARGET_DEFAULTS,
        "curriculum": {**CURRICULUM_DEFAULTS, "condition": 0},
    }
    blocks["policy"] = {f.name: 0 for f in dataclasses.fields(RBFPolicy) if f.name != "W"}
    return {f"arm:{b}.{k}" for b, d in blocks.items() for k in d}


def setting_ids() -> set[str]:
    """Every setting that needs a row (see the module docstring)."""
    return hyperparams_ids() | scales_ids() | run_ids() | arm_ids()


def covers(pattern: str, setting: str) -> bool:
    """Whether ``pattern`` (a glob) names ``setting`` or a key above it."""
    return fnmatchcase(setting, pattern) or fnmatchcase(setting, pattern + ".*")


def uncovered(ids: Iterable[str] | None = None, table: Sequence[Mapping[str, Any]] | None = None) -> list[str]:
    """Setting ids no row covers."""
    patterns = [p for r in (table or rows()) for p in r.get("settings") or []]
    return sorted(i for i in (setting_ids() if ids is None else ids) if not any(covers(p, i) for p in patterns))


def unused_patterns(ids: Iterable[str] | None = None, table: Sequence[Mapping[str, Any]] | None = None) -> list[str]:
    """Row patterns that cover no setting (a typo, or a setting that was removed)."""
    ids = list(setting_ids() if ids is None else ids)
    return [p for r in (table or rows()) for p in r.get("settings") or [] if not any(covers(p, i) for i in ids)]


# ---------------------------------------------------------------------------------------- the page
def _cell(text: Any) -> str:
    """One table cell: its text on one line (runs of ASCII whitespace as one space; a no-break space stays)."""
    return re.sub(r"[ \t\r\n]+", " ", str(text or "")).strip(" ").replace("|", "\\|")


def rows_per_status(table: Sequence[Mapping[str, Any]] | None = None) -> Counter:
    """Rows per status."""
    return Counter(r["status"] for r in (table or rows()))


def _nowrap(text: Any) -> str:
    """A short cell kept to one line (no-break spaces), so the long columns of its table get the width."""
    return _cell(text).replace(" ", "\u00a0")


def _row(cells: Iterable[Any]) -> str:
    return "| " + " | ".join(_cell(c) for c in cells) + " |"


#: The page's two sections: the deviations first, then every row (folded, one block per group).
DEVIATIONS_HEADING = "Deviations from the thesis"
ALL_HEADING = "Every setting, thesis beside kit"


def render(table: Sequence[Mapping[str, Any]] | None = None) -> str:
    """The page as Markdown: a summary, the deviations (group, item, thesis, kit, why), then every row, one folded
    table per group (item, thesis, kit, status, why).

    >>> md = render([{"group": "G", "item": "a|b", "thesis": "t", "kit": "k", "status": "match"}])
    >>> "a\\\\|b" in md and "1 rows: 1 match, 0 stated choice, 0 deviation" in md and "No deviation" in md
    True
    """
    table = list(table or rows())
    n = rows_per_status(table)
    deviations = [r for r in table if r["status"] == "deviation"]
    lines = [
        f"# {TITLE}",
        "",
        "Every setting of the kit's protocol beside what the thesis says about it (quoted, with its section and "
        "line in the thesis text). **match**: the kit does what the thesis writes; **stated choice**: the thesis is "
        "silent and the kit's choice is given with its reason; **deviation**: the kit departs from the thesis, "
        "for the reason given. Generated from `data/protocol.yaml` by `thesis_repro.book.protocol`; "
        "`tests/test_protocol_table.py` fails when a setting of `hyperparams.yaml`, `scales.yaml` or the chapter 5 "
        "job defaults has no row.",
        "",
        f"{len(table)} rows: " + ", ".join(f"{n[s]} {s}" for s in STATUSES) + ".",
        "",
        f"## {DEVIATIONS_HEADING}",
        "",
    ]
    if deviations:
        lines += [
            f"The {len(deviations)} settings where the kit departs from the thesis, each with its reason:",
            "",
            "| Setting (group) | Thesis | Kit | Why |",
            "|---|---|---|---|",
            *(_row([f"{r['item']} ({r['group']})", r["thesis"], r["kit"], r.get("reason", "")]) for r in deviations),
            "",
        ]
    else:
        lines += ["No deviation: the kit does what the thesis writes, or chooses where the thesis is silent.", ""]
    lines += [f"## {ALL_HEADING}", "", "All rows, one folded table per group (click a group to open it).", ""]
    groups: dict[str, list[Mapping[str, Any]]] = {}
    for r in table:
        groups.setdefault(r["group"], []).append(r)
    for group, members in groups.items():
        k = Counter(r["status"] for r in members)
        tally = ", ".join(f"{k[s]} {s}" for s in STATUSES if k[s])
        lines += [
            f"<details><summary><strong>{html.escape(group)}</strong> ({len(members)} rows: {tally})</summary>",
            "",
            "| Item | Thesis | Kit | Status | Why |",
            "|---|---|---|---|---|",
        ]
        for r in members:
            status = f"**{r['status']}**" if r["status"] == "deviation" else _nowrap(r["status"])
            lines.append(_row([r["item"], r["thesis"], r["kit"], status, r.get("reason", "")]))
        lines += ["", "</details>", ""]
    return "\n".join(lines)


def protocols_at(scale: str = "small") -> dict[str, list[str]]:
    """Training protocol -> the chapter 3-4 items (figure ids of scales.yaml with training seeds and test
    rollouts) under it at ``scale``, each as ``"<id> (<seeds>×<rollouts>)"``, from the scale table.

    >>> "3.3 (1×2)" in protocols_at("smoke")["thesis"]
    True
    """
    out: dict[str, list[str]] = {}
    for fig in scales.figures():
        s = scales.figure_settings(fig, scale)
        if "train_seeds" in s and "test_rollouts" in s and not fig.startswith(("5.", "analysis-")):
            out.setdefault(str(s["protocol"]), []).append(f"{fig} ({s['train_seeds']}×{s['test_rollouts']})")
    return out


def _in_words(figs: list[str], tables: list[str]) -> str:
    """``"Figs 3.2 and 3.4 and Table 3.3"``; ``"no item"`` when both are empty."""

    def words(kind: str, ids: list[str]) -> str:
        if not ids:
            return ""
        head = kind if len(ids) == 1 else kind + "s"
        return f"{head} {ids[0]}" if len(ids) == 1 else f"{head} {', '.join(ids[:-1])} and {ids[-1]}"

    parts = [w for w in (words("Fig", figs), words("Table", tables)) if w]
    return " and ".join(parts) or "no item"


def items_with_seeds(seeds: int, scale: str = "small") -> str:
    """The chapter 3-4 items that train ``seeds`` training seeds at ``scale`` (from the scale table), in words:
    ``"Figs 3.2 and 3.4 and Table 3.3"`` (the book page ``book/runs.md`` quotes it; a test keeps them equal).

    >>> items_with_seeds(99)
    'no item'
    """
    figs, tables = [], []
    for fig in scales.figures():
        s = scales.figure_settings(fig, scale)
        if "test_rollouts" in s and s.get("train_seeds") == seeds and not fig.startswith(("5.", "analysis-")):
            (tables if fig.startswith("table-") else figs).append(fig.removeprefix("table-"))
    return _in_words(figs, tables)


def arm_items_with_seeds(seeds: int, scale: str = "small") -> str:
    """Chapter 5's CMA-ES items that run ``seeds`` seeds at ``scale`` (the ``seeds`` list of their blocks), in
    words (``book/runs.md`` quotes it; a test keeps them equal).

    >>> arm_items_with_seeds(99)
    'no item'
    """
    figs = [
        f for f in scales.figures() if f.startswith("5.") and len(scales.figure_settings(f, scale)["seeds"]) == seeds
    ]
    return _in_words(figs, [])


def switch_summary(scale: str = "small") -> str:
    """A section naming the chapter 3-4 items on each training protocol at ``scale``, each with its training
    seeds × test rollouts."""
    lines = [
        f"## Which items train under which protocol at `{scale}`",
        "",
        "From `scales.yaml` (each item: training seeds × test rollouts):",
        "",
    ]
    for protocol, figs in sorted(protocols_at(scale).items(), reverse=True):
        lines.append(f"- `{protocol}`: {', '.join(figs)}")
    return "\n".join([*lines, ""])


def write_page(root: str | Path) -> Path:
    """Write the page into a staged book folder ``root`` as ``protocol.md``; returns its path."""
    out = Path(root) / f"{PAGE}.md"
    out.write_text(render() + "\n" + switch_summary("small"))
    return out
