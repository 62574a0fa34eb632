"""Why the literal Eq 4.11 does not beat parameter averaging: the computations of the analysis page.

The page ``notebooks/analysis-4-kl.py`` calls these functions; each returns a tidy ``DataFrame`` of
numbers computed here (nothing typed in). Aggregates compared on the TRUE Eq 4.7 objective
F(θ) = Σ_i E_s KL(π_θi ‖ π_θ) (:func:`~thesis_repro.mdl.aggregate.eq47_objective`):

* ``params_avg`` — Eq 4.6;
* ``kl_avg`` — Eq 4.11 by CG with the kit's damping (0.1 on the mean Fisher);
* ``eq4.10`` — the undamped closed form Eq 4.10 (dense solve on tiny nets, long CG otherwise);
* ``kl_exact`` — Newton-CG on the true Eq 4.7 (:func:`~thesis_repro.mdl.exact.kl_exact`).

The reference optimum θ* is found independently by SciPy's L-BFGS-B on F from params_avg.
Sub-policies come from a common θ_old in one of two ways: ``"perturb"`` (θ_i = θ_old + δ·ε_i, for the
order-of-magnitude study) or ``"update"`` (a few full-batch Adam steps from θ_old towards a
domain-specific target Gaussian, like Algorithm 3's per-domain PPO updates).

>>> p = make_problem(0, obs_dim=3, act_dim=2, hidden=(4,), n_domains=3, n_states=32)
>>> df = compare_aggregates([p])
>>> sorted(df["aggregate"].unique())
['eq4.10', 'kl_avg', 'kl_exact', 'params_avg']
>>> bool((df.set_index("aggregate")["excess"] >= -1e-9).all())
True
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
import torch
from scipy.optimize import minimize

from thesis_repro.core.validation import check_choice, check_positive
from thesis_repro.mdl import aggregate as agg
from thesis_repro.mdl import exact

KINDS: tuple[str, ...] = ("perturb", "update")
AGGREGATES: tuple[str, ...] = ("params_avg", "kl_avg", "eq4.10", "kl_exact")


@dataclass
class Problem:
    """N sub-policies θ_i of one policy network (float64), the states the expectations run over, θ_old."""

    view: agg.PolicyView
    states: torch.Tensor
    theta_old: torch.Tensor
    thetas: list[torch.Tensor]
    name: str = ""

    def objective(self, theta: torch.Tensor) -> float:
        """Eq 4.7 at ``theta``."""
        return agg.eq47_objective(self.view, theta, self.thetas, self.states)


def make_problem(
    seed: int,
    *,
    obs_dim: int = 3,
    act_dim: int = 2,
    hidden: Sequence[int] = (8,),
    n_domains: int = 4,
    n_states: int = 128,
    kind: str = "update",
    spread: float = 0.3,
    steps: int = 20,
    lr: float = 1e-3,
    log_std_init: float = -0.5,
) -> Problem:
    """A reproducible aggregation problem (see the module docstring for ``kind``).

    ``spread`` is δ for ``"perturb"``; for ``"update"`` it scales how far the domains' target means
    (linear in s) and log-stds move from θ_old's.
    """
    check_choice(kind, KINDS, "problem kind")
    spread = check_positive(spread, "spread")
    if n_domains < 2:
        raise ValueError(f"n_domains must be >= 2, got {n_domains}")
    gen = torch.Generator().manual_seed(10_000 + seed)
    pol = agg.GaussianPolicy(obs_dim, act_dim, hidden=hidden, seed=seed, log_std_init=log_std_init).double()
    view = agg.PolicyView(pol)
    states = torch.randn(n_states, obs_dim, generator=gen, dtype=torch.float64)
    old = view.get_flat()
    thetas = []
    if kind == "perturb":
        for _ in range(n_domains):
            eps = torch.randn(old.shape, generator=gen, dtype=torch.float64)
            thetas.append(old + spread * eps)
    else:
        with torch.no_grad():
            mean_old, ls_old = view.dist(old, states)
        for _ in range(n_domains):
            a = torch.randn(obs_dim, act_dim, generator=gen, dtype=torch.float64) / math.sqrt(obs_dim)
            b = torch.randn(act_dim, generator=gen, dtype=torch.float64)
            c = torch.randn(act_dim, generator=gen, dtype=torch.float64)
            target_mean = mean_old + spread * (states @ a + b)
            target_ls = ls_old + spread * c
            t = old.clone().requires_grad_(True)
            opt = torch.optim.Adam([t], lr=lr)
            for _ in range(steps):
                opt.zero_grad()
                m, ls = view.dist(t, states)
                agg.gaussian_kl(target_mean, target_ls, m, ls).mean().backward()
                opt.step()
            thetas.append(t.detach().clone())
    name = f"{kind}-s{seed}-{obs_dim}x{'x'.join(map(str, hidden)) or 'lin'}x{act_dim}"
    return Problem(view, states, old, thetas, name)


def make_problems(groups: Sequence[dict]) -> list[Problem]:
    """Problems for the scale table's ``problems`` entry: each group ``{n, **make_problem kwargs}`` gives
    ``n`` problems with seeds 0..n−1.

    >>> [p.name for p in make_problems([{"n": 2, "hidden": [4], "n_states": 8}])]
    ['update-s0-3x4x2', 'update-s1-3x4x2']
    """
    out = []
    for g in groups:
        kw = dict(g)
        n = int(kw.pop("n", 1))
        if "hidden" in kw:
            kw["hidden"] = tuple(kw["hidden"])
        out += [make_problem(seed, **kw) for seed in range(n)]
    return out


def reference_optimum(problem: Problem, iters: int = 100, maxiter: int = 100) -> torch.Tensor:
    """θ*: a tight local minimiser of Eq 4.7 — :func:`~thesis_repro.mdl.exact.kl_exact` run to
    convergence (``iters`` iterations, CG to 1e-8, damping 1e-8), then polished by SciPy's L-BFGS-B (``maxiter``).

    (``tests/test_aggregate.py`` checks independently that L-BFGS-B from params_avg reaches the same value.)
    """
    view, states = problem.view, problem.states
    x0 = exact.kl_exact(view, problem.thetas, states, iters=iters, cg_iters=100, cg_rtol=1e-8, damping=1e-8)
    with torch.no_grad():
        targets = [view.dist(t, states) for t in problem.thetas]

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        t = torch.tensor(x, dtype=torch.float64, requires_grad=True)
        m, ls = view.dist(t, states)
        val = sum(agg.gaussian_kl(mi, lsi, m, ls).mean() for mi, lsi in targets)
        (g,) = torch.autograd.grad(val, t)  # type: ignore[arg-type]
        return float(val.detach()), g.numpy()  # type: ignore[union-attr]

    res = minimize(
        fun, x0.numpy(), jac=True, method="L-BFGS-B", options={"maxiter": maxiter, "gtol": 1e-12, "ftol": 1e-15}
    )
    best = torch.tensor(res.x, dtype=torch.float64)
    return best if problem.objective(best) <= problem.objective(x0) else x0


def aggregates(
    problem: Problem,
    *,
    damping: float = 0.1,
    cg_iters: int = 10,
    exact_iters: int = 20,
    dense_max_params: int = 2000,
) -> dict[str, torch.Tensor]:
    """The four aggregates of :data:`AGGREGATES` for ``problem`` (``eq4.10`` dense if P ≤ ``dense_max_params``)."""
    view, s, th = problem.view, problem.states, problem.thetas
    if view.numel <= dense_max_params:
        eq410 = agg.kl_avg_dense(view, th, s, damping=0.0)
    else:
        eq410 = agg.kl_avg(view, th, s, cg_iters=100, damping=0.0, cg_rtol=1e-10)
    return {
        "params_avg": agg.params_avg(th),  # type: ignore[dict-item]
        "kl_avg": agg.kl_avg(view, th, s, cg_iters=cg_iters, damping=damping),
        "eq4.10": eq410,
        "kl_exact": exact.kl_exact(view, th, s, iters=exact_iters),
    }


def compare_aggregates(problems: Sequence[Problem], reference_iters: int = 100, **kwargs) -> pd.DataFrame:
    """One row per (problem, aggregate): Eq 4.7 value, its excess over θ*'s, distance to θ* (absolute
    and relative to params_avg's), and the step size ‖aggregate − params_avg‖."""
    rows = []
    for p in problems:
        opt = reference_optimum(p, iters=reference_iters)
        f_opt = p.objective(opt)
        aggs = aggregates(p, **kwargs)
        avg = aggs["params_avg"]
        moved = float(agg.eq47_kls(p.view, p.theta_old, p.thetas, p.states).mean())
        d_avg = float((avg - opt).norm())
        for name, theta in aggs.items():
            f = p.objective(theta)
            rows.append(
                {
                    "problem": p.name,
                    "aggregate": name,
                    "eq47": f,
                    "excess": f - f_opt,
                    "dist_to_opt": float((theta - opt).norm()),
                    "dist_ratio": float((theta - opt).norm()) / max(d_avg, 1e-300),
                    "step_from_avg": float((theta - avg).norm()),
                    "params": p.view.numel,
                    "kl_old_to_sub": moved,
                }
            )
    return pd.DataFrame(rows)


