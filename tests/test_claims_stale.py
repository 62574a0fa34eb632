"""Saved page numbers carry the kit's stamp (code, config, ``data/thesis/``): numbers written by other kit code
are judged as before but reported stale, per row, in ``claims --json`` and as one line on stderr."""

from __future__ import annotations

import json

import pytest

from thesis_repro.claims import cli, ledger, registry, report, store
from thesis_repro.claims import synthetic as S
from thesis_repro.core import paths, stamps

SCALE = "small"


@pytest.fixture
def saved(tmp_path, monkeypatch):
    """Fig 3.3's numbers saved by this kit in a private build folder; returns the data file."""
    for var in ("THESIS_REPRO_BUILD", "THESIS_REPRO_DATA", "THESIS_REPRO_REFERENCE", "THESIS_REPRO_PUBLISHED_BUILD"):
        monkeypatch.setenv(var, str(tmp_path / var.lower()))
    s = registry.spec("3.3-negative-correlation")
    return store.save_page(s.page, SCALE, S.frames_for(s.rule["measure"], 3, 0), {"scale": SCALE})


def _restamp(path, stamp):
    blob = json.loads(path.read_text())
    blob["kit"] = stamp
    path.write_text(json.dumps(blob))


def test_numbers_saved_by_this_kit_are_fresh(saved):
    blob = json.loads(saved.read_text())
    assert blob["kit"] == stamps.code_stamp("fig-3.3", blob["kit_modules"])
    ledger_py = "thesis_repro/claims/ledger.py"
    assert blob["kit_modules"][ledger_py] == stamps.module_hash(paths.ROOT / ledger_py)
    row = ledger.judge(registry.spec("3.3-negative-correlation"), SCALE, with_null=False)
    assert row.stale == [] and row.as_dict()["stale_pages"] == []


