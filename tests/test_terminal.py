"""Output that fits the terminal: at ``COLUMNS=80`` every line of ``list``, ``runs`` and ``claims`` fits in 80
columns (``score``'s: ``tests/test_compare.py``), the full text stays behind ``--verbose`` / ``--json``, and every
usage error is one line."""

from __future__ import annotations

import io
from pathlib import Path

import pytest

from thesis_repro.cli.commands import main
from thesis_repro.core import terminal

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def shipped(shipped, monkeypatch):
    """conftest's real shipped layer, at 80 columns."""
    monkeypatch.setenv("COLUMNS", "80")
    return shipped


def _fits(text: str, cols: int = 80) -> bool:
    return all(len(line) <= cols for line in text.splitlines())


def test_width_follows_columns(monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    assert terminal.width() == 80
    monkeypatch.setenv("COLUMNS", "10")
    assert terminal.width() == terminal.MIN_COLUMNS
    monkeypatch.delenv("COLUMNS")  # output captured, not a terminal: lines stay whole
    assert terminal.width() == terminal.UNLIMITED and terminal.cut("x" * 300) == "x" * 300


def test_progress_line_has_an_eta_and_fits():
    out = io.StringIO()
    bar = terminal.Progress("train ppo on Hopper", 1000, unit="steps", stream=out)
    for done in (0, 100, 500, 1000):
        bar.update(done)
    bar.close()
    lines = out.getvalue().splitlines()
    assert "100/1,000 steps (10%)" in lines[1] and "ETA" in lines[1] and lines[-1].endswith("done")
    assert _fits(out.getvalue())


def test_list_names_every_figure_with_its_title_in_80_columns(monkeypatch, capsys):
    monkeypatch.setenv("COLUMNS", "80")
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert _fits(out) and "table-3.4" in out and "Generalisation of the basic learners" in out
    assert "guide-score-agent" in out


def test_runs_summarises_and_lists_every_run_on_request(shipped, capsys):
    assert main(["runs", "table-3.3", "--scale", "small"]) == 0
    out = capsys.readouterr().out
    assert _fits(out) and len(out.splitlines()) < 10
    assert "train          30       0           0" in out and "evaluate      120" in out
    assert main(["runs", "table-3.3", "--scale", "small", "--verbose"]) == 0
    full = capsys.readouterr().out
    rows = [line.split() for line in full.splitlines() if line.startswith(("train ", "evaluate "))]
    assert len(rows) == 150
    for kind, _label, key, _state, path in rows:  # the key is the one in the entry's folder name
        assert path.endswith(f"__{key}"), (kind, key, path)


def test_claims_lines_wrap_at_80_columns_and_verbose_gives_them_as_they_are(shipped, capsys):
    ids = ["--ids", "3.3-pareto", "3.2-overfitting"]
    assert main(["claims", "--scale", "small", *ids]) == 0
    cut = capsys.readouterr()
    assert _fits(cut.out) and _fits(cut.err) and "3.3-pareto" in cut.out and "3.2-overfitting" in cut.out
    assert main(["claims", "--scale", "small", "--verbose", *ids]) == 0
    assert not _fits(capsys.readouterr().out)  # the full text


@pytest.mark.parametrize(
    "argv",
    [
        ["claims", "--scale", "Small"],
        ["runs", "--bogus"],
        ["train"],
        ["score", "m.zip"],
        ["enjoy", "ppo", "Hopper", "--seed", "-1"],
        ["list", "extra"],
    ],
)
def test_every_usage_error_is_one_line(argv, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and err.startswith("error: ") and "--help" in err, err


def test_a_claims_usage_error_is_one_line(capsys):
    assert main(["claims", "--scale", "Small"]) == 2
    err = capsys.readouterr().err
    assert err.splitlines() == [
        "error: argument --scale: invalid choice: 'Small' (choose from 'smoke', 'small', 'full') "
        "(see `python -m thesis_repro claims --help`)"
    ]
