"""The book as a reader sees it: built at smoke scale and opened page by page in headless Chromium.

The browser part needs Debian's ``chromium``, which the bootstrap installs (``make chromium``, a step of
``make test``); without it the test skips with the reason. The smoke runs and executed notebooks live
in one session folder shared with ``tests/test_notebooks.py`` (whichever runs first executes them).

Every page is also measured in the browser (:data:`LAYOUT_JS`, judged by :func:`layout_problems`): no table or
image may overflow the text column (a wide table scrolls inside it), a figure shown at under half its drawn size
must be click-to-enlarge, and a page's first verdict must start within the first :data:`FIRST_SCREEN` px.
To check a book you built (``make book SCALE=small``) instead of the smoke book: ``make check-book SCALE=small``,
i.e. ``THESIS_REPRO_BOOK_HTML=build/small/book/_build/html pytest tests/test_book.py -k chromium``.
"""

from __future__ import annotations

import atexit
import base64
import contextlib
import functools
import io
import json
import os
import re
import select
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlparse

import pytest
import yaml

from thesis_repro import figures
from thesis_repro.book import builder as book
from thesis_repro.book import notebooks, protocol
from thesis_repro.claims import report
from thesis_repro.core import paths

#: `make test` runs pytest in two processes (`-n 2 --dist loadgroup`): every test that shares the smoke
#: notebooks' session folder runs in the same one, so they execute once.
pytestmark = pytest.mark.xdist_group("smoke")

THESIS_TXT = Path(os.environ.get("THESIS_TXT", "/work/shared/thesis.txt"))
PROGRESS = re.compile(r"it/s\]|s/it\]|\d%\|")
#: A built book's html folder to check instead of building the smoke book (``make check-book SCALE=small``).
BOOK_HTML = "THESIS_REPRO_BOOK_HTML"
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