def test_numbers_saved_by_other_kit_code_are_judged_but_reported_stale(saved, capsys):
    before = ledger.judge(registry.spec("3.3-negative-correlation"), SCALE, with_null=False)
    _restamp(saved, "0" * 12)
    row = ledger.judge(registry.spec("3.3-negative-correlation"), SCALE, with_null=False)
    assert (row.status, row.statistic) == (before.status, before.statistic)  # the same verdict, flagged
    assert row.stale == ["fig-3.3"]
    # a claim derived from stale claims is stale too
    assert ledger.judge(registry.spec("3.3-not-valid-metric"), SCALE, with_null=False).stale == ["fig-3.3"]

    assert cli.main(["--scale", SCALE, "--json", "--no-null", "--ids", "3.3-negative-correlation"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["stale_pages"] == ["fig-3.3"]
    assert err.count("\n") == 1 and err.startswith("stale: the saved numbers of fig-3.3 ")
    assert "`make figure-3.3 SCALE=small`" in err


def test_numbers_saved_before_stamps_existed_are_stale(saved):
    blob = json.loads(saved.read_text())
    del blob["kit"]
    saved.write_text(json.dumps(blob))
    assert ledger.judge(registry.spec("3.3-negative-correlation"), SCALE, with_null=False).stale == ["fig-3.3"]


def test_analysis_verdicts_saved_by_other_kit_code_are_reported_stale(tmp_path, monkeypatch):
    """Claims judged by a page's own rule (the Eq 4.11 analysis) read its rule's saved verdicts
    (``<page>.rule.json``): stamped the same way."""
    monkeypatch.setenv("THESIS_REPRO_BUILD", str(tmp_path / "build"))
    monkeypatch.setenv("THESIS_REPRO_PUBLISHED_BUILD", str(tmp_path / "published"))
    s = next(x for x in registry.specs() if "page_verdict" in x.rule)
    n = int(s.rule["page_verdict"]) + 1
    path = report.save_rule(s.page, SCALE, [report.Verdict(s.page, "c", report.REPRODUCES, "e")] * n)
    assert ledger.judge(s, SCALE, with_null=False).stale == []
    _restamp(path, "0" * 12)
    row = ledger.judge(s, SCALE, with_null=False)
    assert row.status == report.REPRODUCES and row.stale == [s.page]


def test_the_stamp_covers_what_the_page_imported_its_config_and_notebook_and_nothing_else(tmp_path, monkeypatch):
    """The same dependencies as the book's up-to-date check: a page the book keeps is never called stale."""
    pkg, nbs, thesis = tmp_path / "thesis_repro", tmp_path / "notebooks", tmp_path / "data" / "thesis"
    for d in (pkg, nbs, thesis):
        d.mkdir(parents=True)
    files = {
        "used": pkg / "used.py",
        "unused": pkg / "unused.py",
        "config": pkg / "scales.yaml",
        "thesis": thesis / "claims.yaml",
        "own notebook": nbs / "table-3.4.py",
        "other notebook": nbs / "table-3.3.py",
    }
    for name, f in files.items():
        f.write_text(f"NAME = {name!r}\nx = 1\n")  # each file its own content (a module's identity)
    for name, value in (("ROOT", tmp_path), ("PACKAGE", pkg), ("NOTEBOOKS", nbs), ("THESIS_DATA", thesis)):
        monkeypatch.setattr(paths, name, value)

    modules = stamps.kit_modules(["thesis_repro/used.py"])
    blob = {"kit": stamps.code_stamp("table-3.4", modules), "kit_modules": modules}
    changed = {}
    for name, f in files.items():
        f.write_text(f"NAME = {name!r}\nx = 2\n")
        changed[name] = stamps.is_stale("table-3.4", blob)
        f.write_text(f"NAME = {name!r}\nx = 1\n")
    assert changed == {
        "used": True,
        "unused": False,
        "config": True,
        "thesis": True,
        "own notebook": True,
        "other notebook": False,
    }
    # saved without its module list (older numbers): every module counts
    old = {"kit": stamps.code_stamp("table-3.4", None)}
    files["unused"].write_text("NAME = 'unused'\nx = 2\n")
    assert stamps.is_stale("table-3.4", old) is True


def _kit(tmp_path, monkeypatch):
    """A kit of its own in ``tmp_path``: a numeric module, a module importing it, a page's notebook."""
    pkg, nbs, thesis = tmp_path / "thesis_repro", tmp_path / "notebooks", tmp_path / "data" / "thesis"
    for d in (pkg / "maths", nbs, thesis):
        d.mkdir(parents=True)
    (pkg / "maths" / "auc.py").write_text('"""Area under a curve."""\n\n\ndef auc(y):\n    return sum(y) / len(y)\n')
    (pkg / "page.py").write_text("from thesis_repro.maths.auc import auc\n\nVALUE = auc([1, 2])\n")
    (nbs / "table-3.4.py").write_text("# %% [markdown]\n# Table 3.4\n# %%\nfrom thesis_repro.page import VALUE\n")
    for name, value in (("ROOT", tmp_path), ("PACKAGE", pkg), ("NOTEBOOKS", nbs), ("THESIS_DATA", thesis)):
        monkeypatch.setattr(paths, name, value)
    modules = stamps.kit_modules(["thesis_repro/maths/auc.py", "thesis_repro/page.py"])
    return pkg, {"kit": stamps.code_stamp("table-3.4", modules), "kit_modules": modules}


def test_a_move_a_rename_or_a_docstring_keeps_the_stamp_and_a_numeric_line_does_not(tmp_path, monkeypatch):
    """Numbers depend on what the code computes, not on where a module lives or on its prose: the shipped
    claims snapshot stays fresh across a module move or rename and a docstring or comment edit."""
    pkg, blob = _kit(tmp_path, monkeypatch)
    auc, page = pkg / "maths" / "auc.py", pkg / "page.py"
    assert not stamps.is_stale("table-3.4", blob)

    (pkg / "metrics").mkdir()
    moved = pkg / "metrics" / "area.py"  # moved to another folder and renamed; its importer follows
    auc.rename(moved)
    page.write_text("from thesis_repro.metrics.area import auc  # moved\n\nVALUE = auc([1, 2])\n")
    assert not stamps.is_stale("table-3.4", blob)

    moved.write_text('"""The mean height of a curve: its area over its length."""\n\n\ndef auc(y):\n'
                     '    """Area under ``y``."""\n    return sum(y) / len(y)  # exact\n')  # fmt: skip
    (tmp_path / "notebooks" / "table-3.4.py").write_text(
        "# %% [markdown]\n# Table 3.4: reworded\n# %%\nfrom thesis_repro.page import VALUE\n"
    )
    assert not stamps.is_stale("table-3.4", blob)

    moved.write_text("def auc(y):\n    return sum(y) / max(len(y), 1)\n")  # a numeric line
    assert stamps.is_stale("table-3.4", blob)
    moved.write_text("def auc(y):\n    return sum(y) / len(y)\n")
    assert not stamps.is_stale("table-3.4", blob)
    page.write_text("from thesis_repro.metrics.area import auc\n\nVALUE = auc([1, 3])\n")
    assert stamps.is_stale("table-3.4", blob)


def test_a_ledger_without_saved_pages_says_how_to_compute_them(tmp_path, monkeypatch, capsys):
    """A fresh clone has no saved page numbers at small: the JSON marks the claims *not computed* and stderr
    names the command that executes the pages from the shipped runs (one line, no training)."""
    for var in ("THESIS_REPRO_BUILD", "THESIS_REPRO_DATA", "THESIS_REPRO_REFERENCE", "THESIS_REPRO_PUBLISHED_BUILD"):
        monkeypatch.setenv(var, str(tmp_path / var.lower()))
    ids = ["3.3-negative-correlation", "4.1-harder-settings"]
    assert cli.main(["--scale", SCALE, "--json", "--no-null", "--ids", *ids]) == 0
    out, err = capsys.readouterr()
    assert {c["verdict"] for c in json.loads(out)["claims"]} == {"not computed"}
    assert err.count("\n") == 1 and err.startswith("not computed: 2 claim(s) whose pages have not run at small")
    assert "(fig-3.3, fig-4.1)" in err and "`make book SCALE=small`" in err


def test_a_ledger_with_every_page_saved_prints_no_hint(saved, capsys):
    assert cli.main(["--scale", SCALE, "--no-null", "--ids", "3.3-negative-correlation"]) == 0
    assert capsys.readouterr().err == ""


def test_computed_hashes_are_kept_content_addressed_where_thesis_repro_stamps_says(tmp_path, monkeypatch):
    monkeypatch.setenv(stamps.STAMPS_ENV, str(tmp_path / "shared"))
    calls = []

    def compute() -> str:
        calls.append(1)
        return "0123456789abcdef"

    assert stamps._memo("module", b"x = 1\n", compute) == "0123456789abcdef"
    (entry,) = (tmp_path / "shared").rglob("module-*")
    assert stamps._memo("module", b"x = 1\n", compute) == "0123456789abcdef" and len(calls) == 1  # read back
    entry.write_text("not a hash")  # a corrupt entry is recomputed and rewritten
    assert stamps._memo("module", b"x = 1\n", compute) == "0123456789abcdef" and len(calls) == 2
    assert entry.read_text() == "0123456789abcdef"
    monkeypatch.delenv(stamps.STAMPS_ENV)  # unset: the build folder's own .stamps
    stamps._memo("module", b"x = 1\n", compute)
    assert list((paths.build_dir(".stamps")).rglob("module-*"))
    # in a notebook's kernel (its build folder a staging one): the finished build's, shared by every page
    monkeypatch.setenv(paths.PUBLISHED_ENV, str(tmp_path / "finished"))
    assert stamps._memo_dir().parent == tmp_path / "finished" / ".stamps"
