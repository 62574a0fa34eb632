"""The book builder's terminal and static pages, without building a book: which notebook it is on, where the
scoreboard goes, and the static guide pages in the table of contents."""

from __future__ import annotations

import io
import sys

import yaml

from thesis_repro.book import builder as book
from thesis_repro.book import notebooks
from thesis_repro.core import paths


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_log_gets_one_plain_line_per_notebook():
    out = io.StringIO()
    with book.BookProgress(3, out) as progress:
        for page, action in [("fig-3.3", "executing ..."), ("table-3.4", "up to date"), ("fig-3.6", "executing ...")]:
            progress.step(page, action)
    assert out.getvalue().splitlines() == [
        "[1/3] fig-3.3 executing ...",
        "[2/3] table-3.4 up to date",
        "[3/3] fig-3.6 executing ...",
    ]


def test_a_terminal_gets_the_same_lines_above_a_bar_and_the_notebooks_output_between_them():
    out = _Tty()
    with book.BookProgress(24, out) as progress:
        assert progress.bar is not None
        for i in range(7):
            progress.step(f"page-{i}", "executing ...")
            print(f"verdict of page-{i}")  # what a notebook prints passes above the bar
    assert progress.bar is None and sys.stdout is not out
    text = out.getvalue()
    lines = [ln.split("\r")[-1].strip() for ln in text.split("\n")]
    assert "[7/24] page-6 executing ..." in lines and "verdict of page-6" in lines
    assert lines.index("[7/24] page-6 executing ...") < lines.index("verdict of page-6")
    assert "[7/24] page-6 |" in text  # the bar names the notebook too


def test_the_scoreboard_opens_the_first_page_and_its_method_closes_it():
    intro = (paths.BOOK / "intro.md").read_text()
    assert intro.count(book.SCOREBOARD_MARK) == 1
    board = "\n\n## Scoreboard at scale `small`\n\ncounts\n\n## Method: rules\n\nnull rates\n"
    page = book.place_scoreboard(intro, board)
    assert page.index("## Scoreboard at scale") < page.index("## How to read a page") < page.index("## Method")
    assert page.rstrip().endswith("null rates")


def test_the_static_guide_pages_follow_the_protocol_page_in_the_contents(tmp_path):
    for name in ["intro", "chapter-3", "protocol", *book.GUIDES]:
        (tmp_path / f"{name}.md").write_text(f"# {name}\n")
    toc = yaml.safe_load(book.write_toc([n for n in notebooks.notebook_ids() if n == "3.3"], tmp_path).read_text())
    files = [c["file"] for c in toc["chapters"]]
    assert files == ["chapter-3", "protocol", *book.GUIDES]
    assert all((paths.BOOK / f"{g}.md").exists() for g in book.GUIDES)
