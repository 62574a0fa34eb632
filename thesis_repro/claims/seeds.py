"""Per-seed values that remember their training seeds: the key every v3 statistic joins on.

A :class:`Seeded` is a tuple of floats (so design v2's code, which pairs values by position, reads it unchanged)
that also carries the training seed of each value. Design v3 (:mod:`thesis_repro.claims.stats_v3`) joins two sides,
the units of a pooled test and the fresh-seeds subset by these seeds: a missing value is a missing seed, never a
shift of the others.

>>> x = Seeded((1.0, 3.0), (0, 2))
>>> x, x.seeds, series(x)
((1.0, 3.0), (0, 2), {0: 1.0, 2: 3.0})
>>> seeds_of((5.0, 6.0))
(0, 1)
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any


class Seeded(tuple):
    """A tuple of per-seed floats with ``seeds``: the training seed of each value (same length, distinct)."""

    seeds: tuple[int, ...]

    def __new__(cls, values: Iterable[float], seeds: Iterable[int]) -> Seeded:
        obj = super().__new__(cls, (float(v) for v in values))
        obj.seeds = tuple(int(s) for s in seeds)
        if len(obj.seeds) != len(obj) or len(set(obj.seeds)) != len(obj.seeds):
            raise ValueError(f"Seeded: {len(obj)} values need as many distinct seeds, got {obj.seeds}")
        return obj

    def __reduce__(self) -> tuple[Any, ...]:
        return (Seeded, (tuple(self), self.seeds))


def seeded(values: Mapping[int, float]) -> Seeded:
    """A :class:`Seeded` from ``{seed: value}`` (sorted by seed).

    >>> seeded({3: 1.0, 1: 2.0}).seeds
    (1, 3)
    """
    keys = sorted(values)
    return Seeded((values[k] for k in keys), keys)


def seeds_of(x: Sequence[float] | None) -> tuple[int, ...]:
    """The seeds of ``x``: its own when it is :class:`Seeded`, else positions (a value with no seed record)."""
    if x is None:
        return ()
    return getattr(x, "seeds", None) or tuple(range(len(x)))


def series(x: Sequence[float] | None) -> dict[int, float]:
    """``{seed: value}`` of the finite values of ``x``, by increasing seed (a missing or NaN value is a missing
    seed; the order of ``x`` never matters)."""
    if x is None:
        return {}
    return {s: float(v) for s, v in sorted(zip(seeds_of(x), x, strict=True)) if math.isfinite(float(v))}


def joined(a: Sequence[float], b: Sequence[float]) -> tuple[list[int], list[float], list[float]]:
    """The seeds both ``a`` and ``b`` hold (finite), with each side's value at those seeds.

    >>> joined(Seeded((1.0, 2.0, 3.0), (0, 1, 2)), Seeded((5.0, 7.0), (0, 2)))
    ([0, 2], [1.0, 3.0], [5.0, 7.0])
    """
    sa, sb = series(a), series(b)
    keys = sorted(set(sa) & set(sb))
    return keys, [sa[k] for k in keys], [sb[k] for k in keys]
