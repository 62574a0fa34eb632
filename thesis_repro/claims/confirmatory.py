"""The confirmatory check: a claim's frozen rule (design v3's, seed-keyed; v2's beside it) on the fresh training seeds
alone.

Design v2 was frozen (``data/thesis/claims-design.json``) while only seeds 0-2 existed: those are the seeds the
rules were designed on (v3 changes how v2's levels and margins are tested, not what they are). Every seed from
:data:`FIRST_FRESH` on was generated after the freeze (3-5 in chapters 3-4, 3-9 for chapter 5's CMA-ES figures). A
claim's primary verdict judges every seed its pages saved; beside it, the confirmatory verdict judges the fresh
seeds alone with the same rule, once the pages hold at least :data:`FRESH_SEEDS`, so a reader sees whether a verdict
also holds on data the rules never saw. The two *disagree* when they lean opposite ways (:func:`disagrees`): one on
the side of "reproduces" (*reproduces*, *at least partly*), the other on the side of "does not" (*does not
reproduce*, *at most partly*). A weaker confirmatory verdict on the same side (e.g. *inconclusive* beside
*reproduces*) is not a disagreement: three seeds say less than six.

>>> frames = {"aucs": pd.DataFrame({"seed": [0, 1, 2, 3, 4, 5, 6], "value": range(7)})}
>>> fresh_frames(frames)["aucs"]["seed"].tolist()
[3, 4, 5, 6]
>>> fresh_frames({"aucs": pd.DataFrame({"seed": [0, 1, 2], "value": range(3)})}) is None
True
>>> disagrees("reproduces", "at most partly"), disagrees("reproduces", "inconclusive")
(True, False)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import pandas as pd

from thesis_repro.claims import report

#: The first seed generated after design v2 was frozen: the confirmatory check judges seeds from here on alone.
FIRST_FRESH = 3
#: The fresh seeds in words.
FRESH_WORDS = f"the fresh seeds ({FIRST_FRESH} and above, trained after the design was frozen)"
#: The fresh seeds a page must hold before its claims get a confirmatory verdict (the issue's 3 fresh seeds).
FRESH_SEEDS: tuple[int, ...] = (3, 4, 5)

#: Which way a label leans: +1 towards "reproduces", -1 towards "does not", 0 neither (or not a verdict).
SIDE: dict[str, int] = {
    report.REPRODUCES: 1,
    report.AT_LEAST_PARTLY: 1,
    report.DOES_NOT: -1,
    report.AT_MOST_PARTLY: -1,
}


def seeds_in(frames: Mapping[str, pd.DataFrame]) -> set[int]:
    """Every training seed in ``frames`` (their ``seed`` columns)."""
    return {int(s) for f in frames.values() if "seed" in f.columns for s in f["seed"].dropna().unique()}


def fresh_seeds(frames: Mapping[str, pd.DataFrame]) -> tuple[int, ...]:
    """The fresh seeds in ``frames`` (:data:`FIRST_FRESH` on), sorted."""
    return tuple(sorted(s for s in seeds_in(frames) if s >= FIRST_FRESH))


def fresh_frames(
    frames: Mapping[str, pd.DataFrame], seeds: Sequence[int] | None = None
) -> dict[str, pd.DataFrame] | None:
    """``frames`` restricted to the rows of ``seeds`` (default: every fresh seed, :func:`fresh_seeds`; frames
    without a ``seed`` column unchanged), or None when they do not hold every seed asked for, or by default
    every one of :data:`FRESH_SEEDS` (the page still reads the design seeds only)."""
    have = seeds_in(frames)
    keep = set(fresh_seeds(frames)) if seeds is None else {int(s) for s in seeds}
    if not (keep <= have and (seeds is not None or set(FRESH_SEEDS) <= keep)):
        return None
    return {k: f[f["seed"].isin(keep)].reset_index(drop=True) if "seed" in f.columns else f for k, f in frames.items()}


def seed_range(seeds: Sequence[int]) -> str:
    """``3-5`` for seeds 3, 4, 5 (``3, 5`` when not consecutive)."""
    s = sorted(seeds)
    return f"{s[0]}-{s[-1]}" if s == list(range(s[0], s[-1] + 1)) and len(s) > 1 else ", ".join(map(str, s))


def disagrees(primary: str, confirmatory: str) -> bool:
    """Whether the two verdicts lean opposite ways (:data:`SIDE`)."""
    return SIDE.get(primary, 0) * SIDE.get(confirmatory, 0) < 0


@dataclass
class Confirmation:
    """A claim's confirmatory verdict: its label on :data:`FRESH_SEEDS` alone (design v3's statistical label, v2's
    beside it), the key number, and whether it disagrees with the primary verdict on every seed."""

    status: str
    ours: str
    primary: str
    seeds: tuple[int, ...] = FRESH_SEEDS  # the fresh seeds judged
    v2: str = ""  # design v2's label on the same seeds ("" when not judged by it)

    @property
    def disagrees(self) -> bool:
        return disagrees(self.primary, self.status)

    def line(self) -> str:
        """One line for the page and the terminal, e.g. ``fresh seeds 3-5: reproduces (v2: same) · ours: 4/5 units
        yes``."""
        flag = " (DISAGREES with the primary verdict)" if self.disagrees else ""
        beside = f" ({v2_words(self.status, self.v2)})" if self.v2 else ""
        ours = f" · ours: {self.ours}" if self.ours else ""
        return f"fresh seeds {seed_range(self.seeds)}: {self.status}{beside}{flag}{ours}"

    def as_dict(self) -> dict[str, Any]:
        return {
            "seeds": list(self.seeds),
            "verdict": self.status,
            "v2_verdict": self.v2 or self.status,
            "ours": self.ours,
            "disagrees": self.disagrees,
        }


def v2_words(v3: str, v2: str) -> str:
    """Design v2's label beside v3's, in a few words.

    >>> v2_words("reproduces", "reproduces"), v2_words("inconclusive", "at least partly")
    ('v2: same', 'v2: at least partly')
    """
    return "v2: same" if v2 == v3 else f"v2: {v2}"


# ---------------------------------------------------------------- wording over the ledger's JSON claims
def fresh_verdict(claim: Mapping[str, Any]) -> str | None:
    """A ``claims --json`` claim's confirmatory verdict, None before its fresh seeds are shipped."""
    c = claim.get("confirmatory")
    return str(c["verdict"]) if isinstance(c, Mapping) and c.get("verdict") else None