class Browser:
    """One headless Chromium for many pages, driven over the DevTools protocol on a pipe (``--remote-debugging-pipe``:
    commands in on fd 3, replies out on fd 4, each a JSON text ended by a NUL byte). A browser started per page
    (``--dump-dom``) costs seconds of start-up each; the smoke book has dozens of pages."""

    def __init__(self, exe: str, timeout: float = 90):
        self.exe, self.timeout, self.proc, self.ids = exe, timeout, None, 0

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        to_browser, self._cmd = os.pipe()
        self._out, from_browser = os.pipe()

        def fds() -> None:  # pragma: no cover - runs in the child before exec
            cmd, out = os.dup(to_browser), os.dup(from_browser)  # either pipe end may itself be fd 3 or 4
            os.dup2(cmd, 3)
            os.dup2(out, 4)
            os.set_inheritable(3, True)  # dup2 onto the same number keeps close-on-exec
            os.set_inheritable(4, True)

        self.proc = subprocess.Popen(
            [*_browser_args(self.exe), "--remote-debugging-pipe", "about:blank"],
            preexec_fn=fds,
            close_fds=False,  # 3 and 4 (inheritable copies) must reach Chromium; Python's own fds are not inheritable
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        os.close(to_browser)
        os.close(from_browser)
        self._buf, self._session = b"", None
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self._session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        self.call("Page.enable")

    def close(self) -> None:
        if self.proc is not None:
            for fd in (self._cmd, self._out):
                with contextlib.suppress(OSError):
                    os.close(fd)
            self.proc.kill()
            self.proc.communicate()
            self.proc = None

    def _read(self, deadline: float) -> dict:
        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._out], [], [], left)[0]:
                raise TimeoutError(f"no reply within {self.timeout} s")
            chunk = os.read(self._out, 1 << 20)
            if not chunk:
                raise ConnectionError("chromium closed its DevTools pipe")
            self._buf += chunk
        msg, self._buf = self._buf.split(b"\0", 1)
        return json.loads(msg)

    def call(self, method: str, until: str | None = None, **params: object) -> dict:
        """Send one command (to the page's session once attached); wait for its reply, and then for the event
        ``until`` if given; returns the reply's result."""
        self.ids += 1
        msg: dict = {"id": self.ids, "method": method, "params": params}
        if self._session:
            msg["sessionId"] = self._session
        os.write(self._cmd, json.dumps(msg).encode() + b"\0")
        deadline, result, seen = time.monotonic() + self.timeout, None, until is None
        while result is None or not seen:
            reply = self._read(deadline)
            if reply.get("id") == self.ids:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                result = reply.get("result", {})
            elif until is not None and reply.get("method") == until:
                seen = True
        return result

    def _page(self, fn, page: Path, attempts: int = 2):
        """``fn()`` on a loaded ``page``; a crash or time-out restarts Chromium once, then fails with its stderr."""
        for attempt in range(attempts):
            try:
                if self.proc is None:
                    self.start()
                self.call("Page.navigate", until="Page.loadEventFired", url=page.as_uri())
                return fn()
            except (OSError, TimeoutError, ConnectionError, RuntimeError, ValueError) as err:
                stderr = b""
                if self.proc is not None:
                    self.proc.kill()
                    stderr = self.proc.communicate()[1] or b""
                    self.proc = None
                if attempt == attempts - 1:
                    pytest.fail(f"chromium on {page.name} failed: {err}: {stderr.decode(errors='replace')[-800:]}")
        raise AssertionError("unreachable")  # pragma: no cover

    def dom(self, page: Path) -> str:
        """The page's DOM after Chromium has loaded it and run its scripts (what ``--dump-dom`` prints)."""
        js = "document.documentElement.outerHTML"
        return self._page(
            lambda: self.call("Runtime.evaluate", expression=js, returnByValue=True)["result"]["value"], page
        )

    def dom_and_layout(self, page: Path) -> tuple[str, dict[str, Any] | None]:
        """The page's DOM (as :meth:`dom`), then :data:`LAYOUT_JS`'s numbers, in a :data:`WINDOW` window (the
        script opens every fold of this loaded copy only; the book is not touched)."""
        if self.proc is None:
            self.start()
        w, h = WINDOW
        self.call("Emulation.setDeviceMetricsOverride", width=w, height=h, deviceScaleFactor=1, mobile=False)
        script = LAYOUT_JS.replace("VERDICT_TITLE", json.dumps(VERDICT_TITLE))
        read = "(function () { const p = document.getElementById('tr-layout'); return p ? p.textContent : null; })()"

        def both() -> tuple[str, dict[str, Any] | None]:
            dom = self.call("Runtime.evaluate", expression="document.documentElement.outerHTML", returnByValue=True)
            self.call("Runtime.evaluate", expression=script)
            got = self.call("Runtime.evaluate", expression=read, returnByValue=True)["result"].get("value")
            return dom["result"]["value"], json.loads(got) if got else None

        return self._page(both, page)

    def screenshot(self, page: Path, out: Path, width: int = 1280, height: int = 1600) -> None:
        """A PNG of ``page`` in a ``width`` x ``height`` window (what ``--screenshot --window-size`` writes)."""
        if self.proc is None:
            self.start()
        self.call("Emulation.setDeviceMetricsOverride", width=width, height=height, deviceScaleFactor=1, mobile=False)
        data = self._page(lambda: self.call("Page.captureScreenshot", format="png")["data"], page)
        out.write_bytes(base64.b64decode(data))


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


# --- layout: what a reader sees at a laptop's width -----------------------------------------------------

#: The window the layout is measured in (a laptop screen) and how far down a page's first verdict may start.
WINDOW = (1280, 900)
FIRST_SCREEN = 1400
#: A figure shown at under this fraction of the width it was drawn at is too small to read unless it enlarges.
MIN_SHOWN = 0.5
#: A table column whose text wraps must be at least this many ems wide (about 12 characters): narrower, words
#: break mid-word and a row grows tall.
MIN_COLUMN_EM = 6.0
#: Titles that open a verdict: a claim's admonition, the page's verdict list, a chapter's or the book's summary.
VERDICT_TITLE = (
    r"^((" + "|".join(re.escape(s.capitalize()) for s in report.STATUSES) + r")( ·|:)"
    r"|Verdicts\b|Verdicts at scale|Scoreboard at scale)"
)

