"""The book as a reader sees it: built at smoke scale and opened page by page in headless Chromium.

The browser part needs Debian's ``chromium``, which the bootstrap installs (``make chromium``, a step of
``make test``); without it the test skips with the reason. The smoke runs and executed notebooks live
in one session folder shared with ``tests/test_notebooks.py`` (whichever runs first executes them).
"""

from __future__ import annotations

import atexit
import functools
import json
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path
from urllib.parse import unquote, urlparse

import pytest
import yaml

from thesis_repro import book, figures, notebooks, paths
from thesis_repro.claims import report

#: `make test` runs pytest in two processes (`-n 2 --dist loadgroup`): every test that shares the smoke
#: notebooks' session folder runs in the same one, so they execute once.
pytestmark = pytest.mark.xdist_group("smoke")

THESIS_TXT = Path(os.environ.get("THESIS_TXT", "/work/shared/thesis.txt"))
PROGRESS = re.compile(r"it/s\]|s/it\]|\d%\|")
STATUS_TITLE = re.compile(
    r'<p class="admonition-title">(' + "|".join(re.escape(s.capitalize()) for s in report.STATUSES) + r")(:| ·)"
)


def shared_smoke_dirs(tmp_path_factory) -> dict[str, str]:
    """Run cache and build folder shared by every smoke notebook run of this pytest session."""
    base = tmp_path_factory.getbasetemp() / "smoke-shared"
    (base / "runs").mkdir(parents=True, exist_ok=True)
    (base / "build").mkdir(parents=True, exist_ok=True)
    return {"THESIS_REPRO_DATA": str(base / "runs"), "THESIS_REPRO_BUILD": str(base / "build")}


def chromium() -> str:
    """Path of a headless-capable Chromium (the bootstrap installs Debian's package: `make test` depends on
    ``make chromium``); skips with the reason when there is none. No test installs anything."""
    for name in ("chromium", "chromium-browser"):
        if shutil.which(name):
            return shutil.which(name)
    pytest.skip("browser test needs 'chromium': `make chromium` (part of `make test`) installs it with apt-get")


@functools.cache
def _profile() -> Path:
    """Chromium's profile folder: made on first use, removed when the test session ends (no temp litter)."""
    path = Path(tempfile.mkdtemp(prefix="thesis-repro-chromium-"))
    atexit.register(shutil.rmtree, path, ignore_errors=True)
    return path


def _browser_args(exe: str) -> list[str]:
    # own profile dir: no dependence on a writable $HOME (CI); no first-run, crash-reporter or GPU work
    return [
        exe,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--hide-scrollbars",
        "--no-first-run",
        "--no-default-browser-check",
        "--disable-breakpad",
        "--disable-crash-reporter",
        f"--user-data-dir={_profile()}",
    ]


