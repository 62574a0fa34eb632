"""The protocol page ("One table of every deviation"): one row per setting, no setting without a row."""

from __future__ import annotations

import re

import pytest
import yaml

from thesis_repro.book import builder as book
from thesis_repro.book import protocol
from thesis_repro.core import paths

THESIS = paths.ROOT.parent / "shared" / "thesis.txt"


def _lines_cited(text: str) -> set[int]:
    """Line numbers a thesis cell cites: "line 12", "lines 3-5", "lines 1243, 1261"."""
    out: set[int] = set()
    for m in re.finditer(r"\blines? ((?:\d+(?:\s*[-–]\s*\d+)?(?:,\s*)?)+)", text):
        for part in m.group(1).split(","):
            if not part.strip():
                continue
            a, _, b = part.replace("–", "-").partition("-")
            out |= set(range(int(a), int(b or a) + 1))
    return out


def test_every_learner_and_scale_setting_has_a_row():
    missing = protocol.uncovered()
    assert not missing, (
        f"{len(missing)} setting(s) of hyperparams.yaml / scales.yaml / RUN_DEFAULTS / the chapter 5 job defaults have "
        f"no row in data/protocol.yaml (add them to a row's `settings`): {missing}"
    )
    # the id space really contains what the page promises to cover
    ids = protocol.setting_ids()
    for must in ("hp:ppo:sb3.vf_coef", "hp:ppo-arpl:arpl.epsilon", "hp:ppo:lr_schedule", "hp:ppo:net_arch.pi",
                 "scales:defaults/test_rollouts", "scales:5.4/source.n_tasks", "run:wind", "arm:curriculum.sigma",
                 "arm:policy.kp_scale"):  # fmt: skip
        assert must in ids


def test_a_new_setting_without_a_row_fails():
    hp = yaml.safe_load((paths.CONFIG / "hyperparams.yaml").read_text())
    hp["ppo"]["sb3"]["brand_new"] = 1
    hp["ppo-arpl"]["arpl"]["brand_new"] = 1
    assert protocol.uncovered(protocol.hyperparams_ids(hp)) == ["hp:ppo-arpl:arpl.brand_new", "hp:ppo:sb3.brand_new"]
    sc = yaml.safe_load((paths.CONFIG / "scales.yaml").read_text())
    sc["defaults"]["small"]["brand_new"] = 1
    sc["figures"]["5.4"]["small"]["source"]["brand_new"] = 1
    assert protocol.uncovered(protocol.scales_ids(sc)) == ["scales:5.4/source.brand_new", "scales:defaults/brand_new"]


def test_no_row_names_a_setting_that_does_not_exist():
    assert protocol.unused_patterns() == []


def test_rows_are_complete_and_nothing_is_unknown():
    rows = protocol.rows()
    assert len(rows) >= 60
    for r in rows:
        assert r["status"] in protocol.STATUSES
        assert "unknown" not in " ".join(str(v) for v in r.values()).lower(), r["item"]
        if r["status"] != "match":
            assert r.get("reason"), r["item"]
        # the thesis's words come with their line, or the row says the thesis is silent
        assert _lines_cited(r["thesis"]) or "silent" in r["thesis"], r["item"]
    n = protocol.rows_per_status()
    assert sum(n.values()) == len(rows) and all(n[s] > 0 for s in protocol.STATUSES)


def test_every_appendix_a_hyperparameter_has_a_row():
    if not THESIS.exists():
        pytest.skip("thesis text not available")
    lines = THESIS.read_text().splitlines()
    bullets = {i for i in range(1231, 1302) if lines[i - 1].lstrip().startswith("- ") and ":" in lines[i - 1]}
    cited = set().union(*(_lines_cited(r["thesis"]) for r in protocol.rows()))
    missing = sorted(bullets - cited)
    assert not missing, [lines[i - 1].strip() for i in missing]


def test_cited_lines_exist_in_the_thesis():
    if not THESIS.exists():
        pytest.skip("thesis text not available")
    n = len(THESIS.read_text().splitlines())
    for r in protocol.rows():
        assert all(1 <= i <= n for i in _lines_cited(r["thesis"])), r["item"]


def test_page_renders_every_row_and_joins_the_book_contents(tmp_path):
    md = protocol.render()
    assert md.startswith(f"# {protocol.TITLE}")
    for r in protocol.rows():
        assert protocol._cell(r["item"]) in md
    n = protocol.rows_per_status()
    assert f"{len(protocol.rows())} rows: {n['match']} match, {n['stated choice']} stated choice" in md
    head = md.partition(f"## {protocol.ALL_HEADING}")[0]
    for line in md.splitlines():
        if line.startswith("| ") and not line.startswith("|---"):
            cells = 4 if line in head else 5  # the deviations: the setting with its group in one cell
            assert len(re.findall(r"(?<!\\)\|", line)) == cells + 1, line  # no unescaped pipe inside a cell
    (tmp_path / "chapter-3.md").write_text("# Chapter 3\n")
    protocol.write_page(tmp_path)
    toc = yaml.safe_load(book.write_toc([], tmp_path).read_text())
    assert toc["chapters"][-1] == {"file": "protocol"}


def test_the_page_names_each_item_s_protocol_at_small():
    """The protocol page lists every chapter 3-4 item once, under the protocol scales.yaml gives it."""
    from thesis_repro.core import scales

    listed = protocol.protocols_at("small")
    items = [i.split(" (")[0] for figs in listed.values() for i in figs]
    assert len(items) == len(set(items)) and {"3.3", "table-3.6", "4.1"} <= set(items)
    for name, figs in listed.items():
        for item in figs:
            s = scales.figure_settings(item.split(" (")[0], "small")
            assert s["protocol"] == name and item.endswith(f"({s['train_seeds']}×{s['test_rollouts']})")
    page = protocol.switch_summary("small")
    assert all(f"`{name}`: " in page for name in listed)
