"""Fig 4.7's entropy result checked on the trained runs against the log-σ argument (chapter-4 readings page).

The policy's log σ is state-independent, so every Fisher-weighted aggregate (Eq 4.10/4.11, its line search, the
diagonal Fisher) sets it to params_avg's, the sub-policies' plain mean; the trust-region readings move it a
fraction α of that step from θ_old; only kl_exact (moment matching) changes the formula. With a diagonal Gaussian
the entropy is Σ log σ plus a constant, so the argument predicts: a full-step Fisher reading ends at params_avg's
entropy up to seed noise, and any other entropy comes from a different σ rule or from α < 1.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import stats

from thesis_repro.evaluation import tables

#: How each learner sets log σ when it aggregates (``-`` for joint: one learner, no aggregation).
SIGMA_RULE: dict[str, str] = {
    "params_avg": "the sub-policies' mean (Eq 4.6)",
    "kl_avg": "params_avg's (Fisher-weighted)",
    "kl_avg_ls": "params_avg's (Fisher-weighted)",
    "kl_avg_once": "params_avg's (Fisher-weighted)",
    "kl_diag": "params_avg's (Fisher-weighted)",
    "kl_avg_tr": "θ_old's + α·(params_avg's − θ_old's)",
    "kl_avg_trpo": "θ_old's + α·(params_avg's − θ_old's)",
    "kl_exact": "moment-matched to the sub-policies",
    "joint": "- (one learner on the merged batch)",
}
BASELINE = "params_avg"


def diff_ci(a: np.ndarray, b: np.ndarray, level: float = tables.CI_LEVEL) -> tuple[float, float, float]:
    """``(mean(a) − mean(b), lo, hi)``: the Welch ``level`` interval of a difference of means (NaN bounds with
    fewer than two values on a side).

    >>> d, lo, hi = diff_ci(np.array([1.0, 2.0, 3.0]), np.array([0.0, 1.0, 2.0]))  # se 0.816, df 4, t 2.776
    >>> d, round(lo, 2), round(hi, 2)
    (1.0, -1.27, 3.27)
    """
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = float(a.mean() - b.mean())
    if len(a) < 2 or len(b) < 2:
        return d, float("nan"), float("nan")
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    se = float(np.sqrt(va + vb))
    if se == 0.0:
        return d, d, d
    df = (va + vb) ** 2 / (va**2 / (len(a) - 1) + vb**2 / (len(b) - 1))
    half = float(stats.t.ppf(0.5 + level / 2, df)) * se
    return d, d - half, d + half


def _diff_text(d: float, lo: float, hi: float) -> str:
    if not np.isfinite(d):
        return ""
    return f"{d:+.2f} (one seed: no CI)" if not np.isfinite(lo) else f"{d:+.2f} [{lo:+.2f}, {hi:+.2f}]"


def step_fractions(runs: pd.DataFrame) -> dict[tuple[str, int], float]:
    """Per (algo, seed): the run's mean logged step fraction α (NaN where a learner logs none)."""
    out = {}
    for row in runs.itertuples():
        sf = np.asarray(row.result.get("curve_step_fraction", []), dtype=float)
        out[(row.algo, int(row.seed))] = float(np.nanmean(sf)) if np.isfinite(sf).any() else float("nan")
    return out


