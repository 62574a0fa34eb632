"""``python -m thesis_repro claims --scale small [--json]``: the claims ledger from saved results, no training.

Each claim is judged from the per-seed numbers its page saved when its notebook ran
(``build/<scale>/figures/<page>.data.json``), or, where this build has none (a fresh clone before its book),
from the shipped claims snapshot (:mod:`thesis_repro.claims.snapshot`, said on stderr); a claim whose page has
neither at that scale is reported as *not computed* (nothing is trained or evaluated here). ``--ship`` (``make
ship-claims``) refreshes the snapshot from this build's pages.

>>> main(["--scale", "smoke", "--ids", "3.3-negative-correlation"])  # doctest: +ELLIPSIS
not ... · 3.3-negative-correlation · l. 555 negative correlation · thesis: ...
distinct thesis claims: 1 not ...
0
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from collections.abc import Sequence

from thesis_repro.claims import design, evidence, ledger, ledger_row, registry, scoreboard, snapshot, thesis_budget
from thesis_repro.core.scales import SCALES


def main(argv: list[str] | None = None) -> int:
    """Print the ledger (one line per claim, or ``--json``); returns the exit code."""
    warnings.simplefilter("ignore", RuntimeWarning)  # NaN means of cells a scale does not run

    ap = argparse.ArgumentParser(prog="python -m thesis_repro claims", description=__doc__.split("\n")[0])
    ap.add_argument("--scale", default="small", choices=list(SCALES))
    ap.add_argument("--json", action="store_true", help="the whole ledger as JSON")
    ap.add_argument("--ids", nargs="*", help="only these claim ids")
    ap.add_argument(
        "--no-null",
        action="store_true",
        help="skip calibration (faster): design v3's statistical labels, before its calibration gate",
    )
    ap.add_argument(
        "--ship",
        action="store_true",
        help="copy this build's saved page numbers into the shipped claims snapshot (after `make book`)",
    )
    ap.add_argument(
        "--check-snapshot",
        action="store_true",
        help="compare this build's saved page numbers with the shipped snapshot (after `make book`); 1 if any differ",
    )
    ap.add_argument("--verbose", action="store_true", help="each verdict's evidence under its one line")
    ap.add_argument(
        "--freeze",
        action="store_true",
        help="freeze the claims design (data/thesis/claims-design.json); refused when it would change a frozen "
        "version's rules",
    )
    args = ap.parse_args(argv)
    if args.freeze:
        broken = design.check_frozen() if design.frozen().get("version") == design.VERSION else []
        if broken:
            print(
                f"error: design {design.VERSION} is frozen and this would change it ({'; '.join(broken[:3])}); "
                "bump thesis_repro.claims.design.VERSION for a new design version",
                file=sys.stderr,
            )
            return 2
        d = design.freeze()
        print(f"froze design {d['version']} ({d['hash'][:12]}): {len(d['rules'])} rules")
        return 0
    if args.check_snapshot:
        got = snapshot.check(args.scale)
        for name, verdict in got.items():
            print(f"{name}: {verdict}")
        same = sum(v == "identical" for v in got.values())
        print(
            f"{same}/{len(got)} saved files identical to the shipped snapshot ({snapshot.snapshot_source(args.scale)})"
        )
        return 0 if same == len(got) else 1
    if args.ship:
        try:
            changed = snapshot.ship(args.scale)
        except ValueError as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
        where = ledger.ship_calibration(args.scale)
        print(f"shipped the claims' calibration and power to {where}")
        print(
            f"shipped {len(snapshot.files())} saved file(s) to {snapshot.snapshot_source(args.scale)}; "
            f"{len(changed)} data file(s) changed" + (f": {', '.join(changed)}" if changed else "")
        )
        return 0
    specs = [s for s in registry.specs() if not args.ids or s.id in args.ids]
    rows = sorted((ledger.judge(s, args.scale, not args.no_null) for s in specs), key=lambda r: r.spec.beyond)
    hints = (
        scoreboard.shipped_hint(rows, args.scale),
        scoreboard.not_computed_hint(rows, args.scale),
        scoreboard.stale_hint(ledger_row.stale_pages(rows), args.scale),
    )
    for hint in hints:
        if hint:
            print(hint, file=sys.stderr)
    if args.json:
        json.dump(scoreboard.as_json(rows, args.scale), sys.stdout, indent=1, ensure_ascii=False)
        print()
        return 0
    print("\n".join(ledger_lines(rows, args.verbose)))
    return 0


def ledger_lines(rows: Sequence[ledger_row.Row], verbose: bool = False) -> list[str]:
    """The ledger on the terminal: a line per claim (its fresh seeds' verdict under it, where they are shipped;
    ``verbose``: v1's verdict and the evidence), then the counts, on the fresh seeds alone too."""
    out, beyond = [], False
    for r in rows:
        if r.spec.beyond and not beyond:
            beyond = True
            out.append("beyond the thesis (the kit's own extensions, counted apart):")
        out.append(ledger_row.headline(r, width=160))
        if r.confirmation:
            out.append(f"    {r.confirmation.line()}")
        if r.thesis_budget:
            out.append(f"    {r.thesis_budget.get('line') or thesis_budget.thesis_budget_line(r.thesis_budget)}")
        if verbose:
            gate = f" ({r.v3['reason']})" if r.v3.get("reason") else ""
            before = f"v2: {r.v2_status or r.status}; v1: {r.v1_status or r.status}"
            out.append(f"    {before}{gate}; {evidence.describe(r)}")
            if r.subset:
                out.append(f"    {r.subset['line']}")
    c = scoreboard.counts(rows)
    out.append("distinct thesis claims: " + ", ".join(f"{v} {scoreboard.SHORT.get(k, k)}" for k, v in c.items()))
    if any(r.confirmation for r in rows):
        fresh = sorted(scoreboard.confirmatory_counts(rows).items(), key=scoreboard.fresh_order)
        out.append(
            "on the fresh seeds alone (confirmatory, the same frozen rules): "
            + ", ".join(f"{v} {scoreboard.SHORT.get(k, k)}" for k, v in fresh)
        )
    b = scoreboard.counts(rows, beyond=True)
    if b:
        out.append("beyond the thesis: " + ", ".join(f"{v} {scoreboard.SHORT.get(k, k)}" for k, v in b.items()))
    return out


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