def summarise_aggregates(table: pd.DataFrame) -> pd.DataFrame:
    """Per aggregate: median Eq 4.7 value (absolute and as a fraction of params_avg's on the same problem),
    median excess, median/max distance ratio, fraction of problems where it beats params_avg."""
    base = table["problem"].map(table[table["aggregate"] == "params_avg"].set_index("problem")["eq47"])
    t = table.assign(beats_avg=table["eq47"] < base - 1e-12, rel=table["eq47"] / base)
    out = t.groupby("aggregate", sort=False).agg(
        median_eq47=("eq47", "median"),
        median_eq47_vs_avg=("rel", "median"),
        median_excess=("excess", "median"),
        median_dist_ratio=("dist_ratio", "median"),
        max_dist_ratio=("dist_ratio", "max"),
        beats_params_avg=("beats_avg", "mean"),
        problems=("problem", "nunique"),
    )
    return out.reindex([a for a in AGGREGATES if a in out.index])


def linear_gaussian(seed: int = 0, *, n_domains: int = 4, n_states: int = 256, spread: float = 0.5) -> pd.DataFrame:
    """The linear-Gaussian case: each aggregate's Eq 4.7 value, its distance to the CLOSED-FORM optimum,
    and the largest deviation of its mean parameters from the plain average (0 for the exact optimum)."""
    p = make_problem(
        seed, obs_dim=3, act_dim=2, hidden=(), n_domains=n_domains, n_states=n_states, kind="perturb", spread=spread
    )
    closed = exact.linear_gaussian_optima(p.view, p.thetas, p.states)
    aggs = {"closed form (Eq 4.7)": closed["eq47"], "closed form (Eq 4.10)": closed["eq410"]}
    aggs.update(aggregates(p, exact_iters=30))
    avg = p.view.params(aggs["params_avg"])
    rows = []
    for name, theta in aggs.items():
        got = p.view.params(theta)
        mean_dev = max(float((got[k] - avg[k]).abs().max()) for k in p.view.names if k != "log_std")
        rows.append(
            {
                "aggregate": name,
                "eq47": p.objective(theta),
                "dist_to_closed_form": float((theta - closed["eq47"]).norm()),
                "mean_params_minus_plain_avg": mean_dev,
                "log_std": [round(v, 4) for v in got["log_std"].tolist()],
            }
        )
    return pd.DataFrame(rows).set_index("aggregate")