#: Measures the page in Chromium once it has loaded and appends the numbers as JSON in ``<pre id="tr-layout">``:
#: the text column (the article's content box), the first verdict's top (before any fold is opened), then, with
#: every ``<details>`` fold open, each shown table and image (its box, the box of the element that clips or
#: scrolls it and that one's overflow, an image's drawn size and whether it is a link) and the page's width.
LAYOUT_JS = r"""
(function () {
  function box(el) {
    const r = el.getBoundingClientRect();
    return {left: r.left + scrollX, right: r.right + scrollX, top: r.top + scrollY, bottom: r.bottom + scrollY};
  }
  function measure() {
    const article = document.querySelector('article.bd-article') || document.querySelector('main') || document.body;
    const cs = getComputedStyle(article), a = box(article);
    const column = {left: a.left + parseFloat(cs.paddingLeft), right: a.right - parseFloat(cs.paddingRight)};
    const title = new RegExp(VERDICT_TITLE);
    let first = null;
    article.querySelectorAll('.admonition-title, p > strong:first-child, h1, h2').forEach(function (el) {
      if (el.getClientRects().length && title.test(el.textContent.trim())) {
        const y = box(el).top;
        if (first === null || y < first) first = y;
      }
    });
    article.querySelectorAll('details').forEach(function (d) { d.open = true; });
    const items = [];
    article.querySelectorAll('table, img').forEach(function (el) {
      if (!el.getClientRects().length) return;  // not shown
      let clip = null, kind = null;
      for (let c = el; c && c !== article; c = c.parentElement) {
        const o = getComputedStyle(c).overflowX;
        if (o !== 'visible') { clip = c; kind = o; break; }
      }
      const cell = el.querySelector('th, td');
      const item = {kind: el.tagName.toLowerCase(), box: box(el), width: el.scrollWidth,
        name: (el.getAttribute('src') || (cell ? cell.textContent : '')).trim().slice(-48),
        clip: clip ? box(clip) : null, clipKind: kind, clipsItself: clip === el};
      if (el.tagName === 'IMG') {
        item.natural = [el.naturalWidth, el.naturalHeight];
        item.linked = !!el.closest('a[href]');
      } else {  // per column: its width in ems and the most lines any of its cells' text wraps to
        const cols = [], taken = [];  // taken[row][column]: a cell above spans into it (rowspan)
        el.querySelectorAll('tr').forEach(function (tr, r) {
          let k = 0;
          Array.from(tr.children).forEach(function (c) {
            while (taken[r] && taken[r][k]) k++;
            const cs = c.colSpan || 1, i = k;
            for (let dr = 0; dr < (c.rowSpan || 1); dr++)
              for (let dc = 0; dc < cs; dc++) (taken[r + dr] = taken[r + dr] || [])[k + dc] = true;
            k += cs;
            if (cs > 1) return;  // a cell spanning columns says nothing of one column's width
            const st = getComputedStyle(c), em = parseFloat(st.fontSize) || 16;
            const w = (c.clientWidth - parseFloat(st.paddingLeft) - parseFloat(st.paddingRight)) / em;
            // the text's own lines (distinct line tops), not the cell's height: a row made tall by another cell
            // does not wrap this one
            const range = document.createRange();
            range.selectNodeContents(c);
            const tops = Array.from(range.getClientRects()).filter(function (r) { return r.width > 0; })
              .map(function (r) { return r.top; }).sort(function (a, b) { return a - b; });
            const lines = tops.filter(function (t, k) { return k === 0 || t - tops[k - 1] > 0.6 * em; }).length;
            if (!cols[i]) cols[i] = {em: w, lines: lines};
            else { cols[i].em = Math.min(cols[i].em, w); cols[i].lines = Math.max(cols[i].lines, lines); }
          });
        });
        item.cols = cols;
      }
      items.push(item);
    });
    const out = document.createElement('pre');
    out.id = 'tr-layout';
    out.textContent = JSON.stringify({window: [innerWidth, innerHeight], column: column, items: items,
      firstVerdict: first, pageWidth: document.documentElement.scrollWidth});
    document.body.appendChild(out);
  }
  if (document.readyState === 'complete') measure(); else addEventListener('load', measure);
})();
"""


