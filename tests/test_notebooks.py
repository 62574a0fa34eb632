"""Papermill smoke run of every notebook (seconds each); the book itself is tested in tests/test_book.py."""

from __future__ import annotations

import json

import pytest

from tests.test_book import shared_smoke_dirs
from thesis_repro.book import notebooks
from thesis_repro.core import paths

#: `make test` runs pytest in two processes (`-n 2 --dist loadgroup`): every test that shares the smoke
#: notebooks' session folder runs in the same one, so they execute once.
pytestmark = pytest.mark.xdist_group("smoke")

IDS = notebooks.notebook_ids(guides=True)  # the guide pages too (no claims, no verdict)


@pytest.mark.slow
@pytest.mark.parametrize("nid", IDS)
def test_notebook_smoke(nid, tmp_path_factory, monkeypatch):
    for k, v in shared_smoke_dirs(tmp_path_factory).items():
        monkeypatch.setenv(k, v)
    # the session's book build may already have executed it with today's sources (same execution key)
    out = notebooks.executed_path(nid, "smoke")
    if not notebooks.is_current(nid, "smoke"):
        out = notebooks.execute_notebook(nid, "smoke", log=False)
    nb = json.loads(out.read_text())
    errors = [o for c in nb["cells"] for o in c.get("outputs", []) if o.get("output_type") == "error"]
    assert not errors
    tags = [c["metadata"].get("tags", []) for c in nb["cells"]]
    assert any("parameters" in t for t in tags), "notebook needs a cell tagged 'parameters'"
    assert any("injected-parameters" in t for t in tags)
    text = out.read_text()
    assert "reproduced" in text.lower(), "notebooks must label the kit's own numbers 'reproduced'"
    # the execution cache: stamped key and the kit modules the kernel imported (the listing cell is removed)
    meta = nb["metadata"]["thesis_repro"]
    assert notebooks.is_current(nid, "smoke")
    assert "thesis_repro/book/builder.py" not in meta["modules"]
    if not notebooks.is_guide(nid):  # a guide writes no verdict
        assert "thesis_repro/claims/report.py" in meta["modules"]
    assert all(notebooks.DEPS_TAG not in t for t in tags)
    assert meta["execution_key"] == notebooks.execution_key(nid, "smoke", None, meta["modules"])
    assert meta["execution_key"] != notebooks.execution_key(nid, "smoke", None, meta["modules"][:-1])


def test_the_smoke_group_stays_on_one_worker(request):
    """Under `make test` (pytest-xdist, ``--dist loadgroup``) a test of the smoke group carries its group in its node
    id, which is what keeps the group on one worker: the smoke notebooks then execute once, for this module and
    the book. pytest 9 ignores the id xdist 3.8 rewrites (constraints.txt pins pytest 8)."""
    if not getattr(request.config.option, "loadgroup", False):
        pytest.skip("not under pytest-xdist --dist loadgroup")
    assert request.node.nodeid.endswith("@smoke"), request.node.nodeid


def test_notebook_ids_and_book_order():
    assert all(notebooks.check_notebook(n) == n for n in IDS)
    assert IDS == sorted(IDS, key=notebooks.sort_key)
    assert notebooks.sort_key("4.7") < notebooks.sort_key("table-4.1") < notebooks.sort_key("analysis-4-kl")
    assert notebooks.sort_key("analysis-4-kl") < notebooks.sort_key("5.3")
    assert notebooks.page_chapter("analysis-4-kl") == "4" and notebooks.page_chapter("table-3.7") == "3"
    assert paths.notebook("analysis-4-kl").name == "analysis-4-kl.py"
    assert notebooks.executed_path("table-3.4", "small").name == "table-3.4.ipynb"


def test_unknown_notebook_is_an_error():
    with pytest.raises(ValueError, match=r"unknown figure '9.99'; valid figures are: '3.2'"):
        notebooks.check_notebook("9.99")
    with pytest.raises(ValueError, match="figure id must be a string"):
        notebooks.check_notebook(3.3)
    assert paths.notebook("3.3").name == "fig-3.3.py"
    assert notebooks.check_notebook("fig-3.3") == "3.3"


def test_execution_key_tracks_source_scale_and_parameters():
    k = notebooks.execution_key("3.3", "smoke")
    assert k == notebooks.execution_key("3.3", "smoke")
    assert k != notebooks.execution_key("3.3", "small")
    assert k != notebooks.execution_key("3.3", "smoke", {"SELECTION": "mean"})
    assert k != notebooks.execution_key("3.2", "smoke")
    assert not notebooks.is_current("3.3", "smoke")  # nothing executed in this test's build folder