def equal_fisher_check(seed: int = 0, n_domains: int = 4) -> float:
    """max |Eq 4.10 − params_avg| when every I(θ_i) is the same matrix (a linear mean with fixed log-std)."""
    pol = agg.GaussianPolicy(3, 2, hidden=(), seed=seed).double()
    view = agg.PolicyView(pol, [n for n, _ in pol.named_parameters() if n != "log_std"])
    gen = torch.Generator().manual_seed(seed)
    states = torch.randn(64, 3, generator=gen, dtype=torch.float64)
    t0 = view.get_flat()
    thetas = [t0 + torch.randn(t0.shape, generator=gen, dtype=torch.float64) for _ in range(n_domains)]
    return float((agg.kl_avg_dense(view, thetas, states, damping=0.0) - agg.params_avg(thetas)).abs().max())


def spread_scaling(
    spreads: Sequence[float], seeds: Sequence[int] = (0,), reference_iters: int = 100, **problem_kwargs
) -> pd.DataFrame:
    """How the corrections scale with the sub-policies' spread δ (``"perturb"`` problems).

    Columns: ``true_step`` = ‖θ* − params_avg‖ (what Eq 4.7 asks for), ``eq410_step`` = ‖Eq 4.10 −
    params_avg‖ (what Eq 4.10 gives), ``eq410_error`` = ‖Eq 4.10 − θ*‖, ``avg_error`` = ‖params_avg − θ*‖
    (= ``true_step``), ``error_ratio`` = ``eq410_error / avg_error``. If Eq 4.10 were right to leading
    order, ``eq410_error`` would vanish faster than ``true_step`` as δ → 0 (``error_ratio`` → 0).
    """
    rows = []
    for seed in seeds:
        for d in spreads:
            p = make_problem(seed, kind="perturb", spread=d, **problem_kwargs)
            avg = agg.params_avg(p.thetas)
            opt = reference_optimum(p, iters=reference_iters)
            eq410 = agg.kl_avg_dense(p.view, p.thetas, p.states, damping=0.0)
            rows.append(
                {
                    "seed": seed,
                    "spread": d,
                    "true_step": float((opt - avg).norm()),
                    "eq410_step": float((eq410 - avg).norm()),
                    "eq410_error": float((eq410 - opt).norm()),
                    "avg_error": float((avg - opt).norm()),
                    "error_ratio": float((eq410 - opt).norm() / (avg - opt).norm().clamp_min(1e-300)),
                }
            )
    return pd.DataFrame(rows)