def measure_layout(browser: Browser, page: Path) -> dict[str, Any]:
    """:data:`LAYOUT_JS`'s numbers for ``page``, loaded at :data:`WINDOW` (:meth:`Browser.dom_and_layout`)."""
    dom, layout = browser.dom_and_layout(page)
    assert layout is not None, f"{page.name}: the layout script wrote nothing ({len(dom)} characters of DOM)"
    return layout


def layout_problems(m: dict[str, Any], page: str, verdict: bool = True) -> list[str]:
    """What a reader would find wrong in ``page``'s layout ``m`` (:func:`measure_layout`): a table or image that
    runs past the text column, or is cut off by a box that does not scroll; a figure shown at under
    :data:`MIN_SHOWN` of its drawn width that is not click-to-enlarge; a table column whose text wraps in under
    :data:`MIN_COLUMN_EM` ems; the page wider than the window; and, when the page has verdicts (``verdict``), none,
    or the first starting below :data:`FIRST_SCREEN` px.

    >>> col = {"left": 0, "right": 100}
    >>> wide = {"kind": "table", "name": "a", "box": {"left": 0, "right": 150}, "clip": None, "clipKind": None}
    >>> layout_problems({"column": col, "items": [wide], "firstVerdict": 10, "pageWidth": 100}, "p")
    ['p: table a overflows its column by 50 px']
    >>> squeezed = {**wide, "box": {"left": 0, "right": 90}, "cols": [{"em": 2.5, "lines": 3}, {"em": 2, "lines": 1}]}
    >>> layout_problems({"column": col, "items": [squeezed], "firstVerdict": 10, "pageWidth": 100}, "p")
    ['p: table a column 1 wraps at 2.5 em (under 6)']
    >>> scrolls = {**wide, "clip": {"left": 0, "right": 100}, "clipKind": "auto"}
    >>> layout_problems({"column": col, "items": [scrolls], "firstVerdict": 2000, "pageWidth": 100}, "p")
    ['p: first verdict at y = 2000 px, below the first 1400 px']
    """
    out = []
    col = m["column"]
    for it in m["items"]:
        what = f"{it['kind']} {it['name']}".rstrip()
        visible = it["box"]
        if it["clip"] is not None:
            if it["clipKind"] in ("hidden", "clip") and it["box"]["right"] > it["clip"]["right"] + 1:
                out.append(f"{page}: {what} is cut off by {it['box']['right'] - it['clip']['right']:.0f} px")
            visible = it["clip"]  # what shows of the item: its scrolling (or clipping) box
        over = max(visible["right"] - col["right"], col["left"] - visible["left"])
        if over > 1:
            out.append(f"{page}: {what} overflows its column by {over:.0f} px")
        for i, column in enumerate(it.get("cols") or []):
            if column and column["lines"] > 1 and column["em"] < MIN_COLUMN_EM:
                out.append(f"{page}: {what} column {i + 1} wraps at {column['em']:.1f} em (under {MIN_COLUMN_EM:g})")
        if it["kind"] == "img" and it.get("natural") and it["natural"][0] > 0:
            shown = (it["box"]["right"] - it["box"]["left"]) / it["natural"][0]
            if shown < MIN_SHOWN and not it.get("linked"):
                out.append(f"{page}: {what} is shown at {shown:.0%} of its size and is not click-to-enlarge")
    if m.get("window") and m["pageWidth"] > m["window"][0] + 1:
        out.append(f"{page}: the page is {m['pageWidth']} px wide, wider than the {m['window'][0]} px window")
    if verdict:
        if m["firstVerdict"] is None:
            out.append(f"{page}: no verdict found")
        elif m["firstVerdict"] > FIRST_SCREEN:
            out.append(f"{page}: first verdict at y = {m['firstVerdict']:.0f} px, below the first {FIRST_SCREEN} px")
    return out