def run_browser(exe: str, *args: str, timeout: float = 90, attempts: int = 2) -> subprocess.CompletedProcess:
    """Run headless Chromium; a crash or time-out is retried once, then fails with Chromium's own stderr."""
    for attempt in range(attempts):
        try:
            out = subprocess.run([*_browser_args(exe), *args], capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired as err:
            problem = f"timed out after {timeout} s: {str(err.stderr or '')[-800:]}"
        else:
            if out.returncode == 0:
                return out
            problem = f"exit code {out.returncode}: {out.stderr[-800:]}"
        if attempt == attempts - 1:
            pytest.fail(f"chromium {' '.join(args)} failed: {problem}")
    raise AssertionError("unreachable")  # pragma: no cover


def dump_dom(exe: str, page: Path) -> str:
    """The page's DOM after Chromium has loaded it and run its scripts."""
    return run_browser(exe, "--dump-dom", page.as_uri()).stdout


def local_refs(html: str, attr: str) -> list[str]:
    """Values of ``attr`` (``src``/``href``) that point into the book (no scheme, not a pure fragment).

    >>> local_refs('<a href="x.html#a"></a><a href="https://y"></a><a href="#top"></a>', "href")
    ['x.html']
    """
    out = []
    for value in re.findall(rf'\b{attr}="([^"]*)"', html):
        parsed = urlparse(value)
        if parsed.scheme or parsed.netloc or not parsed.path:
            continue
        out.append(unquote(parsed.path))
    return out


@pytest.fixture(scope="module")
def smoke_book(tmp_path_factory) -> Path:
    """The smoke book, built from the session's shared smoke runs (executing only what is missing)."""
    with pytest.MonkeyPatch.context() as mp:
        for k, v in shared_smoke_dirs(tmp_path_factory).items():
            mp.setenv(k, v)
        root = tmp_path_factory.mktemp("smoke-book")
        index = book.build("smoke", root=root)
    return index.parent


# --- claims data and the builder's pure functions (fast) ---------------------------------------------


def test_every_notebook_has_its_thesis_claims():
    entries = book.claims()
    for nid in notebooks.notebook_ids():
        page = notebooks.page_id(nid)
        assert page in entries, f"add {page} to data/thesis/claims.yaml"
        assert entries[page]["claims"], page


def _cited_text(lines: list[str], numbers: list[int]) -> str:
    """The cited thesis lines as one text, a word hyphenated across a cited line's end rejoined ("de-" + "grades").

    >>> _cited_text(["models de-", "x", "grades rapidly"], [1, 3]), _cited_text(["a", "b"], [1, 2])
    ('models degrades rapidly', 'a b')
    """
    text = lines[numbers[0] - 1]
    for n in numbers[1:]:
        hyphenated = re.search(r"[^\W\d_]-$", text)
        text = text[:-1] + lines[n - 1] if hyphenated else f"{text} {lines[n - 1]}"
    return text


def test_claims_quote_the_thesis_verbatim():
    if not THESIS_TXT.exists():
        pytest.skip(f"thesis text not found at {THESIS_TXT} (set THESIS_TXT)")
    lines = THESIS_TXT.read_text().splitlines()
    data = yaml.safe_load((paths.THESIS_DATA / "claims.yaml").read_text())
    for page, entry in data.items():
        if "caption" in entry:
            assert entry["caption"] in lines[entry["caption_line"] - 1], page
        for c in entry["claims"]:
            plain = " ".join(lines[n - 1] for n in c["lines"])
            assert c["text"] in plain or c["text"] in _cited_text(lines, c["lines"]), (page, c["text"])


def test_clean_outputs_keeps_content_and_drops_noise():
    outputs = [
        {"output_type": "stream", "name": "stdout", "text": "fig-3.3 (smoke): 6 runs\n"},
        {"output_type": "stream", "name": "stderr", "text": "train:  17%|#   | 1/6 [00:02<00:13, 2.6s/it]"},
        {"output_type": "stream", "name": "stdout", "text": "evaluate: 100%|####| 6/6 [00:01, 7.9it/s]\nAUC 3.1\n"},
        {
            "output_type": "stream",
            "name": "stdout",
            "text": "saved /tmp/x/fig.png\n[3.3] NOT JUDGED AT THIS SCALE - c\n",
        },
        {"output_type": "execute_result", "data": {"text/plain": "<Figure size 640x480 with 2 Axes>"}},
        {"output_type": "display_data", "data": {"image/png": "AAAA", "text/plain": "<Figure size 640x480>"}},
        {"output_type": "display_data", "data": {"text/markdown": "```{admonition} Reproduces: c\n```"}},
    ]
    out = book.clean_outputs(outputs)
    assert [o["output_type"] for o in out] == ["stream", "display_data", "display_data"]
    assert out[0]["text"] == "fig-3.3 (smoke): 6 runs\nAUC 3.1\n"
    assert "image/png" in out[1]["data"] and "text/markdown" in out[2]["data"]


def test_prepare_page_drops_parameters_and_opens_with_the_thesis(monkeypatch, tmp_path):
    nb = {
        "cells": [
            {"cell_type": "markdown", "metadata": {}, "source": "# Figure 3.3 - title\ntext"},
            {"cell_type": "code", "metadata": {"tags": ["parameters"]}, "source": "SCALE = 'small'", "outputs": []},
            {
                "cell_type": "code",
                "metadata": {"tags": ["injected-parameters"]},
                "source": "SCALE = 's'",
                "outputs": [],
            },
            {"cell_type": "code", "metadata": {}, "source": "x", "outputs": []},
        ],
        "metadata": {},
    }
    page = book.prepare_page(nb, "3.3", "smoke")
    sources = [c["source"] for c in page["cells"]]
    assert not any("SCALE =" in s for s in sources)
    assert sources[0] == "# Figure 3.3 - title"  # the title, then the thesis's claims, then the notebook's text
    assert "Figure 3.3 in the thesis" in sources[1] and "line 555" in sources[1]
    assert sources[2] == "text"
    assert page["cells"][3]["metadata"]["tags"] == ["hide-input"]
    assert "No computed verdict" in sources[-1]  # nothing was reported at this (empty) build


def test_summaries_count_verdicts(monkeypatch, tmp_path):
    report.report("fig-3.3", "small", [report.Verdict("3.3", "a", report.REPRODUCES, "e|1")], display=False)
    report.report("fig-3.2", "small", [report.Verdict("3.2", "b", report.DOES_NOT)], display=False)
    # the scoreboard reads the claims ledger: distinct thesis claims, none computed in this empty build
    board = book.scoreboard(["3.2", "3.3"], "small")
    from thesis_repro.claims import ledger

    n_thesis = sum(not s.beyond for s in ledger.specs())
    assert f"Distinct claims of the thesis: **{n_thesis}**" in board and "Beyond the thesis" in board
    assert "| **all** |" in board and "false R" in board
    table = book.chapter_summary("3", ["3.2", "3.3"], "small")
    assert "e\\|1" in table and "**reproduces**" in table and "**does not reproduce**" in table


@pytest.mark.slow
def test_a_failing_notebook_gets_an_error_page_and_fails_the_build(monkeypatch, tmp_path):
    def boom(nid, scale, **kwargs):
        raise RuntimeError("Traceback (most recent call last):\n  ...\nKeyError: 'sigmas'")

    monkeypatch.setattr(notebooks, "execute", boom)
    with pytest.raises(RuntimeError, match=r"1 notebook\(s\) failed at scale smoke \(fig-3.3\)"):
        book.build("smoke", ids=["3.3"], root=tmp_path / "book")
    html = (tmp_path / "book" / "_build" / "html" / "executed" / "fig-3.3.html").read_text()
    assert "Execution failed at scale smoke" in html and "KeyError" in html
    assert "Traceback" not in html and "Figure 3.3 in the thesis" in html


@pytest.mark.slow
def test_shipped_only_book_leaves_out_what_would_train_and_says_how_to_run_it(monkeypatch, tmp_path):
    # the test run cache and shipped layer are empty: Fig 3.3's training runs are all to compute
    monkeypatch.setattr(notebooks, "execute", lambda *a, **k: pytest.fail("a notebook that would train ran"))
    book.build("smoke", ids=["3.3"], root=tmp_path / "book", shipped_only=True)
    html = tmp_path / "book" / "_build" / "html"
    page = re.sub(r"<[^>]+>", "", (html / "executed" / "fig-3.3.html").read_text())
    n = len(figures.training_jobs("3.3", "smoke"))
    assert "Not run in this build (scale smoke)" in page and "Figure 3.3 in the thesis" in page
    assert f"{n} of its {n} training runs are neither shipped nor cached" in page
    assert "make figure-3.3 SCALE=smoke" in page and "make plan-3.3 SCALE=smoke MISSING=1" in page
    assert "not built: " in (html / "chapter-3.html").read_text()  # the chapter table says why, no verdict


# --- the built book in a real browser -------------------------------------------------------------------


@pytest.mark.slow
def test_smoke_book_in_headless_chromium(smoke_book, tmp_path):
    exe = chromium()
    html_root = smoke_book
    pages = sorted(html_root.glob("*.html")) + sorted((html_root / "executed").glob("*.html"))
    pages = [p for p in pages if p.name not in ("genindex.html", "search.html")]
    expected = {f"{notebooks.page_id(n)}.html" for n in notebooks.notebook_ids()}
    assert expected <= {p.name for p in pages}, f"pages missing: {sorted(expected - {p.name for p in pages})}"
    problems = []
    for page in pages:
        redirect = re.search(r'http-equiv="Refresh" content="0; url=([^"]+)"', page.read_text(), re.IGNORECASE)
        if redirect:  # Sphinx's index.html only redirects; Chromium's dump of it races the redirect (empty)
            if not (page.parent / redirect.group(1)).exists():
                problems.append(f"{page.name}: redirects to a missing page {redirect.group(1)}")
            continue
        dom = dump_dom(exe, page)
        if "</html>" not in dom:
            problems.append(f"{page.name}: no DOM dumped ({len(dom)} characters)")
            continue
        for src in local_refs(dom, "src"):
            if not (page.parent / src).resolve().exists():
                problems.append(f"{page.name}: broken image/script {src}")
        for href in local_refs(dom, "href"):
            if not (page.parent / href).resolve().exists():
                problems.append(f"{page.name}: broken link {href}")
        if PROGRESS.search(dom):
            problems.append(f"{page.name}: progress-bar text {PROGRESS.search(dom).group(0)!r}")
        if "Traceback (most recent call last)" in dom:
            problems.append(f"{page.name}: Python traceback")
        if page.parent.name == "executed":
            if "in the thesis" not in dom:
                problems.append(f"{page.name}: no thesis caption/claim block")
            if not STATUS_TITLE.search(dom):
                problems.append(f"{page.name}: no verdict admonition")
            if page.name.startswith("fig-") and not re.search(r'<img[^>]+src="[^"]*_images/[^"]+\.png"', dom):
                problems.append(f"{page.name}: no figure image")
    assert not problems, f"{len(problems)} problem(s): " + "; ".join(problems[:30])
    intro = dump_dom(exe, html_root / "intro.html")
    assert "Scoreboard at scale" in intro, intro[-2000:]
    for ch in sorted({notebooks.chapter(n) for n in notebooks.notebook_ids()}):
        assert "Verdicts at scale" in dump_dom(exe, html_root / f"chapter-{ch}.html"), ch
    shot = tmp_path / "page.png"
    run_browser(exe, f"--screenshot={shot}", "--window-size=1280,1600", (html_root / "intro.html").as_uri())
    assert shot.exists() and shot.stat().st_size > 20_000, "screenshot of intro.html is blank"  # a rendered page


@pytest.mark.slow
def test_executed_pages_are_cached(tmp_path, capsys):
    """An unchanged notebook is not executed again: the second build executes nothing."""
    nid = "5.3" if "5.3" in notebooks.notebook_ids() else notebooks.notebook_ids()[0]  # a cheap one
    book.build("smoke", ids=[nid], root=tmp_path / "book1")
    assert "1 notebook(s) executed, 0 up to date" in capsys.readouterr().out
    assert notebooks.is_current(nid, "smoke")
    before = json.loads(notebooks.executed_path(nid, "smoke").read_text())["metadata"]["thesis_repro"]
    book.build("smoke", ids=[nid], root=tmp_path / "book2")
    after = json.loads(notebooks.executed_path(nid, "smoke").read_text())["metadata"]["thesis_repro"]
    assert before == after
    assert "0 notebook(s) executed, 1 up to date" in capsys.readouterr().out
