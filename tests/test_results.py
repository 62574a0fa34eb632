"""RESULTS.md and the README's generated blocks (``python -m thesis_repro results``): current with the shipped
claims snapshot, and worded from the ledger's JSON whichever keys it carries."""

from __future__ import annotations

import os

import pytest

from thesis_repro.claims import results
from thesis_repro.cli.commands import main
from thesis_repro.core import paths

CLAIM = {
    "id": "3.3-pareto",
    "page": "fig-3.3",
    "thesis_lines": [547],
    "claim": "There is a clear trade-off between training performance and generalisation across all the variants "
    "we ran",
    "verdict": "does not reproduce",
    "statistic": {"k": 0, "n": 2, "value": 0.0, "ci": [0.0, 0.0], "undecided": 0},
}


@pytest.mark.xdist_group("snapshot-ledger")  # conftest.SNAPSHOT_LEDGER_GROUP: one judging for all
def test_results_md_and_readme_blocks_are_current_with_the_shipped_snapshot(snapshot_ledger, monkeypatch):
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(paths.ROOT / "data" / "reference"))  # the real shipped layer
    files = results.generated_files("small", rows=snapshot_ledger)
    stale = [p.name for p, text in files.items() if not p.exists() or p.read_text() != text]
    assert not stale, f"out of date with the shipped claims snapshot: {', '.join(stale)}; run `make results`"


def test_the_fallbacks_word_todays_ledger_keys():
    row = results.claims_table([CLAIM]).splitlines()[2]
    cut = "There is a clear trade-off between training performance and generalisation across all ..."
    assert row.startswith(f"| `3.3-pareto` | l. 547 | {cut} |")
    # ... thesis, ours, verdict, the thesis's effect, v2's verdict (none given: the verdict), fresh seeds, thesis's
    # budget
    assert row.endswith(
        "| - | 0/2 units yes, yes-share [0.00, 0.00] | **does not reproduce** | - | does not reproduce | - | - |"
    )
    assert len(results.short(CLAIM).removesuffix(" ...").split()) == results.SHORT_WORDS


def test_the_ledgers_new_keys_win_over_the_fallbacks():
    new = {**CLAIM, "short": "Training return trades off against generalisation", "thesis_value": "r < 0"}
    new |= {"ours": "r = 0.71 [0.02, 1.39]", "label": "contradicted", "v2_verdict": "does not reproduce"}
    new |= {"thesis_effect": {"excluded": True, "ours_side": "larger"}}
    row = results.claims_table([new]).splitlines()[2]
    assert "| Training return trades off against generalisation | r < 0 | r = 0.71 [0.02, 1.39] |" in row
    # no fresh seeds, no thesis-budget verdict
    assert row.endswith("**contradicted** | excluded (ours larger) | does not reproduce | - | - |")
    assert results.v2_counts([new]) == [("does not reproduce", 1)]
    block = results.readme_results({"claims": [new, {**CLAIM, "id": "x", "verdict": "inconclusive"}]}, "small")
    assert "| contradicted | 1 | 0 |" in block and "| inconclusive | 1 | 1 |" in block
    assert "| does not reproduce | 0 | 1 |" in block  # v2's count of a label v3 no longer gives
    line = "- `3.3-pareto` (l. 547): Training return trades off against generalisation; ours: r = 0.71 [0.02, 1.39]"
    assert line + "\n" in block
    assert "`x`" not in block  # only the claims that do not reproduce get a line


def test_results_md_counts_every_claim_once_and_groups_by_chapter():
    ledger = {"claims": [CLAIM, {**CLAIM, "id": "5.6-curriculum", "page": "fig-5.6", "verdict": "reproduces"}]}
    ledger |= {"beyond_the_thesis": [{**CLAIM, "id": "4.1-kl-exact", "page": "fig-4.1"}]}
    text = results.results_md(ledger, "small")
    assert "**2 distinct thesis claims (design ):** does not reproduce 1, reproduces 1." in text
    assert "Under design v2 (the registered analysis of seeds 0-5, kept beside it): does not reproduce 1, " in text
    assert text.index("## Chapter 3") < text.index("## Chapter 5") < text.index("## Beyond the thesis")
    assert text.count("`3.3-pareto`") == 1 and "`4.1-kl-exact`" in text


def test_a_readme_without_its_markers_is_one_error_line(tmp_path, monkeypatch, capsys):
    with pytest.raises(ValueError, match="README.md needs one <!-- results:start --> ... <!-- results:end --> block"):
        results.replace_block("no markers", results.RESULTS_MARKERS, "x")
    monkeypatch.setattr(results, "generated_files", lambda scale: results.render_results({}, scale, "no markers", ""))
    assert main(["results", "--check"]) == 2
    assert capsys.readouterr().err.strip().startswith("error: README.md needs one <!-- results:start -->")


def test_an_unknown_option_is_one_error_line(capsys):
    assert main(["results", "--scale", "full"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: unrecognized arguments: --scale full") and len(err.splitlines()) == 1


def test_the_ledger_is_judged_from_the_snapshot_not_from_this_builds_pages(monkeypatch, tmp_path):
    monkeypatch.setenv("THESIS_REPRO_BUILD", str(tmp_path))
    monkeypatch.setenv(paths.PUBLISHED_ENV, str(tmp_path))
    (tmp_path / "small" / "figures").mkdir(parents=True)
    (tmp_path / "small" / "figures" / "fig-3.3.data.json").write_text("{}")
    with results.snapshot_only():
        assert not paths.figures_dir("small").exists() and paths.PUBLISHED_ENV not in os.environ
    assert paths.figures_dir("small") == tmp_path / "small" / "figures"
    assert os.environ[paths.PUBLISHED_ENV] == str(tmp_path)
