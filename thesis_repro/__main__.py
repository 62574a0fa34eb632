"""Command line: ``python -m thesis_repro figure 3.3 --scale small`` | ``book`` | ``list`` | ``runs 3.3`` |
``reference-runs --scale small`` | ``budgets --scale small`` | ``plan 3.3 --scale full --cores 64``."""

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
    book.add_argument("--reuse", action="store_true", help="reuse executed notebooks even if their sources changed")
    book.add_argument("--force", action="store_true", help="re-execute every notebook (default: only changed ones)")
    book.add_argument(
        "--shipped-only", action="store_true", help="execute only notebooks whose training runs are shipped or cached"
    )
    sub.add_parser("list", help="list the notebooks and scales")
    runs_p = sub.add_parser("runs", help="where a figure's runs are: kind, label, key, state, path")
    runs_p.add_argument("figure", nargs="?", default="all", help="figure id such as 3.3, or 'all'")
    runs_p.add_argument("--scale", default="small", help="smoke | small | full")
    runs_p.add_argument("--json", action="store_true", help="print the rows as JSON")
    runs_p.add_argument("--check", action="store_true", help="report stale or corrupt shipped runs instead")
    ref = sub.add_parser("reference-runs", help="train the figures' training runs and ship them in data/reference")
    ref.add_argument("--scale", default="small", help="smoke | small | full")
    ref.add_argument("--figures", nargs="+", default=None, help="figure ids (default: every figure)")
    ref.add_argument("--kind", nargs="+", default=None, help="job kinds to ship (default: train)")
    ref.add_argument("--commit", action="store_true", help="git-commit each run as it lands")
    ref.add_argument("--jobs", type=int, default=None, help="runs trained at once (default 1; 2 on two idle cores)")
    bud = sub.add_parser("budgets", help="are the training runs trained? curve statistics of cached/shipped runs")
    bud.add_argument("--scale", default="small", help="smoke | small | full")
    bud.add_argument("--figures", nargs="+", default=None, help="figure ids (default: every figure)")
    plan_p = sub.add_parser("plan", help="cost before running: jobs, env steps, throughput, core-hours, wall time")
    plan_p.add_argument("figure", nargs="?", default="all", help="figure id such as 3.3, or 'all' (+ the book)")
    plan_p.add_argument("--scale", default="full", help="smoke | small | full")
    plan_p.add_argument("--cores", type=int, default=None, help="cores for the wall time (default: this machine's)")
    plan_p.add_argument("--envs", nargs="+", default=None, help="only these tasks (a figure's `envs` setting)")
    plan_p.add_argument("--algos", nargs="+", default=None, help="only these learners (a figure's `algos` setting)")
    plan_p.add_argument("--missing", action="store_true", help="only what is neither cached nor shipped yet")
    args = parser.parse_args(argv)

    if getattr(args, "jobs", None):
        os.environ["THESIS_REPRO_JOBS"] = str(args.jobs)
    try:
        check_environment()
        if args.cmd == "list":
            print("scales:", ", ".join(scales.SCALES))
            print("notebooks:", ", ".join(notebooks.notebook_ids()))
        elif args.cmd == "figure":
            scales.check_scale(args.scale)
            ids = notebooks.notebook_ids() if args.figure == "all" else [notebooks.check_notebook(args.figure)]
            for nid in ids:
                notebooks.execute(nid, args.scale)
        elif args.cmd == "plan":
            return _plan_command(args)
        elif args.cmd in ("runs", "reference-runs"):
            return _runs_command(args)
        elif args.cmd == "budgets":
            from thesis_repro import budgets, figures

            scales.check_scale(args.scale)
            ids = [figures.get(f).id for f in args.figures] if args.figures else None
            print(budgets.render(budgets.table(args.scale, ids)))
            cost = budgets.retrain_cost(args.scale, ids)
            print("\nRETRAIN=1 cost (measured wall time of the finished runs, 1 core each; upper bounds):")
            print(cost.to_string(index=False, float_format=lambda v: f"{v:.2f}"))
        elif args.cmd == "book":
            from thesis_repro import book as book_mod

            book_mod.build(args.scale, reuse=args.reuse, force=args.force, shipped_only=args.shipped_only)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except RuntimeError as err:  # e.g. notebooks that failed while the book was built
        print(f"error: {err}", file=sys.stderr)
        return 1
    return 0


def check_environment() -> None:
    """The kit's environment settings (``make ... RETRAIN=1 BACKEND=ray``) are valid before anything runs:
    a typo is a one-line error here, not a traceback inside a notebook's kernel."""
    from thesis_repro import backends, paths

    paths.retrain()
    backends.backend()


def _plan_command(args: argparse.Namespace) -> int:
    from thesis_repro import plan

    scales.check_scale(args.scale)
    if args.cores is not None and args.cores < 1:
        raise ValueError(f"--cores must be an integer >= 1, got {args.cores}")
    rates = plan.load_rates()
    print(plan.rates_note(rates))
    subset = {k: v for k, v in (("envs", args.envs), ("algos", args.algos)) if v is not None}
    if args.figure != "all":
        print(plan.report(plan.plan_figure(args.figure, args.scale, args.cores, rates, args.missing, **subset), rates))
        return 0
    if subset:
        raise ValueError("--envs/--algos choose a subset of one figure; name it (plan 3.3 --algos ppo trpo)")
    per, book = plan.plan_book(args.scale, args.cores, rates, args.missing)
    for p in per:
        print(plan.summary(p))
    print("\nthe book (every figure; runs shared by figures counted once):")
    print(plan.report(book, rates))
    return 0


def _runs_command(args: argparse.Namespace) -> int:
    import json

    from thesis_repro import figures, runs

    scales.check_scale(args.scale)
    if args.cmd == "reference-runs":
        kinds = args.kind or figures.TRAINING_KINDS
        runs.generate(args.scale, args.figures, kinds, commit=args.commit, n_jobs=args.jobs or 1)
        return 0
    if args.check:
        stale, corrupt = runs.check_shipped(args.scale), runs.verify_shipped()
        for s in stale:
            print(s.message)
        for path, err in corrupt.items():
            print(f"corrupt shipped run {path}: {err}")
        print(f"{len(runs.shipped_entries())} shipped runs: {len(stale)} stale, {len(corrupt)} corrupt")
        return 1 if stale or corrupt else 0
    ids = figures.ids() if args.figure == "all" else [args.figure]
    for fid in ids:
        rows = runs.rows(fid, args.scale)
        if args.json:
            print(json.dumps({"figure": fid, "scale": args.scale, "runs": rows}, indent=1))
            continue
        train = [j for j in figures.jobs(fid, args.scale) if j.kind in figures.TRAINING_KINDS]
        print(f"{figures.get(fid).notebook_id} ({args.scale}): {runs.summary(train) if train else 'no training runs'}")
        print(runs.table(rows) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
