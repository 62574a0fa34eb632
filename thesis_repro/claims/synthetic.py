"""Synthetic per-seed frames of every page schema, with no effect anywhere (for null calibration and tests).

Every learner, condition and strategy draws from one distribution, so no claim is true in them except by
chance. :func:`frames` returns every frame name a measure reads (and the ``name@page`` keys of claims that
read several pages).

>>> f = frames(3, seed=0)
>>> sorted(f)[:3], f["aucs"]["seed"].nunique()
(['aucs', 'catch', 'curve'], 3)
"""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd

ENVS = ("Walker2d", "Hopper", "HalfCheetah", "InvertedPendulum", "InvertedDoublePendulum")
TESTS = ("obs", "act", "env", "dom")
METHODS = (
    "ppo", "trpo", "ddpg", "sac", "ppo-obsnoise", "ppo-actnoise", "ppo-envnoise", "ppo-mdl", "ppo-16", "ppo-scn",
    "ppo-scn-16", "ppo-ent", "ppo-arpl", "ppo-epopt", "ppo-maml-dg", "ppo-reptile-dg",
)  # fmt: skip
ALGOS4 = ("kl_avg", "kl_exact", "params_avg", "joint")
FAMILIES = ("reach", "throw", "bic", "cast")
STRATEGIES = ("scratch", "direct", "matrix", "tensor", "ella", "rbf-ella", "fcnn")


def frames(n_seeds: int = 3, seed: int = 0) -> dict[str, pd.DataFrame]:
    """Every frame of every page, ``n_seeds`` training seeds, no effect of learner / condition / strategy."""
    rng = np.random.default_rng(seed)
    seeds = range(n_seeds)
    n = lambda k, loc=100.0, sd=10.0: loc + sd * rng.standard_normal(k)  # noqa: E731
    rows = list(itertools.product(ENVS, TESTS, METHODS, seeds))
    aucs = pd.DataFrame(rows, columns=["env", "test", "method", "seed"]).assign(value=n(len(rows)))
    rows = list(itertools.product(ENVS, METHODS, TESTS, (0.0, 0.2, 0.4), seeds))
    returns = pd.DataFrame(rows, columns=["env", "method", "test", "sigma", "seed"]).assign(**{"return": n(len(rows))})
    rows = list(itertools.product(("Walker2d",), METHODS, seeds))
    train = pd.DataFrame(rows, columns=["env", "method", "seed"]).assign(value=n(len(rows)))
    sh = (-0.2, 0.0, 0.2)
    rows = list(itertools.product(("ppo", "trpo"), seeds, sh, sh))
    heat3 = pd.DataFrame(rows, columns=["method", "seed", "row_shift", "col_shift"]).assign(**{"return": n(len(rows))})
    rows = list(itertools.product(seeds, range(12)))
    curve = pd.DataFrame(rows, columns=["seed", "iteration"]).assign(train_return=n(len(rows)), test_auc=n(len(rows)))
    rows = list(itertools.product(ENVS, TESTS, METHODS[:7], seeds))
    points = pd.DataFrame(rows, columns=["env", "test", "algo", "seed"]).assign(
        train_return=n(len(rows)), auc=n(len(rows))
    )
    rows = list(itertools.product(ALGOS4, "abcd", seeds, range(10)))
    curves = pd.DataFrame(rows, columns=["algo", "panel", "seed", "iteration"]).assign(
        **{"return": n(len(rows), 1000, 100), "entropy": n(len(rows), 1.0, 0.1)}
    )
    rows = list(itertools.product(ALGOS4, "abcd", seeds, (-2.0, 0.0, 2.0)))
    wind = pd.DataFrame(rows, columns=["algo", "panel", "seed", "value"]).assign(**{"return": n(len(rows), 1000, 100)})
    rows = list(itertools.product(ALGOS4, "abcd", seeds, (0.5, 1.0, 1.5), (0.5, 1.0, 1.5)))
    heat4 = pd.DataFrame(rows, columns=["algo", "panel", "seed", "mass", "friction"]).assign(
        **{"return": n(len(rows), 1000, 100)}
    )
    rows = list(itertools.product(("obs", "act"), ALGOS4, "abcd", seeds, (0.0, 0.1, 0.2)))
    noise = pd.DataFrame(rows, columns=["noise", "algo", "panel", "seed", "value"]).assign(
        **{"return": n(len(rows), 1000, 100)}
    )
    rows = list(itertools.product(FAMILIES, FAMILIES, STRATEGIES, seeds))
    summary = pd.DataFrame(rows, columns=["source", "target", "strategy", "seed"]).assign(
        success_rate=rng.uniform(0, 1, len(rows)), total_cost=n(len(rows))
    )
    summary["pair"] = summary["source"] + "→" + summary["target"]
    catch = pd.DataFrame({"seed": list(seeds), "success": False, "taut_and_slack": False})
    final = pd.DataFrame(list(itertools.product(("CL", "NC"), seeds)), columns=["condition", "seed"]).assign(
        final_success=rng.uniform(0, 0.5, 2 * n_seeds)
    )
    out = {
        "aucs": aucs,
        "returns": returns,
        "train": train,
        "heat": heat3,
        "curve": curve,
        "points": points,
        "curves": curves,
        "wind": wind,
        "noise": noise,
        "summary": summary,
        "catch": catch,
        "final": final,
    }
    ch4 = {"curves": curves, "wind": wind, "heat": heat4, "noise": noise}
    for page in ("fig-4.1", "fig-4.3", "fig-4.4"):
        out.update({f"{k}@{page}": v for k, v in ch4.items()})
    return out


def frames_for(measure: str, n_seeds: int = 3, seed: int = 0) -> dict[str, pd.DataFrame]:
    """:func:`frames` with the chapter-4 heat map / chapter-5 curves under the names the measure reads."""
    f = frames(n_seeds, seed)
    if measure.startswith("ch4") or measure == "contribution4":
        f["heat"] = f["heat@fig-4.4"]
    if measure == "cast_bic":
        f["curves"] = _arm_curves(n_seeds, seed)
    return f


def _arm_curves(n_seeds: int, seed: int) -> pd.DataFrame:
    rng = np.random.default_rng(seed + 1)
    rows = list(itertools.product(FAMILIES, FAMILIES, STRATEGIES, range(n_seeds), range(20)))
    return pd.DataFrame(rows, columns=["source", "target", "strategy", "seed", "trials"]).assign(
        cost=100 + 10 * rng.standard_normal(len(rows))
    )
