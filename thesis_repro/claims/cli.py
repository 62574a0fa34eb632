"""``python -m thesis_repro claims --scale small [--json]``: the claims ledger from saved results, no training.

Each claim is judged from the per-seed numbers its page saved when its notebook ran
(``build/<scale>/figures/<page>.data.json``); a claim whose page has not run at that scale is reported as
*not computed* (nothing is trained or evaluated here).

>>> main(["--scale", "smoke", "--ids", "3.3-negative-correlation"])  # doctest: +ELLIPSIS
3.3-negative-correlation ...
0
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings

from thesis_repro.scales import SCALES


def main(argv: list[str] | None = None) -> int:
    """Print the ledger (one line per claim, or ``--json``); returns the exit code."""
    from thesis_repro.claims import ledger

    warnings.simplefilter("ignore", RuntimeWarning)  # NaN means of cells a scale does not run

    ap = argparse.ArgumentParser(prog="python -m thesis_repro claims", description=__doc__.split("\n")[0])
    ap.add_argument("--scale", default="small", choices=list(SCALES))
    ap.add_argument("--json", action="store_true", help="the whole ledger as JSON")
    ap.add_argument("--ids", nargs="*", help="only these claim ids")
    ap.add_argument("--no-null", action="store_true", help="skip the null pass rates (faster)")
    args = ap.parse_args(argv)
    specs = [s for s in ledger.specs() if not args.ids or s.id in args.ids]
    rows = sorted((ledger.judge(s, args.scale, not args.no_null) for s in specs), key=lambda r: r.spec.beyond)
    for hint in (ledger.not_computed_hint(rows, args.scale), ledger.stale_hint(ledger.stale_pages(rows), args.scale)):
        if hint:
            print(hint, file=sys.stderr)
    if args.json:
        json.dump(ledger.as_json(rows), sys.stdout, indent=1, ensure_ascii=False)
        print()
        return 0
    for r in rows:
        tag = " [beyond the thesis]" if r.spec.beyond else ""
        print(
            f"{r.spec.id} ({r.spec.page}, l. {','.join(map(str, r.spec.lines)) or '-'}){tag}: {r.status.upper()}"
            f" - {ledger.describe(r)}"
        )
    c = ledger.counts(rows)
    print("distinct thesis claims: " + ", ".join(f"{v} {ledger.SHORT.get(k, k)}" for k, v in c.items()))
    b = ledger.counts(rows, beyond=True)
    if b:
        print("beyond the thesis: " + ", ".join(f"{v} {ledger.SHORT.get(k, k)}" for k, v in b.items()))
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
