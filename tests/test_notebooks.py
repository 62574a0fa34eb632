"""Papermill smoke run of every notebook, then the book build at smoke scale (seconds each)."""

from __future__ import annotations

import json

import pytest

from thesis_repro import book, notebooks, paths

IDS = notebooks.notebook_ids()


@pytest.fixture(scope="module")
def smoke_env(tmp_path_factory):
    """One run cache and build folder shared by all notebook smoke runs (they share jobs)."""
    return {
        "THESIS_REPRO_DATA": str(tmp_path_factory.mktemp("nb-runs")),
        "THESIS_REPRO_BUILD": str(tmp_path_factory.mktemp("nb-build")),
    }


@pytest.mark.slow
@pytest.mark.parametrize("nid", IDS)
def test_notebook_smoke(nid, smoke_env, monkeypatch):
    for k, v in smoke_env.items():
        monkeypatch.setenv(k, v)
    out = notebooks.execute(nid, "smoke", log=False)
    nb = json.loads(out.read_text())
    errors = [o for c in nb["cells"] for o in c.get("outputs", []) if o.get("output_type") == "error"]
    assert not errors
    tags = [c["metadata"].get("tags", []) for c in nb["cells"]]
    assert any("parameters" in t for t in tags), "notebook needs a cell tagged 'parameters'"
    assert any("injected-parameters" in t for t in tags)
    text = out.read_text()
    assert "reproduced" in text.lower(), "notebooks must label the kit's own numbers 'reproduced'"


@pytest.mark.slow
def test_book_builds_at_smoke(smoke_env, monkeypatch, tmp_path):
    for k, v in smoke_env.items():
        monkeypatch.setenv(k, v)
    index = book.build("smoke", reuse=True, root=tmp_path / "book")
    assert index.exists()
    html = (index.parent / "intro.html").read_text()
    assert "Reproducing" in html
    for nid in IDS:
        page = tmp_path / "book" / "_build" / "html" / "executed" / f"{notebooks.executed_path(nid, 's').stem}.html"
        assert page.exists(), page


def test_unknown_notebook_is_an_error():
    with pytest.raises(ValueError, match="unknown figure"):
        notebooks.check_notebook("9.99")
    assert paths.notebook("3.3").name == "fig-3.3.py"