def has_verdicts(page: Path) -> bool:
    """Whether a book page shows verdicts: the landing page, a chapter page and a notebook's page."""
    chapter = re.fullmatch(r"chapter-\d+\.html", page.name)  # a chapter's own page (not its static sections)
    return page.name == "intro.html" or bool(chapter) or page.parent.name == "executed"


_FIXTURE = """<!DOCTYPE html><html><head><style>body {{ margin: 0; }} article {{ width: 400px; padding: 0 20px; }}
.scroll {{ overflow-x: auto; }} .hide {{ overflow: hidden; }}</style></head><body><article class="bd-article">
<table style="width: 600px"><tr><td>too wide</td></tr></table>
<div class="scroll"><table style="width: 900px"><tr><td>scrolls</td></tr></table></div>
<div class="hide"><table style="width: 700px"><tr><td>cut off</td></tr></table></div>
<img src="{strip}" style="max-width: 100%"><a href="{strip}"><img src="{strip}" style="max-width: 100%"></a>
<img src="{small}"><div style="height: {gap}px"></div>
<div class="admonition"><p class="admonition-title">Reproduces · x · l. 1 claim</p></div>
<details><table style="width: 500px"><tr><td>folded</td></tr></table></details>
<table style="width: 380px; table-layout: fixed"><tr><td style="width: 40px">squeezed into a column</td><td>x</td></tr>
</table>
</article></body></html>"""


def _png(path: Path, width: int, height: int) -> Path:
    """A plain PNG of ``width`` × ``height`` (matplotlib: already a dependency of the kit)."""
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(width / 100, height / 100), dpi=100)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


@pytest.mark.slow
def test_layout_checker_finds_overflow_small_figures_and_a_late_verdict(tmp_path):
    """The checker itself, on a tiny page: each fault is found once (a squeezed table column too), and a table that
    scrolls inside a box, a linked figure and a figure at its own size pass."""
    exe = chromium()
    strip, small = _png(tmp_path / "strip.png", 2000, 200), _png(tmp_path / "small.png", 300, 100)
    page = tmp_path / "page.html"
    page.write_text(_FIXTURE.format(strip=strip.name, small=small.name, gap=2000))
    with Browser(exe) as browser:
        found = layout_problems(measure_layout(browser, page), "page")
    # the column: 400 px of content from x = 20 (the article's padding)
    assert found[:4] == [
        "page: table too wide overflows its column by 200 px",
        "page: table cut off is cut off by 300 px",
        "page: img strip.png is shown at 20% of its size and is not click-to-enlarge",
        "page: table folded overflows its column by 100 px",
    ], found
    assert re.fullmatch(r"page: table squeezed into a column column 1 wraps at \d\.\d em \(under 6\)", found[4])
    assert len(found) == 6 and re.fullmatch(r"page: first verdict at y = \d+ px, below the first 1400 px", found[5])
    page.write_text(_FIXTURE.format(strip=strip.name, small=small.name, gap=100))
    with Browser(exe) as browser:
        assert not any("verdict" in p for p in layout_problems(measure_layout(browser, page), "page"))


def given_book() -> Path | None:
    """The html folder of a built book named by ``$THESIS_REPRO_BOOK_HTML`` (None when unset); a folder that is
    not one fails the test with one line."""
    given = os.environ.get(BOOK_HTML)
    if not given:
        return None
    if not (Path(given) / "intro.html").is_file():
        pytest.fail(f"error: {BOOK_HTML}={given} is not a built book's html folder (make book SCALE=small builds one)")
    return Path(given)


