"""Command line, one file on purpose (over 800 lines): the one parser of every command, each handler keeping the one
error contract below (its ``error:`` line, its exit code) and calling the module that does the work, so nothing
here is shared with another module.

``python -m thesis_repro figure 3.3 --scale small`` | ``book`` | ``list`` | ``runs 3.3`` |
``reference-runs --scale small`` | ``budgets --scale small [--spread]`` | ``plan 3.3 --scale full --cores 64`` |
``claims ...`` | ``results [--check]`` | ``verify --scale small -n 20`` | ``bench [NAME ...] [--list]`` |
``score model.zip --task Hopper --scale small [--versus ppo]`` | ``train ppo Hopper --seed 0 [--timesteps N]
[--train]`` | ``enjoy ppo Hopper --seed 0 --test obs --sigma 0.4 --video out.mp4 [--lean --size 240]``
(your agent under the thesis's protocol, :mod:`thesis_repro.book.agent`) | ``--version``. Installed, the same command
line is the ``thesis-repro`` console script.

Output fits the terminal (:mod:`thesis_repro.core.terminal`: ``COLUMNS``); ``--verbose`` or ``--json`` give the full
text.

Every failure a user can cause ends in one ``error: ...`` line on stderr and a non-zero exit code, never a
traceback: a bad argument or setting (2), a notebook that failed (its own exception, 1), a folder that cannot
be written (the path and the setting naming it, 1). Ctrl-C prints ``interrupted; rerun to resume`` and exits
130 (143 for SIGTERM, 129 for SIGHUP): finished runs are cached and interrupted ones resume.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import logging
import os
import signal
import sys
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, NoReturn

from thesis_repro.core.validation import one_line

INTERRUPTED = "interrupted; rerun to resume"


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised like Ctrl-C so that the same cleanup runs; ``code`` is the exit code."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.code = 128 + signum


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one ``error:`` line (no usage block)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"error: {one_line(ValueError(message))} (see `{self.prog} --help`)\n")


@contextlib.contextmanager
def _one_line_usage_errors() -> Iterator[None]:
    """Every argument parser of the command (also the claims ledger's own) reports a usage error as one line,
    as :class:`Parser` does, while the command runs."""
    saved = argparse.ArgumentParser.error
    argparse.ArgumentParser.error = Parser.error  # type: ignore[method-assign]
    try:
        yield
    finally:
        argparse.ArgumentParser.error = saved  # type: ignore[method-assign]


def positive_int(text: str, low: int = 1) -> int:
    """``--jobs``/``--cores`` values: an integer >= 1 (``low``).

    >>> positive_int("2")
    2
    >>> positive_int("0")
    Traceback (most recent call last):
    ...
    argparse.ArgumentTypeError: invalid value '0'; valid values are integers >= 1
    """
    try:
        value = int(text)
    except ValueError:
        value = low - 1
    if value < low:
        raise argparse.ArgumentTypeError(f"invalid value {text!r}; valid values are integers >= {low}")
    return value


def nonneg_int(text: str) -> int:
    """``--seeds`` values: an integer >= 0.

    >>> nonneg_int("0")
    0
    """
    return positive_int(text, low=0)


def main_exit() -> None:
    """The ``thesis-repro`` console script: :func:`main`, its return value as the exit code."""
    sys.exit(main())


def version() -> str:
    """The kit's version: the installed distribution's, else the package's ``__version__``.

    >>> version() == __import__("thesis_repro").__version__
    True
    """
    from importlib import metadata

    import thesis_repro

    try:
        return metadata.version("thesis_repro")
    except metadata.PackageNotFoundError:
        return thesis_repro.__version__


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit code (see the module docstring)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if (nk := sys.modules.get("thesis_repro.book.notebook_kernel")) is not None:  # a new command: no bar of its own yet
        nk.line_ended()
    try:
        with _signals_as_interrupts(), _one_line_usage_errors():
            return _main(argv)
    except KeyboardInterrupt as err:
        # the notebook client's pending tasks die with the kernel: asyncio would log each as it is collected
        logging.getLogger("asyncio").setLevel(logging.CRITICAL)
        nk = sys.modules.get("thesis_repro.book.notebook_kernel")
        if nk is not None:  # no kernel can be running if the kernel module was never imported
            nk.kill_kernels()
        print(f"\n{INTERRUPTED}", file=sys.stderr)  # on its own line, never glued onto a progress bar's
        return err.code if isinstance(err, Terminated) else 130


@contextlib.contextmanager
def _signals_as_interrupts() -> Iterator[None]:
    """SIGTERM and SIGHUP raise :class:`Terminated` while the command runs (kernels and files get cleaned)."""

    def handler(signum: int, frame: Any) -> None:
        raise Terminated(signum)

    saved = {}
    for sig in (signal.SIGTERM, signal.SIGHUP):
        with contextlib.suppress(ValueError, OSError):  # not the main thread: leave the handlers alone
            saved[sig] = signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, old in saved.items():
            signal.signal(sig, old)


def _main(argv: list[str]) -> int:
    parser = Parser(prog="python -m thesis_repro")
    parser.add_argument("--version", action="version", version=f"thesis_repro {version()}")
    sub = parser.add_subparsers(dest="cmd", required=True)
    fig = sub.add_parser("figure", help="execute one notebook (or 'all') at a scale")
    fig.add_argument("figure", help="figure id such as 3.3, table-3.4, or 'all'")
    fig.add_argument("--scale", default="small", help="smoke | small | full")
    fig.add_argument("--jobs", type=positive_int, default=None, help="parallel worker processes, >= 1 (default: cores)")
    fig.add_argument(
        "--train",
        action="store_true",
        help="train the runs that are neither shipped nor cached (without it such a figure refuses, naming the cost)",
    )
    fig.add_argument(
        "-p",
        "--parameter",
        nargs=2,
        action="append",
        default=[],
        metavar=("NAME", "VALUE"),
        help="a notebook parameter (VALUE read as YAML); SCALE is --scale's",
    )
    book = sub.add_parser("book", help="execute every notebook at a scale and build the HTML book")
    book.add_argument("--scale", default="small")
    book.add_argument("--jobs", type=positive_int, default=None, help="parallel worker processes, >= 1")
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
    runs_p.add_argument("--verbose", action="store_true", help="list every run (default: counts per kind)")
    runs_p.add_argument(
        "--check", action="store_true", help="report stale or corrupt shipped runs and corrupt local runs instead"
    )
    runs_p.add_argument(
        "--compact",
        action="store_true",
        help="rewrite the shipped training runs' arrays.npz in the compact lossless layout (same numbers, bit for bit)",
    )
    ref = sub.add_parser("reference-runs", help="train the figures' training runs and ship them in data/reference")
    ref.add_argument("--scale", default="small", help="smoke | small | full")
    ref.add_argument("--figures", nargs="+", default=None, help="figure ids (default: every figure)")
    ref.add_argument("--kind", nargs="+", default=None, help="job kinds to ship (default: train)")
    ref.add_argument("--commit", action="store_true", help="git-commit each run as it lands")
    ref.add_argument("--algos", nargs="+", default=None, help="only these learners' runs (default: all)")
    ref.add_argument(
        "--seeds", nargs="+", type=nonneg_int, default=None, help="only these training seeds (default: all)"
    )
    ref.add_argument(
        "--jobs", type=positive_int, default=None, help="runs trained at once, >= 1 (default 1; 2 on two idle cores)"
    )
    ref.add_argument(
        "--order",
        default="seed-first",
        help="seed-first (default): the first seed of every item first, then item by item; item: item by item in "
        "the order of --figures, every requested seed of an item before the next; claims: item by item, the items "
        "ranked by claims settled per core-hour (`plan order`; needs --seeds; chapter 5 to 10 seeds)",
    )
    ref.add_argument(
        "--until",
        default=None,
        metavar="HH:MM",
        help="start only jobs expected to end by this clock time (at the shipped runs' pace; the session's end)",
    )
    ref.add_argument(
        "--study",
        default=None,
        help="a budget study's jobs instead of the figures' (thesis-budget: Fig 3.3's variants at the thesis's 4e6 "
        "steps, evaluated after 1M, 2M, 3M and 4M; default kinds train evaluate), in its own order",
    )
    bud = sub.add_parser("budgets", help="are the training runs trained? curve statistics of cached/shipped runs")
    bud.add_argument("--scale", default="small", help="smoke | small | full")
    bud.add_argument("--figures", nargs="+", default=None, help="figure ids (default: every figure)")
    bud.add_argument(
        "--spread", action="store_true", help="seed spread per learner and task (markdown), beside published numbers"
    )
    bud.add_argument("--protocol", default=None, help="with --spread: only this protocol's runs (thesis)")
    bud.add_argument(
        "--at", type=positive_int, default=None, help="with --spread: also the training return at this many env steps"
    )
    bud.add_argument(
        "--shipped-only", action="store_true", help="with --spread: the shipped runs alone (data/reference)"
    )
    bud.add_argument("--algos", nargs="+", default=None, help="with --spread: only these learners (default: all)")
    plan_p = sub.add_parser("plan", help="cost before running: jobs, env steps, throughput, core-hours, wall time")
    plan_p.add_argument(
        "figure",
        nargs="?",
        default="all",
        help="figure id such as 3.3, 'all' (+ the book), 'order' (the generator's order for --seeds: claims "
        "settled per core-hour), or a budget study (thesis-budget: its price and its order)",
    )
    plan_p.add_argument("--scale", default=None, help="smoke | small | full (default full; a budget study: small)")
    plan_p.add_argument(
        "--cores", type=positive_int, default=None, help="cores for the wall time, >= 1 (default: this machine's)"
    )
    plan_p.add_argument("--envs", nargs="+", default=None, help="only these tasks (a figure's `envs` setting)")
    plan_p.add_argument("--algos", nargs="+", default=None, help="only these learners (a figure's `algos` setting)")
    plan_p.add_argument("--missing", action="store_true", help="only what is neither cached nor shipped yet")
    plan_p.add_argument(
        "--seeds", nargs="+", type=int, default=None, help="only these training seeds, also past the scale's count"
    )
    plan_p.add_argument(
        "--rates",
        choices=["bench", "shipped"],
        default=None,
        help="bench (default; `plan order`: shipped): make bench's measured rates (else documented defaults); "
        "shipped: the pace the shipped runs kept (on this CPU where it made enough of them)",
    )
    ver = sub.add_parser("verify", help="recompute a random sample of shipped evaluations and compare (make verify)")
    ver.add_argument("--scale", default="small", help="smoke | small | full")
    ver.add_argument("-n", type=positive_int, default=20, help="how many shipped evaluations, >= 1 (default 20)")
    ver.add_argument("--seed", type=int, default=None, help="seed of the sample (default: random, printed)")
    ver.add_argument("--train", action="store_true", help="also retrain the cheapest shipped training run")
    ver.add_argument(
        "--kind",
        nargs="+",
        default=None,
        help="shipped kinds to sample from (default: evaluate; chapter 5's arm kinds too, e.g. arm-target)",
    )
    ver.add_argument("--figure", default=None, help="recompute every shipped evaluation behind a figure, e.g. 3.3")
    ver.add_argument(
        "--entry",
        default=None,
        help="recompute one shipped entry: its label (ppo__Hopper__s4__obs) or key (6+ characters)",
    )
    ver.add_argument(
        "--claim",
        default=None,
        help="recompute every entry behind a claim and its pages' saved numbers (vs the snapshot)",
    )
    ver.add_argument(
        "--all", action="store_true", help="recompute every shipped evaluation of the scale (make verify-all)"
    )
    ver.add_argument(
        "--study",
        default=None,
        help="a budget study's free integrity check instead (thesis-budget: each learner without a budget-dependent "
        "schedule, at the small budget, is the shipped small run bit for bit); nothing is trained",
    )
    bench_p = sub.add_parser("bench", help="throughput benchmarks, printed as ratios (make bench)")
    bench_p.add_argument("names", nargs="*", help="benchmarks to run (default: all; --list names them)")
    bench_p.add_argument("--list", action="store_true", help="list the registered benchmarks and exit")
    _agent_parsers(sub)
    sub.add_parser("claims", help="the thesis's claims ledger (`claims --help` for its commands)", add_help=False)
    sub.add_parser("results", help="write RESULTS.md and the README's results block (`results --help`)", add_help=False)
    if argv[:1] == ["claims"]:  # everything after `claims` is the ledger's own command line
        return _guarded(lambda: _claims(argv[1:]))
    if argv[:1] == ["results"]:
        return _guarded(lambda: _results(argv[1:]))
    try:
        args = parser.parse_args(argv)
    except SystemExit as done:  # --help, or a usage error (already printed as one `error:` line)
        return int(done.code or 0)
    if getattr(args, "jobs", None):
        os.environ["THESIS_REPRO_JOBS"] = str(args.jobs)
    return _guarded(lambda: _command(args))


def _guarded(command: Any) -> int:
    """Run ``command()``; a user's error becomes one ``error:`` line and an exit code."""
    try:
        return command()
    except ValueError as err:
        _error(one_line(err))
        return 2
    except BrokenPipeError:  # the reader went away (`... runs all | head`): stop quietly
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        return 1
    except OSError as err:  # an unwritable, full or misplaced folder
        _error(describe_os_error(err))
        return 1
    except RuntimeError as err:  # e.g. a notebook that failed, notebooks that failed while the book was built
        _error(one_line(err))
        return 1


def _error(message: str) -> None:
    """Print ``error: message`` on a line of its own (after a notebook's unfinished progress bar, a new line)."""
    nk = sys.modules.get("thesis_repro.book.notebook_kernel")  # no bar can be open if no notebook ran
    print(("\n" if nk is not None and nk.line_open() else "") + f"error: {message}", file=sys.stderr)
    if nk is not None:
        nk.line_ended()


def describe_os_error(err: OSError) -> str:
    """One line for an ``OSError``: what went wrong, the path, and the setting that chose the path.

    >>> describe_os_error(OSError(28, "No space left on device", "/x/runs/train"))
    '/x/runs/train: No space left on device'
    """
    from thesis_repro.core import paths

    what = err.strerror or one_line(err)
    name = err.filename
    if name is None:
        return what
    where = ""
    settings = (
        (paths.runs_dir(), "the run cache, THESIS_REPRO_DATA"),
        (paths.build_dir("x").parent, "the build folder, THESIS_REPRO_BUILD"),
        (paths.reference(), "the shipped runs, THESIS_REPRO_REFERENCE"),
    )
    for root, setting in settings:
        path = Path(os.fsdecode(name)).absolute()
        if path == root.absolute() or root.absolute() in path.parents:
            where = f" ({setting})"
            break
    return f"{os.fsdecode(name)}{where}: {what}"


def check_writable(folder: Path) -> None:
    """Create ``folder`` if needed and write (and remove) a small file in it; an ``OSError`` naming the
    folder if it cannot be written (read-only, full, or a path through a file)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".write-test-") as fh:
            fh.write(b"\0" * 4096)
            fh.flush()
            os.fsync(fh.fileno())
    except OSError as err:
        raise OSError(err.errno, f"cannot be written ({err.strerror or err})", str(folder)) from None


def _claims(argv: list[str]) -> int:
    """``python -m thesis_repro claims ...``: the claims ledger's own command line."""
    from thesis_repro.core import paths
    from thesis_repro.core.validation import read_yaml

    read_yaml(paths.THESIS_DATA / "claims.yaml")  # a truncated or non-UTF-8 registry: one line naming file and line
    try:
        from thesis_repro.claims import cli
    except ImportError as err:
        raise RuntimeError(f"the claims ledger is not available ({err})") from None
    try:
        return _ledger(cli.main, argv)
    except SystemExit as done:  # --help, or a usage error (already printed as one `error:` line)
        return int(done.code or 0)


def _ledger(ledger_main: Any, argv: list[str]) -> int:
    """Run the claims ledger's ``main``: its lines and notes wrapped at the terminal's width, unless ``--verbose``
    or ``--json`` asks for the full text as the ledger prints it (or ``--help``)."""
    if {"-h", "--help", "--json", "--verbose"} & set(argv):
        return int(ledger_main(argv) or 0)
    from thesis_repro.core import terminal

    if sys.stderr.isatty():  # the ledger prints nothing until it is done
        print("judging the thesis's claims from saved numbers (about 30 s) ...", file=sys.stderr, flush=True)
    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = int(ledger_main(argv) or 0)
    finally:  # wrapped at the terminal's width; --verbose or --json give the full text as it is
        for line in err.getvalue().splitlines():  # an error stays one line
            print(line if line.startswith("error:") else terminal.wrap(line), file=sys.stderr)
        if text := out.getvalue().rstrip("\n"):
            print(terminal.wrap(text, indent="    "))
    return code


def _results(argv: list[str]) -> int:
    """``python -m thesis_repro results ...``: RESULTS.md and the README blocks from the shipped claims snapshot."""
    from thesis_repro.claims import results

    try:
        return int(results.main(argv, parser=Parser) or 0)
    except SystemExit as done:  # --help, or a usage error (already printed as one `error:` line)
        return int(done.code or 0)


def _command(args: argparse.Namespace) -> int:
    from thesis_repro.book import notebooks
    from thesis_repro.core import paths, scales

    check_environment()
    if args.cmd == "list":
        print(list_text())
    elif args.cmd == "figure":
        scales.check_scale(args.scale)
        notebooks.require_book()
        ids = notebooks.notebook_ids(guides=True) if args.figure == "all" else [notebooks.check_notebook(args.figure)]
        params = notebook_parameters(args.parameter, args.scale)
        for folder in (paths.runs_dir(), paths.build_dir(args.scale)):
            check_writable(folder)
        if args.scale != "smoke" and not (args.train or paths.retrain()):
            from thesis_repro.runs import costs as plan

            for nid in ids:
                plan.refuse_training(nid, args.scale)
        for nid in ids:
            notebooks.execute_notebook(nid, args.scale, params)
    elif args.cmd == "plan":
        return _plan_command(args)
    elif args.cmd == "bench":
        return _bench_command(args)
    elif args.cmd in AGENT_COMMANDS:
        return _agent_command(args)
    elif args.cmd == "verify":
        if args.study is not None:
            return _prefix_command(args)
        from thesis_repro.cli import verify

        return verify.main(args)
    elif args.cmd in ("runs", "reference-runs"):
        return _runs_command(args)
    elif args.cmd == "budgets":
        from thesis_repro import figures
        from thesis_repro.runs import budgets

        scales.check_scale(args.scale)
        ids = [figures.get(f).id for f in args.figures] if args.figures else None
        if args.spread:
            cache = budgets.shipped_cache() if args.shipped_only else None
            frame = budgets.spread(budgets.seed_runs(args.scale, args.protocol, args.at, cache, ids, args.algos))
            print(budgets.render_spread(frame, args.at))
            return 0
        if args.protocol is not None or args.at is not None or args.shipped_only or args.algos is not None:
            raise ValueError(
                "--protocol, --at, --algos and --shipped-only go with --spread (budgets --spread --protocol thesis)"
            )
        print(budgets.format_table(budgets.table(args.scale, ids)))
        cost = budgets.retrain_cost(args.scale, ids)
        print("\nRETRAIN=1 cost (measured wall time of the finished runs, 1 core each; upper bounds):")
        print(cost.to_string(index=False, float_format=lambda v: f"{v:.2f}"))
    elif args.cmd == "book":
        from thesis_repro.book import builder as book_mod

        scales.check_scale(args.scale)
        notebooks.require_book()
        for folder in (paths.runs_dir(), paths.build_dir(args.scale)):
            check_writable(folder)
        book_mod.build(args.scale, reuse=args.reuse, force=args.force, shipped_only=args.shipped_only)
    return 0


def _bench_command(args: argparse.Namespace) -> int:
    """``make bench``: run the registered benchmarks; the rates they measure price the cost plan (``plan``)."""
    from thesis_repro.core import bench
    from thesis_repro.runs import throughput

    if args.list:
        for name, target in bench.BENCHMARKS.items():
            print(f"{name:14s} {target}")
        return 0
    written = throughput.write_throughput(bench.run_benchmarks(args.names or None))
    if written is not None:
        print(f"throughput per learner family (steps per CPU-second) -> {written}")
    return 0


#: What "AUC" means, printed under every score (thesis Eq 3.6).
AUC_NOTE = (
    "AUC (thesis Eq 3.6): the area under testing return vs σ, Δσ times the sum of the testing returns over the "
    "σ grid; higher is more robust to the perturbation"
)

#: Subcommands for your own agent (:mod:`thesis_repro.book.agent`).
AGENT_COMMANDS = ("score", "train", "enjoy", "clips")


def _agent_parsers(sub: Any) -> None:
    sc = sub.add_parser("score", help="score SB3 model zips (one per training seed) beside the shipped learners")
    sc.add_argument("models", nargs="+", help="SB3 .zip files saved with model.save (several: training seeds)")
    sc.add_argument("--task", required=True, help="InvertedPendulum | InvertedDoublePendulum | Walker2d | Hopper | ...")
    sc.add_argument("--scale", default="small", help="the book grid of this scale: smoke | small | full")
    sc.add_argument("--algo", default=None, help="the models' SB3 class (ppo, sac, td3, ...; default: detected)")
    sc.add_argument("--label", default="your agent", help="the models' name in the table and figure")
    sc.add_argument("--figure", default=None, metavar="PNG", help="save the Fig 3.4-style comparison here")
    sc.add_argument("--no-compare", action="store_true", help="only your scores, not the shipped learners beside")
    sc.add_argument("--verbose", action="store_true", help="the tables in full, whatever the terminal's width")
    sc.add_argument(
        "--versus", nargs="+", default=None, metavar="LEARNER", help="a paired test of your agent against each"
    )
    tr = sub.add_parser("train", help="train (or load) one chapter-3 run through the run cache")
    tr.add_argument("algo", help="a chapter-3 learner: ppo, trpo, ddpg, sac, ppo-16, ...")
    tr.add_argument("task", help="InvertedPendulum | InvertedDoublePendulum | Walker2d | Hopper | HalfCheetah")
    tr.add_argument("--seed", type=nonneg_int, default=0, help="training seed, >= 0 (default 0)")
    tr.add_argument("--scale", default="small", help="smoke | small | full (the book's budget at that scale)")
    tr.add_argument(
        "--timesteps", type=positive_int, default=None, help="env steps instead of the book's budget (a run of its own)"
    )
    tr.add_argument(
        "--train", action="store_true", help="train a run neither shipped nor cached (without it: its cost, no run)"
    )
    en = sub.add_parser("enjoy", help="watch one episode of a shipped or cached policy, or of an SB3 zip")
    en.add_argument("algo", help="a chapter-3 learner (ppo, trpo, ddpg, sac, ppo-16, ...) or an SB3 model .zip")
    en.add_argument("task", help="InvertedPendulum | InvertedDoublePendulum | Walker2d | Hopper | HalfCheetah")
    en.add_argument("--lean", action="store_true", help="no shadows, reflections or skybox (renders faster)")
    en.add_argument("--size", type=positive_int, default=None, help="frames of SIZE x SIZE pixels (default 480)")
    en.add_argument("--every", type=positive_int, default=1, help="a frame every EVERY steps (default 1)")
    en.add_argument("--human", action="store_true", help="watch in a window instead (needs a display)")
    en.add_argument("--sb3-algo", default=None, help="the SB3 class of a .zip (ppo, sac, ...; default: detected)")
    en.add_argument("--seed", type=nonneg_int, default=0, help="training seed, >= 0 (default 0)")
    en.add_argument("--scale", default="small", help="smoke | small | full")
    en.add_argument("--test", default="none", help="perturbation: none | obs | act | env | dom (default none)")
    en.add_argument("--sigma", type=float, default=0.0, help="its σ (default 0)")
    en.add_argument("--video", default=None, metavar="OUT.mp4", help="write the episode here (.mp4 or .gif)")
    en.add_argument("--episode-seed", type=nonneg_int, default=0, help="seed of the episode (default 0)")
    en.add_argument("--max-steps", type=positive_int, default=None, help="stop after this many steps (default 1000)")
    cl = sub.add_parser("clips", help="render the chapter-3 landing page's clips (build/<scale>/clips)")
    cl.add_argument("--scale", default="small", help="smoke | small | full (the policies of that scale)")
    cl.add_argument("--force", action="store_true", help="render again even if they are up to date")


def _agent_command(args: argparse.Namespace) -> int:
    from thesis_repro.book import agent, clips
    from thesis_repro.core import paths, scales, terminal
    from thesis_repro.core.validation import check_choice

    scales.check_scale(args.scale)
    if args.cmd == "train":
        return _train_command(args)
    elif args.cmd == "clips":
        doc = clips.make_clips(args.scale, force=args.force)
        for c in doc["clips"]:
            what = (
                f"return {c['return']:.1f} in {c['length']} steps ({c['source']} run)"
                if c.get("file")
                else f"no clip: not trained ({c['missing']})"
            )
            print(f"{c['algo']} on {doc['task']} ({doc['test']}, σ {doc['sigma']}): {what}")
        print(f"clips: {clips.clips_dir(args.scale)}")
    elif args.cmd == "enjoy":
        zipped = args.algo.lower().endswith(".zip")
        out = clips.enjoy(
            args.sb3_algo if zipped else args.algo,
            args.task,
            args.seed,
            args.scale,
            test=args.test,
            sigma=args.sigma,
            video=args.video,
            episode_seed=args.episode_seed,
            max_steps=args.max_steps,
            size=args.size,
            every=args.every,
            lean=args.lean,
            model=args.algo if zipped else None,
            human=args.human,
            progress=True,
        )
        where = f"; video: {out['video']}" if out["video"] else ""
        source = out["source"] if zipped else f"{out['source']} run"
        print(
            terminal.wrap(
                f"{args.algo} on {agent.match_task(args.task)} ({args.test}, σ {args.sigma}): return "
                f"{out['return']:.1f} in {out['length']} steps ({source}){where}"
            )
        )
    else:
        from thesis_repro.envs import short_name
        from thesis_repro.evaluation.score import score_model

        task = short_name(args.task)
        if args.no_compare and (args.figure or args.versus):
            raise ValueError("--figure and --versus show the comparison; drop --no-compare")
        for learner in args.versus or ():  # before scoring: a typo costs no time
            check_choice(learner, agent.learner_names(task, args.scale), "learner")
        models = [agent.load_sb3(p, args.algo) for p in args.models]
        if not args.no_compare and (note := paths.reference_note()) is not None:
            raise ValueError(f"{note} (or score with --no-compare)")
        scores = score_model(models, task, args.scale, label=args.label)
        print(str(scores) if args.verbose else terminal.wrap(str(scores)))
        if not args.no_compare:
            steps = [getattr(m, "num_timesteps", 0) for m in models]
            cmp = agent.compare_with_shipped(scores, timesteps=max(steps) if all(steps) else None)
            print()
            print(str(cmp) if args.verbose else terminal.wrap(f"testing AUC, {cmp.ci_label}"))
            if not args.verbose:  # pandas wraps the columns into blocks at the terminal's width
                print(terminal.frame(cmp.wide()))
            for learner in args.versus or ():
                print()
                text = cmp.versus_text(learner)
                print(text if args.verbose else terminal.wrap(text, indent="      "))
            if args.figure:
                cmp.figure.savefig(args.figure, dpi=120)
                print(f"figure: {args.figure}")
        print(terminal.wrap(AUC_NOTE))
    return 0


def _train_command(args: argparse.Namespace) -> int:
    """``train``: load a shipped or cached run, or train it (its cost first, then a progress line with an ETA); a run
    neither shipped nor cached needs ``--train`` (or ``--timesteps``, a budget of the user's) outside ``smoke``."""
    import numpy as np

    from thesis_repro.book import agent
    from thesis_repro.core import paths, terminal
    from thesis_repro.core.cache import RunCache

    job = agent.training_job(args.algo, args.task, args.seed, args.scale, args.timesteps)
    algo, task = job.config["algorithm"], agent.match_task(args.task)
    budget = f", {args.timesteps:,} steps" if args.timesteps else ""
    what = f"{algo} on {task} (seed {args.seed}, scale {args.scale}{budget})"
    cache = RunCache()
    state = cache.state(job)
    if state not in ("shipped", "cached"):
        steps, seconds = agent.train_cost(job)
        status = "interrupted, resumes" if state == "partial" else "neither shipped nor cached"
        cost = f"{steps:,} env steps, about {terminal.duration(seconds)} on one core"
        consent = args.train or args.timesteps is not None or args.scale == "smoke" or paths.retrain()
        if not consent:
            note = paths.reference_note()
            raise ValueError(
                f"{what} is {status}: training it takes {cost}; pass --train to train it, or --timesteps N for "
                f"a budget of your own{f' ({note})' if note else ''}"
            )
        print(terminal.wrap(f"{what}: {status}; training: {cost}"), flush=True)
    with agent.showing_progress(f"train {algo} on {task}"):
        res = cache.run(job)
    tr = res.get("train_return")
    ret = "" if tr is None else f", training return {float(np.mean(tr)):.1f}"
    print(terminal.wrap(f"{what}: {res.source}{ret}"))
    print(res.path)
    return 0


def notebook_parameters(pairs: list[list[str]], scale: str) -> dict[str, Any]:
    """``-p NAME VALUE`` pairs as notebook parameters (values read as YAML: ``3`` is an int, ``[1, 2]`` a list);
    a ``SCALE`` other than ``scale`` is a ``ValueError``.

    >>> notebook_parameters([["SEEDS", "3"], ["SCALE", "smoke"]], "smoke")
    {'SEEDS': 3}
    """
    import yaml

    from thesis_repro.book import notebooks
    from thesis_repro.core import yamlfile

    params: dict[str, Any] = {}
    for name, text in pairs:
        try:
            params[name] = yamlfile.parse(text)
        except yaml.YAMLError:
            params[name] = text
    return notebooks.check_parameters(params, scale)


def check_jobs() -> int | None:
    """``THESIS_REPRO_JOBS`` (worker processes; set by ``--jobs``) as an int, ``None`` if unset; anything but
    an integer >= 1 is a ``ValueError``.

    >>> os.environ["THESIS_REPRO_JOBS"] = "two"; check_jobs()
    Traceback (most recent call last):
    ...
    ValueError: THESIS_REPRO_JOBS: invalid value 'two'; valid values are integers >= 1 (unset: one per core)
    >>> del os.environ["THESIS_REPRO_JOBS"]
    """
    text = os.environ.get("THESIS_REPRO_JOBS")
    if text is None:
        return None
    try:
        return positive_int(text.strip())
    except argparse.ArgumentTypeError:
        raise ValueError(
            f"THESIS_REPRO_JOBS: invalid value {text!r}; valid values are integers >= 1 (unset: one per core)"
        ) from None


def check_environment() -> None:
    """The kit's environment settings (``make ... RETRAIN=1 BACKEND=ray``, ``THESIS_REPRO_JOBS``) are valid
    before anything runs: a typo is a one-line error here, not a traceback inside a notebook's kernel."""
    from thesis_repro.core import backends, paths

    paths.retrain()
    backends.backend()
    check_jobs()


def list_text(cols: int | None = None) -> str:
    """What ``list`` prints, within ``cols`` columns (default: the terminal's): the scales, every figure and
    table with its title, the other notebooks, and where the notebooks and the shipped runs are when this install
    has none."""
    from thesis_repro import figures
    from thesis_repro.book import notebooks
    from thesis_repro.core import paths, scales, terminal

    lines = [f"scales: {', '.join(scales.SCALES)}", "figures and tables (python -m thesis_repro figure ID):"]
    lines += [f"  {fid:<10} {figures.get(fid).title}" for fid in figures.ids()]
    if paths.NOTEBOOKS.is_dir():
        other = [n for n in notebooks.notebook_ids(guides=True) if figures.FIGURES.get(n) is None]
        lines.append(f"other pages: {', '.join(other)}")
    else:
        lines.append("notebooks: none in this install (they ship with the kit's clone; `figure` and `book` need it)")
    if (note := paths.reference_note()) is not None:
        lines.append(note)
    return terminal.wrap("\n".join(lines), cols)


def _plan_command(args: argparse.Namespace) -> int:
    from thesis_repro import figures
    from thesis_repro.core import scales
    from thesis_repro.runs import budget_study, throughput
    from thesis_repro.runs import costs as plan

    study = args.figure in budget_study.STUDIES
    args.scale = scales.check_scale(args.scale or ("small" if study else "full"))
    if not study and args.figure not in ("all", "order") and args.figure.removeprefix("fig-") not in figures.FIGURES:
        named = ", ".join(f"'{f}'" for f in figures.ids())
        studies = ", ".join(f"'{s}'" for s in budget_study.STUDIES)
        raise ValueError(
            f"unknown figure {args.figure!r}; valid figures are: {named}; or 'all', 'order', a budget study: {studies}"
        )
    if study and (args.envs or args.algos or args.seeds):
        raise ValueError(f"plan {args.figure} prices the whole study; --envs/--algos/--seeds subset a figure's jobs")
    if args.figure == "order" and (args.envs or args.algos):
        raise ValueError("plan order ranks whole items; --envs/--algos choose a subset of one figure")
    if args.figure == "order" and not args.seeds:
        raise ValueError("plan order needs --seeds: the seeds to add, such as --seeds 3 4 5")
    if (args.rates or ("shipped" if args.figure == "order" else "bench")) == "shipped":
        from thesis_repro.core.provenance import platform_info

        rates = throughput.shipped_rates(by_env=True, machine=platform_info())
    else:
        rates = throughput.load_rates()
    print(throughput.rates_note(rates))
    if study:
        print(_study_plan(args.figure, args.scale, args.cores, rates, args.missing))
        return 0
    if args.figure == "order":
        from thesis_repro.runs import order

        print(order.order_report(_order_plan(args.scale, args.seeds, rates, args.missing)))
        return 0
    subset = {k: v for k, v in (("envs", args.envs), ("algos", args.algos)) if v is not None}
    if args.figure != "all":
        p = plan.plan_figure(args.figure, args.scale, args.cores, rates, args.missing, args.seeds, **subset)
        print(plan.cost_report(p, rates))
        return 0
    if subset:
        raise ValueError("--envs/--algos choose a subset of one figure; name it (plan 3.3 --algos ppo trpo)")
    per, book = plan.plan_book(args.scale, args.cores, rates, args.missing, args.seeds)
    for p in per:
        print(plan.plan_summary(p))
    print("\nthe book (every figure; runs shared by figures counted once):")
    print(plan.cost_report(book, rates))
    return 0


def _ledger_claims(scale: str) -> list[Any]:
    """The claims as the generator's order sees them (:func:`thesis_repro.runs.order.claims_from`), from the claims
    ledger at ``scale`` (judged from saved numbers, calibration from the caches and the shipped snapshot)."""
    from thesis_repro.claims import ledger, registry
    from thesis_repro.runs import order

    rows = ledger.ledger(scale)
    return order.claims_from({**r.as_dict(), "pages": sorted(registry.pages_read(r.spec))} for r in rows)


def _study_order(name: str, scale: str, rates: Any, kinds: Any = ("train", "evaluate")) -> list[Any]:
    """A budget study's jobs in the generator's order (:func:`thesis_repro.runs.budget_study.ordered`), its items ranked
    by the claims of the ledger at ``small`` (whose calibration the study's seeds are judged by)."""
    from thesis_repro.runs import budget_study

    budget_study.check_study(name)
    return budget_study.ordered(scale, rates, _ledger_claims("small"), kinds)


#: Training runs of a study's order listed by ``plan <study>`` (the rest is counted).
ORDER_SHOWN = 12


def _study_plan(name: str, scale: str, cores: int | None, rates: Any, missing: bool) -> str:
    """``plan thesis-budget``: the study's price (every job, or with ``missing`` those neither cached nor shipped,
    and how many are left) and the first training runs of its order (with ``missing``, of the runs left, each at its
    work left)."""
    from thesis_repro.core.cache import RunCache
    from thesis_repro.runs import budget_study, throughput
    from thesis_repro.runs import costs as plan

    budget_study.check_study(name)
    jobs = budget_study.budget_jobs(scale)
    cache = RunCache() if missing else None
    p = plan.plan_jobs(name, jobs, scale, cores or os.cpu_count() or 1, rates, cache)
    lines = [plan.cost_report(p, rates), budget_study.size_line(budget_study.size_estimate(scale))]
    if missing:
        lines.append(
            f"{name} ({scale}): {p.n_jobs:,} jobs left of {len(jobs):,} ({p.n_train:,} training runs, "
            f"{p.n_other:,} evaluations)"
        )
    ordered = [q.job for q in _study_order(name, scale, rates, ("train",))]
    if cache is not None:
        ordered = plan.to_compute(ordered, cache)
    rows, total = [], 0.0
    for i, j in enumerate(ordered[:ORDER_SHOWN], 1):
        w = throughput.work(j) if cache is None else throughput.work_left(j, cache)
        total += (h := plan.core_hours(w, throughput.job_rate(j, rates)))
        rows.append({"#": str(i), "run": j.label, "core-hours": f"{h:,.2f}", "total": f"{total:,.1f}"})
    lines.append(
        f"the generator's order (`make {name}`{', the runs left, each at its work left' if missing else ''}): the "
        "Pareto panels' tasks first, within a task the items that read its runs by claims settled per core-hour, each "
        "item's runs cheapest first; each run's evaluations follow it"
    )
    lines.append(plan.text_table(rows, ("#", "run", "core-hours", "total")) if rows else "no training runs left")
    if len(ordered) > ORDER_SHOWN:
        lines.append(f"... {len(ordered) - ORDER_SHOWN} more training runs")
    return "\n".join(lines)


def _prefix_command(args: argparse.Namespace) -> int:
    """``verify --study thesis-budget``: the study's free integrity check
    (:func:`~thesis_repro.runs.budget_study.prefix_checks`; exit code 1 if a run that must be bit-identical is not)."""
    from thesis_repro.core import scales
    from thesis_repro.runs import budget_study
    from thesis_repro.runs import costs as plan

    budget_study.check_study(args.study)
    scales.check_scale(args.scale)
    checks = budget_study.prefix_checks(args.scale)
    rows = [{"run": c.label, "status": c.status, "detail": c.detail} for c in checks]
    print(plan.text_table(rows, ("run", "status", "detail")))
    counts = {s: sum(c.status == s for c in checks) for s in dict.fromkeys(c.status for c in checks)}
    print(f"{args.study} ({args.scale}): " + ", ".join(f"{n} {s}" for s, n in counts.items()))
    return 1 if any(c.failed for c in checks) else 0


def _order_plan(
    scale: str, seeds: list[int], rates: Any, missing: bool = False, figure_ids: list[str] | None = None
) -> Any:
    """The generator's order (:func:`thesis_repro.runs.order.confirmatory_plan`) from the claims ledger at ``scale``
    (judged from saved numbers, calibration from the caches and the shipped snapshot)."""
    from thesis_repro.runs import order

    return order.confirmatory_plan(scale, seeds, _ledger_claims(scale), rates, missing, figure_ids)


def _of_learners(queue: list[Any], algos: Sequence[str] | None) -> list[Any]:
    """The ``queue``'s jobs (training runs and their evaluations) of the learners ``algos``, in order; all without."""
    from thesis_repro.runs.needs import job_algorithm

    return [q for q in queue if job_algorithm(q.job) in algos] if algos else queue


def _study_runs(args: argparse.Namespace) -> int:
    """``reference-runs --study thesis-budget``: the study's jobs (default kinds: train and evaluate, each run's
    evaluations as soon as it is shipped) in its order, through the generator (``--commit``, ``--until``, ``--jobs``
    as for the figures; ``--algos``: only those learners' runs, in the same order, so two commands can split the
    study, SAC's long runs on one core and the rest on the other). Outside ``smoke`` it refuses to start before
    the claims design it is judged under is frozen (:func:`thesis_repro.runs.budget_study.check_design`)."""
    from thesis_repro.core import paths
    from thesis_repro.core.provenance import claims_design, platform_info
    from thesis_repro.core.validation import check_choice
    from thesis_repro.runs import budget_study, generator, throughput

    budget_study.check_study(args.study)
    given = [f"--{k}" for k in ("figures", "seeds") if getattr(args, k)]
    if given or args.order != "seed-first":
        drop = ", ".join(given) or "--order"
        raise ValueError(f"--study {args.study} makes the whole study in its own order; drop {drop}")
    learners = budget_study.variants(budget_study.budget_settings(args.scale))
    for algo in args.algos or ():
        check_choice(algo, learners, f"{args.study} learner")
    if args.scale != "smoke":
        budget_study.check_design(claims_design())
    for folder in (paths.runs_dir(), paths.reference()):
        check_writable(folder)
    kinds = args.kind or ("train", "evaluate")
    rates = throughput.shipped_rates(by_env=True, machine=platform_info())
    jobs = _of_learners(_study_order(args.study, args.scale, rates, kinds), args.algos)
    until = generator.parse_until(args.until) if args.until is not None else None
    generator.generate(args.scale, None, kinds, commit=args.commit, n_jobs=args.jobs or 1, until=until, jobs=jobs)
    return 0


def _runs_command(args: argparse.Namespace) -> int:
    import json

    from thesis_repro import figures
    from thesis_repro.core import paths, scales
    from thesis_repro.runs import costs as plan
    from thesis_repro.runs import generator, shipped_checks, throughput
    from thesis_repro.runs import layer as runs

    scales.check_scale(args.scale)
    if args.cmd == "reference-runs" and args.study is not None:
        return _study_runs(args)
    if args.cmd == "reference-runs":
        from thesis_repro.core.validation import check_choice
        from thesis_repro.learners.config import ALGORITHMS

        check_choice(args.order, (*generator.ORDERS, "claims"), "order")
        for folder in (paths.runs_dir(), paths.reference()):
            check_writable(folder)
        kinds = args.kind or figures.TRAINING_KINDS
        for algo in args.algos or ():
            check_choice(algo, ALGORITHMS, "algorithm")
        only: dict[str, Any] = {"algos": args.algos, "seeds": args.seeds, "order": args.order}
        until = generator.parse_until(args.until) if args.until is not None else None
        figure_ids = args.figures
        if args.order == "claims":
            from thesis_repro.core.provenance import platform_info
            from thesis_repro.runs import order

            if not args.seeds:
                raise ValueError("--order claims needs --seeds: the seeds to add, such as --seeds 3 4 5")
            rates = throughput.shipped_rates(by_env=True, machine=platform_info())
            ranked = _order_plan(args.scale, args.seeds, rates, missing=True, figure_ids=args.figures)
            print(order.order_report(ranked), flush=True)
            figure_ids = order.item_order(ranked)
            only.update(order="item", item_seeds={f: order.item_seeds(f, args.seeds) for f in figure_ids})
        n_jobs = args.jobs or 1
        generator.generate(args.scale, figure_ids, kinds, commit=args.commit, n_jobs=n_jobs, until=until, **only)
        return 0
    if args.compact:
        check_writable(paths.reference())
        done = runs.compact_shipped()
        before, after = sum(b for b, _ in done.values()), sum(a for _, a in done.values())
        print(f"{len(done)} shipped training runs compacted: arrays {before / 1e6:.2f} MB -> {after / 1e6:.2f} MB")
        return 0
    if args.check:
        from thesis_repro.runs import studies

        stale = shipped_checks.check_shipped(args.scale, also=studies.keys(args.scale, protocol=True))
        corrupt, local = shipped_checks.verify_shipped(), shipped_checks.verify_local()
        for s in stale:
            print(s.message)
        for path, err in corrupt.items():
            print(f"corrupt shipped run {path}: {err}")
        for path, err in local.items():
            print(f"corrupt local run {path}: {err} (removed and recomputed when a figure next needs it)")
        print(
            f"{len(runs.shipped_entries())} shipped runs: {len(stale)} stale, {len(corrupt)} corrupt; "
            f"{len(runs.local_entries())} local runs ({paths.runs_dir()}): {len(local)} corrupt"
        )
        return 1 if stale or corrupt or local else 0
    from thesis_repro.core import terminal

    ids = figures.ids() if args.figure == "all" else [figures.get(args.figure).id]
    for fid in ids:
        rows = runs.run_rows(fid, args.scale)
        if args.json:
            print(json.dumps({"figure": fid, "scale": args.scale, "runs": rows}, indent=1))
            continue
        train = [j for j in figures.jobs(fid, args.scale) if j.kind in figures.TRAINING_KINDS]
        line = runs.summary(train, verify=True) if train else "no training runs"
        print(terminal.wrap(f"{figures.get(fid).notebook_id} ({args.scale}): {line}"))
        if args.verbose:  # every run, in full
            print(plan.text_table(rows) + "\n")
        else:
            print(terminal.fit(runs.rows_summary(rows)) + "\n")
    if not (args.json or args.verbose):
        print(terminal.wrap("every run with its key and folder: --verbose; as JSON: --json"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
