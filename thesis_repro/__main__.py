"""Command line: ``python -m thesis_repro figure 3.3 --scale small`` | ``book`` | ``list``."""

from __future__ import annotations

import argparse
import os
import sys

from thesis_repro import notebooks, scales


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m thesis_repro")
    sub = parser.add_subparsers(dest="cmd", required=True)
    fig = sub.add_parser("figure", help="execute one notebook (or 'all') at a scale")
    fig.add_argument("figure", help="figure id such as 3.3, table-3.4, or 'all'")
    fig.add_argument("--scale", default="small", help="smoke | small | full")
    fig.add_argument("--jobs", type=int, default=None, help="parallel worker processes (default: cores)")
    book = sub.add_parser("book", help="execute every notebook at a scale and build the HTML book")
    book.add_argument("--scale", default="small")
    book.add_argument("--jobs", type=int, default=None)
    book.add_argument("--reuse", action="store_true", help="reuse already executed notebooks")
    sub.add_parser("list", help="list the notebooks and scales")
    args = parser.parse_args(argv)

    if getattr(args, "jobs", None):
        os.environ["THESIS_REPRO_JOBS"] = str(args.jobs)
    try:
        if args.cmd == "list":
            print("scales:", ", ".join(scales.SCALES))
            print("notebooks:", ", ".join(notebooks.notebook_ids()))
        elif args.cmd == "figure":
            scales.check_scale(args.scale)
            ids = notebooks.notebook_ids() if args.figure == "all" else [notebooks.check_notebook(args.figure)]
            for nid in ids:
                notebooks.execute(nid, args.scale)
        elif args.cmd == "book":
            from thesis_repro import book as book_mod

            book_mod.build(args.scale, reuse=args.reuse)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