def test_a_wrong_book_folder_is_one_error_line(monkeypatch, tmp_path):
    monkeypatch.setenv(BOOK_HTML, str(tmp_path))
    with pytest.raises(pytest.fail.Exception, match=r"^error: THESIS_REPRO_BOOK_HTML=\S+ is not a built book's html"):
        given_book()
    (tmp_path / "intro.html").write_text("<html></html>")
    assert given_book() == tmp_path
    monkeypatch.delenv(BOOK_HTML)
    assert given_book() is None


@dataclass
class SmokeBook:
    """The smoke book's HTML folder, what its build printed, and the notebooks that were not up to date before it."""

    html: Path
    printed: str
    stale_before: list[str]


@pytest.fixture(scope="module")
def smoke_book(tmp_path_factory) -> SmokeBook:
    """The smoke book, built once from the session's shared smoke runs (executing only what is missing); every
    test that needs the built book or the executed smoke notebooks reads this one. Or the built book at
    ``$THESIS_REPRO_BOOK_HTML`` (its ``_build/html`` folder: ``make check-book SCALE=small``)."""
    if given := given_book():
        return SmokeBook(given, "", [])
    with pytest.MonkeyPatch.context() as mp:
        for k, v in shared_smoke_dirs(tmp_path_factory).items():
            mp.setenv(k, v)
        stale = [n for n in notebooks.notebook_ids(guides=True) if not notebooks.is_current(n, "smoke")]
        root = tmp_path_factory.mktemp("smoke-book")
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed):
            index = book.build("smoke", root=root)
    print(printed.getvalue(), end="")
    return SmokeBook(index.parent, printed.getvalue(), stale)


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
    board = book.book_scoreboard(["3.2", "3.3"], "small")
    from thesis_repro.claims import ledger

    n_thesis = sum(not s.beyond for s in ledger.specs())
    assert f"Distinct claims of the thesis: **{n_thesis}**" in board and "Beyond the thesis" in board
    assert "| **all** |" in board and "false R" in board
    table = book.chapter_summary("3", ["3.2", "3.3"], "small")
    assert "e\\|1" in table and "**reproduces**" in table and "**does not reproduce**" in table


def test_chapter_table_shows_each_verdict_s_one_line_not_its_evidence():
    line = "reproduces · 3.3-x · l. 555 claim · thesis: r -0.43 · ours: r +0.79 [+0.50, +0.92]"
    v = report.Verdict("3.3", "claim", report.REPRODUCES, "long evidence " * 50, headline=line)
    report.report("fig-3.3", "small", [v], display=False)
    table = book.chapter_summary("3", ["3.3"], "small")
    assert "l. 555 claim · thesis: r -0.43 · ours: r +0.79 [+0.50, +0.92]" in table and "long evidence" not in table


def test_protocol_page_opens_with_its_deviations_and_folds_the_rest():
    md = protocol.render()
    deviations = [r for r in protocol.rows() if r["status"] == "deviation"]
    head, _, rest = md.partition(f"## {protocol.ALL_HEADING}")
    assert f"## {protocol.DEVIATIONS_HEADING}" in head and rest, "the deviations, then every row"
    first_table = head.split(f"## {protocol.DEVIATIONS_HEADING}", 1)[1]
    assert f"The {len(deviations)} settings" in first_table
    assert first_table.count("\n| ") == len(deviations) + 1  # the header and one row per deviation
    assert all(protocol._cell(r["item"]) in first_table for r in deviations)
    groups = {r["group"] for r in protocol.rows()}
    assert rest.count("<details>") == rest.count("</details>") == len(groups)  # every group folded
    assert not re.search(r"\n\| Item \|", head), "no full table before the deviations"


def test_chapter_4_pages_say_whether_the_thesis_reports_curve_values():
    for nid in notebooks.notebook_ids():
        page = notebooks.page_id(nid)
        cell = book.thesis_cell(page, "small")["source"]
        if notebooks.page_chapter(nid) == "4":
            assert cell.count("**Thesis values:**") == 1, page
            assert "none" in cell or "data/thesis/" in cell, page
        else:
            assert "**Thesis values:**" not in cell, page