def loglog_slopes(
    table: pd.DataFrame,
    columns: Sequence[str] = ("true_step", "eq410_step", "eq410_error"),
    max_spread: float = float("inf"),
) -> dict[str, float]:
    """Least-squares slope of log(column) against log(spread) over rows with spread ≤ ``max_spread`` and a
    positive value, pooled over seeds: the order in δ (2 means ∝ δ²).

    >>> t = pd.DataFrame({"spread": [0.1, 0.01, 0.001], "true_step": [1e-2, 1e-4, 1e-6]})
    >>> round(loglog_slopes(t, ["true_step"])["true_step"], 6)
    2.0
    """
    rows = table[table["spread"] <= max_spread]
    out = {}
    for c in columns:
        ok = rows[rows[c] > 0]
        if len(ok["spread"].unique()) < 2:
            raise ValueError(f"need positive {c!r} at two spreads or more to fit a slope")
        out[c] = float(np.polyfit(np.log(ok["spread"].to_numpy()), np.log(ok[c].to_numpy()), 1)[0])
    return out


def damping_sweep(
    problem: Problem, dampings: Sequence[float], cg_iters: int = 10, reference_iters: int = 100
) -> pd.DataFrame:
    """Eq 4.7 value and distance to θ* of kl_avg and kl_exact for each damping λ (CG: ``cg_iters`` products
    for kl_avg as in training; kl_exact at its defaults otherwise)."""
    opt = reference_optimum(problem, iters=reference_iters)
    f_opt = problem.objective(opt)
    view, s, th = problem.view, problem.states, problem.thetas
    rows = []
    for lam in dampings:
        for name, theta in (
            ("kl_avg", agg.kl_avg(view, th, s, cg_iters=cg_iters, damping=lam)),
            ("kl_exact", exact.kl_exact(view, th, s, damping=lam)),
        ):
            rows.append(
                {
                    "damping": lam,
                    "aggregate": name,
                    "excess": problem.objective(theta) - f_opt,
                    "dist_to_opt": float((theta - opt).norm()),
                }
            )
    avg = agg.params_avg(th)
    rows.append(
        {
            "damping": float("nan"),
            "aggregate": "params_avg",
            "excess": problem.objective(avg) - f_opt,  # type: ignore[arg-type]
            "dist_to_opt": float((avg - opt).norm()),  # type: ignore[operator]
        }
    )
    return pd.DataFrame(rows)


#: How :func:`sweep_text` shows params_avg's damping (NaN in the frame: Eq 4.6 uses no Fisher, so no damping).
NO_DAMPING = "n/a (no damping)"


def sweep_text(sweep: pd.DataFrame) -> str:
    """:func:`damping_sweep` as printed text, numbers to 3 significant digits; params_avg's damping reads
    :data:`NO_DAMPING` instead of NaN.

    >>> t = pd.DataFrame({"damping": [0.1, float("nan")], "aggregate": ["kl_avg", "params_avg"],
    ...                   "excess": [0.000879, 0.000674], "dist_to_opt": [0.1033, 0.0178]})
    >>> print(sweep_text(t))
                damping   aggregate   excess  dist_to_opt
    0               0.1      kl_avg 0.000879        0.103
    1  n/a (no damping)  params_avg 0.000674       0.0178
    """
    shown = sweep.assign(damping=[NO_DAMPING if pd.isna(v) else f"{v:.3g}" for v in sweep["damping"]])
    return shown.to_string(float_format=lambda v: f"{v:.3g}")


def fisher_spectrum(problem: Problem) -> dict[str, float]:
    """Smallest/largest eigenvalue and condition number of the mean sub-policy Fisher Ī (tiny nets only)."""
    fims = [agg.fisher_matrix(problem.view, t, problem.states) for t in problem.thetas]
    ev = torch.linalg.eigvalsh(sum(fims) / len(fims))  # type: ignore[arg-type]
    lo, hi = float(ev[0]), float(ev[-1])
    return {"min_eig": lo, "max_eig": hi, "condition": hi / max(lo, 1e-300)}


__all__ = [
    "AGGREGATES",
    "Problem",
    "aggregates",
    "compare_aggregates",
    "damping_sweep",
    "equal_fisher_check",
    "fisher_spectrum",
    "linear_gaussian",
    "loglog_slopes",
    "make_problem",
    "make_problems",
    "reference_optimum",
    "spread_scaling",
    "summarise_aggregates",
]