def log_sigma_check(runs: pd.DataFrame, curves: pd.DataFrame, diverged: pd.DataFrame | None = None) -> pd.DataFrame:
    """One row per learner: its σ rule, seeds (diverged runs left out: ``diverged`` has ``algo, seed,
    diverged``), final entropy, its difference from params_avg's with a Welch 95 % interval, mean step fraction
    α and late return (mean of the last third of iterations), and whether the run agrees with the argument's
    prediction: ``same`` (full-step Fisher reading: the interval covers 0), ``moves`` (another σ rule or α < 1:
    a difference is allowed), ``-`` (params_avg itself, or joint)."""
    cur = curves
    if diverged is not None and len(diverged):
        bad = diverged[diverged["diverged"]][["algo", "seed"]]
        keep = cur.merge(bad.assign(_bad=True), on=["algo", "seed"], how="left")
        cur = cur[keep["_bad"].isna().to_numpy()]
    last = cur[cur["iteration"] == cur["iteration"].max()]
    n_it = int(cur["iteration"].max()) if len(cur) else 0
    late = cur[cur["iteration"] > n_it - max(1, n_it // 3)]
    alpha = step_fractions(runs)
    base = last[last["algo"] == BASELINE].groupby("seed")["entropy"].mean().to_numpy(float)
    rows = []
    for algo in dict.fromkeys(runs["algo"]):
        ent = last[last["algo"] == algo].groupby("seed")["entropy"].mean()
        if ent.empty:
            n_bad = int(len(runs[runs["algo"] == algo]))
            rows.append(
                {
                    "learner": algo,
                    "log σ at an aggregation": SIGMA_RULE.get(algo, "?"),
                    "seeds": f"0 ({n_bad} diverged)",
                    "argument": "diverged, not judged",
                }
            )
            continue
        a = float(np.mean([alpha[(algo, int(s))] for s in ent.index]))
        d, lo, hi = diff_ci(ent.to_numpy(float), base) if len(base) and algo != BASELINE else (np.nan,) * 3
        fisher = SIGMA_RULE.get(algo, "").startswith("params_avg's")
        if algo in (BASELINE, "joint") or not np.isfinite(d):
            agrees = "-"
        elif fisher and not a < 0.999:  # no α logged, or every step full
            covered = "same: yes" if lo <= 0 <= hi else "same: NO"
            agrees = covered if np.isfinite(lo) else "same: untested (one seed)"
        else:
            agrees = "moves"
        rows.append(
            {
                "learner": algo,
                "log σ at an aggregation": SIGMA_RULE.get(algo, "?"),
                "seeds": str(len(ent)),
                "final entropy": float(ent.mean()),
                "Δ vs params_avg [95 % CI]": _diff_text(d, lo, hi),
                "mean α": "-" if not np.isfinite(a) else f"{a:.2f}",
                "late return": float(late[late["algo"] == algo].groupby("seed")["return"].mean().mean()),
                "argument": agrees,
            }
        )
    cols = ["learner", "log σ at an aggregation", "seeds", "final entropy", "Δ vs params_avg [95 % CI]", "mean α"]
    table = pd.DataFrame(rows).reindex(columns=[*cols, "late return", "argument"]).set_index("learner")
    table["late return"] = [f"{v:.0f}" if pd.notna(v) else "" for v in table["late return"]]
    table["final entropy"] = [f"{v:.2f}" if pd.notna(v) else "" for v in table["final entropy"]]
    return table.fillna("")


def check_line(table: pd.DataFrame) -> str:
    """One printed sentence per learner the argument makes a prediction for (``same`` or ``moves``)."""
    lines = []
    ref = table.loc[BASELINE] if BASELINE in table.index else None
    for algo, r in table.iterrows():
        arg = r.get("argument")
        if not isinstance(arg, str) or arg == "-":
            continue
        if arg.startswith("diverged"):
            lines.append(f"{algo}: every run diverged in training, not judged.")
            continue
        ci = r["Δ vs params_avg [95 % CI]"]
        if arg.startswith("same"):
            verdict = {"same: yes": "consistent with the argument.", "same: NO": "NOT consistent with the argument."}
            lines.append(
                f"{algo} keeps params_avg's log σ with a full step: final entropy Δ {ci} nats, "
                + verdict.get(arg, "not tested: one seed.")
            )
        else:
            extra = ""
            if ref is not None and ref.get("late return") and r["late return"]:
                extra = f"; late return {r['late return']} against params_avg's {ref['late return']}"
            step = "" if r["mean α"] == "-" else f", mean step fraction α {r['mean α']}"
            lines.append(
                f"{algo}'s log σ at an aggregation is {r['log σ at an aggregation']}{step}: "
                f"final entropy Δ {ci} nats{extra}."
            )
    return "\n".join(lines)