def did_not_hold(claim: Mapping[str, Any]) -> bool:
    """Whether the claim did not hold up on the fresh seeds: their verdict leans towards "does not"."""
    return SIDE.get(fresh_verdict(claim) or "", 0) < 0


def fresh_summary(claims: Sequence[Mapping[str, Any]]) -> str:
    """One plain sentence: which thesis claims did not hold up on the fresh seeds (or that none did, or that no
    claim has been judged on them yet), and which fresh verdicts lean against their primary verdict.

    >>> print(fresh_summary([{"id": "a"}]))
    No thesis claim has been judged on the fresh seeds (3 and above, trained after the design was frozen) yet: no \
claim's pages hold them (0 of 1).
    >>> fresh_summary([{"id": "a", "confirmatory": {"verdict": "does not reproduce", "disagrees": True}},
    ...                {"id": "b", "confirmatory": {"verdict": "reproduces", "disagrees": False}}])
    'On the fresh seeds (3 and above, trained after the design was frozen), 2 of 2 claims judged: 1 thesis claim \
did not hold up: `a` (does not reproduce; it disagrees with its verdict on every seed).'
    """
    judged = [c for c in claims if fresh_verdict(c)]
    if not judged:
        return f"No thesis claim has been judged on {FRESH_WORDS} yet: no claim's pages hold them (0 of {len(claims)})."
    failed = [c for c in judged if did_not_hold(c)]
    other = [c for c in judged if c["confirmatory"].get("disagrees") and not did_not_hold(c)]
    head = f"On {FRESH_WORDS}, {len(judged)} of {len(claims)} claims judged: "

    def item(c: Mapping[str, Any]) -> str:
        why = "; it disagrees with its verdict on every seed" if c["confirmatory"].get("disagrees") else ""
        return f"`{c.get('id')}` ({fresh_verdict(c)}{why})"

    if failed:
        n = len(failed)
        text = head + f"{n} thesis claim{'s' if n > 1 else ''} did not hold up: " + ", ".join(map(item, failed)) + "."
    else:
        text = head + "every thesis claim judged held up or stayed open (none leans towards 'does not')."
    if other:
        text += " Leaning the other way from their verdict on every seed: " + ", ".join(map(item, other)) + "."
    return text