@pytest.mark.slow
@pytest.mark.xdist_group("book-pages")  # with the module mark, a group of its own: no shared smoke folder
def test_a_failing_notebook_gets_an_error_page_and_fails_the_build(monkeypatch, tmp_path):
    def boom(nid, scale, **kwargs):
        raise RuntimeError("Traceback (most recent call last):\n  ...\nKeyError: 'sigmas'")

    monkeypatch.setattr(notebooks, "execute_notebook", boom)
    with pytest.raises(RuntimeError, match=r"1 notebook\(s\) failed at scale smoke \(fig-3.3\)"):
        book.build("smoke", ids=["3.3"], root=tmp_path / "book")
    html = (tmp_path / "book" / "_build" / "html" / "executed" / "fig-3.3.html").read_text()
    assert "Execution failed at scale smoke" in html and "KeyError" in html
    assert "Traceback" not in html and "Figure 3.3 in the thesis" in html


@pytest.mark.slow
@pytest.mark.xdist_group("book-pages")  # with the module mark, a group of its own: no shared smoke folder
def test_shipped_only_book_leaves_out_what_would_train_and_says_how_to_run_it(monkeypatch, tmp_path):
    # the test run cache and shipped layer are empty: Fig 3.3's training runs are all to compute
    monkeypatch.setattr(notebooks, "execute_notebook", lambda *a, **k: pytest.fail("a notebook that would train ran"))
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
    """Every page of the book loads, links and shows what it should, and its layout passes :func:`layout_problems`
    at a laptop's width."""
    with Browser(chromium()) as browser:
        check_book_in_browser(browser, smoke_book.html, tmp_path)


def check_book_in_browser(browser: Browser, html_root: Path, tmp_path: Path) -> None:
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
        dom, layout = browser.dom_and_layout(page)
        if "</html>" not in dom or layout is None:
            problems.append(f"{page.name}: no DOM or layout dumped ({len(dom)} characters)")
            continue
        where = f"{page.parent.name}/{page.name}" if page.parent != html_root else page.name
        problems += layout_problems(layout, where, verdict=has_verdicts(page))
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
    intro = browser.dom(html_root / "intro.html")
    assert "Scoreboard at scale" in intro, intro[-2000:]
    for ch in sorted({notebooks.page_chapter(n) for n in notebooks.notebook_ids()}):
        assert "Verdicts at scale" in browser.dom(html_root / f"chapter-{ch}.html"), ch
    shot = tmp_path / "page.png"
    browser.screenshot(html_root / "intro.html", shot)
    assert shot.exists() and shot.stat().st_size > 20_000, "screenshot of intro.html is blank"  # a rendered page


@pytest.mark.slow
def test_executed_pages_are_cached(smoke_book, tmp_path_factory, tmp_path, monkeypatch, capsys):
    """The book executes exactly the notebooks that are not up to date, and an unchanged notebook is not executed
    again: a second build of the session's smoke book executes nothing (the smoke book's own build, reused)."""
    if given_book():
        pytest.skip(f"{BOOK_HTML} names a built book: nothing is built here")
    n = len(notebooks.notebook_ids(guides=True))  # the book executes the guides too
    stale = len(smoke_book.stale_before)
    assert f"({stale} notebook(s) executed, {n - stale} up to date" in smoke_book.printed
    for k, v in shared_smoke_dirs(tmp_path_factory).items():
        monkeypatch.setenv(k, v)
    nid = "5.3" if "5.3" in notebooks.notebook_ids() else notebooks.notebook_ids()[0]  # a cheap one
    assert notebooks.is_current(nid, "smoke")
    before = json.loads(notebooks.executed_path(nid, "smoke").read_text())["metadata"]["thesis_repro"]
    book.build("smoke", ids=[nid], root=tmp_path / "book2")
    after = json.loads(notebooks.executed_path(nid, "smoke").read_text())["metadata"]["thesis_repro"]
    assert before == after
    assert "0 notebook(s) executed, 1 up to date" in capsys.readouterr().out
