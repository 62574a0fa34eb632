"""Readings of chapter 4's aggregation step that the thesis leaves open, and what each one rests on in its text.

The thesis asks for the policy closest in KL to the N sub-policies (Eq 4.7), approximates each KL to second
order (Eq 4.8) and solves that by CG (Eq 4.10/4.11, l. 859), but gives no damping, step size, line search or
trust region for the aggregate. :data:`READINGS` lists the readings the kit trains, each a hyperparameter id of
``config/hyperparams.yaml`` with the thesis lines it rests on. Besides :func:`~thesis_repro.mdl.aggregate.kl_avg`
(the literal reading, and the damped step with a line search on Eq 4.7) this module adds:

* :func:`kl_trust_region` — the Eq 4.11 aggregate, its step from θ_old scaled down until the aggregate's
  E_s KL(π_θold ‖ π_θ) is no larger than the largest of the sub-policies' own (l. 803);
* :func:`kl_diag` — Eq 4.10 with each I(θ_i) replaced by its diagonal: a per-parameter Fisher-weighted mean.

>>> import torch
>>> from thesis_repro.mdl.aggregate import GaussianPolicy, PolicyView, mean_kl
>>> view = PolicyView(GaussianPolicy(3, 2, hidden=(4,), seed=0))
>>> s = torch.randn(32, 3, generator=torch.Generator().manual_seed(0))
>>> t0 = view.get_flat()
>>> thetas = [t0 + 0.05 * torch.randn(t0.shape, generator=torch.Generator().manual_seed(i)) for i in range(3)]
>>> info = {}
>>> new = kl_trust_region(view, thetas, s, t0, info=info)
>>> float(mean_kl(view, t0, new, s)) <= info["kl_bound"] + 1e-6
True
>>> lo, hi = torch.stack(thetas).min(0).values, torch.stack(thetas).max(0).values
>>> bool(((kl_diag(view, thetas, s) >= lo - 1e-6) & (kl_diag(view, thetas, s) <= hi + 1e-6)).all())
True
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import torch
from torch import Tensor

from thesis_repro.core.validation import check_nonneg
from thesis_repro.mdl.aggregate import FisherProducts, GaussianPolicy, PolicyView, kl_avg, kl_avg_dense, mean_kl
from thesis_repro.mdl.exact import kl_exact


class Reading(NamedTuple):
    """One reading of the aggregation step: its hyperparameter id, the thesis lines it rests on, what it does
    (``update``: a template whose ``{name}`` fields are the learner's settings, filled in where it is shown)."""

    algo: str
    name: str
    lines: str
    basis: str
    update: str


#: The readings the kit trains, in the order of the book's table, with the lines of the thesis's text they rest on
#: (chapter 4: l. 783 TRPO's trust region, l. 803 "constraints on gradient step sizes", l. 807 "we take a step to
#: minimise", l. 809 Eq 4.7, l. 813 Eq 4.8, l. 817 Eq 4.9, l. 845 Alg 3's step, l. 855-859 Eq 4.10/4.11 and their
#: CG solve).
READINGS: tuple[Reading, ...] = (
    Reading(
        "kl-avg",
        "literal",
        "845, 855-859",
        "Alg 3 computes θ_new 'following Eq. (4.11)' after every epoch; l. 859: 'approximately solved by conjugate "
        "gradient methods ... without forming the full matrices'",
        "Eq 4.11 by {cg_iters} CG iterations, damping λ = {damping} on the mean Fisher (TRPO's cg_damping), full step",
    ),
    Reading(
        "kl-avg-ls",
        "line search",
        "807, 809, 813",
        "l. 807: 'we take a step to minimise overall probability distance'; Eq 4.7 (l. 809) is that distance and "
        "Eq 4.8 (l. 813) only its quadratic model, so a step is accepted only where the true Eq 4.7 agrees",
        "the same CG correction, backtracked (1, 1/2, ..., {smallest_fraction}, 0) until Eq 4.7 is no larger than at "
        "params_avg: never worse than params_avg",
    ),
    Reading(
        "kl-avg-tr",
        "trust region",
        "783, 803",
        "l. 803: averaging 'may break the constraints on gradient step sizes'; l. 783: TRPO's 'constraint on KL "
        "divergence between old and updated policy'",
        "the Eq 4.11 aggregate, its step from θ_old scaled (bisection) until E_s KL(π_θold ‖ π_θ) is at most the "
        "largest sub-policy's own",
    ),
    Reading(
        "kl-avg-trpo",
        "trust region, TRPO's bound",
        "783, 803, 1251",
        "the trust region of l. 783/803 with the bound the thesis gives TRPO: 'Maximum KL divergence: 0.01' "
        "(App. A, l. 1251; Eq 4.11's CG settings, 10 iterations and damping 0.1, are App. A's TRPO ones too)",
        "the Eq 4.11 aggregate, its step from θ_old scaled (bisection) until E_s KL(π_θold ‖ π_θ) ≤ {kl_bound}",
    ),
    Reading(
        "kl-avg-once",
        "once per iteration",
        "845, 859",
        "l. 859: Eq 4.11 'can be approximately solved by conjugate gradient methods after multiple gradient steps'; "
        "Alg 3 (l. 845) instead aggregates after every epoch",
        "the literal Eq 4.11 step, once per iteration after each sub-policy's K PPO epochs",
    ),
    Reading(
        "kl-diag",
        "diagonal Fisher",
        "817, 859",
        "l. 859: 'costly to compute the inverse of FIMs' ... 'without forming the full matrices'; the diagonal of "
        "Eq 4.9's I(θ_i) (l. 817) is the cheapest approximation that needs neither",
        "Eq 4.10 with diagonal Fisher matrices: per parameter, the mean of the θ_i weighted by their "
        "Fisher diagonals (no damping: a convex combination)",
    ),
    Reading(
        "kl-exact",
        "exact Eq 4.7",
        "809",
        "Eq 4.7 as written, without the quadratic approximation of Eq 4.8",
        "Newton-CG with the aggregate's Fisher and an Armijo line search from params_avg (the kit's own)",
    ),
)


def reading_ids() -> tuple[str, ...]:
    """The hyperparameter ids of :data:`READINGS`, in order.

    >>> reading_ids()[:2]
    ('kl-avg', 'kl-avg-ls')
    """
    return tuple(r.algo for r in READINGS)


def kl_trust_region(
    view: PolicyView,
    thetas: Sequence[Tensor],
    states: Tensor,
    theta_old: Tensor,
    *,
    cg_iters: int = 10,
    damping: float = 0.1,
    cg_rtol: float = 1e-6,
    kl_bound: float | None = None,
    bisect_iters: int = 20,
    info: dict | None = None,
) -> Tensor:
    """Eq 4.11's aggregate θ* (:func:`~thesis_repro.mdl.aggregate.kl_avg`), its step from ``theta_old`` scaled to
    θ_old + α (θ* − θ_old) with the largest α ∈ [0, 1] (``bisect_iters`` bisections) such that
    E_s KL(π_θold ‖ π_θ) ≤ ``kl_bound``; by default the bound is max_i E_s KL(π_θold ‖ π_θi), the largest step
    a sub-policy took on its own. α = 0 keeps θ_old. ``info`` receives ``cg_residual``, ``step_fraction`` (α),
    ``kl_bound`` and ``kl_old`` (the accepted aggregate's KL to θ_old).
    """
    if bisect_iters < 1:
        raise ValueError(f"bisect_iters must be >= 1, got {bisect_iters}")
    inner: dict = {}
    target = kl_avg(view, thetas, states, theta_old, cg_iters=cg_iters, damping=damping, info=inner, cg_rtol=cg_rtol)
    old = theta_old.detach()
    with torch.no_grad():
        if kl_bound is None:
            bound = max(float(mean_kl(view, old, t.detach(), states)) for t in thetas)
        else:
            bound = check_nonneg(kl_bound, "kl_bound")
        step = target - old

        def kl_at(alpha: float) -> float:
            return float(mean_kl(view, old, old + alpha * step, states))

        alpha, kl = 1.0, kl_at(1.0)
        if not kl <= bound:  # also NaN: bisect for the largest feasible α
            lo, hi, kl = 0.0, 1.0, 0.0
            for _ in range(bisect_iters):
                mid = 0.5 * (lo + hi)
                k_mid = kl_at(mid)
                if k_mid <= bound:
                    lo, kl = mid, k_mid
                else:
                    hi = mid
            alpha = lo
    if info is not None:
        info.update(cg_residual=inner["cg_residual"], step_fraction=alpha, kl_bound=bound, kl_old=kl)
    return old + alpha * step


def kl_diag(view: PolicyView, thetas: Sequence[Tensor], states: Tensor, *, damping: float = 0.0) -> Tensor:
    """Eq 4.10 with each I(θ_i) replaced by its diagonal D_i: θ_new = mean + (D̄ + λ)⁻¹ (1/N) Σ_i D_i (θ_i − mean).

    With λ = 0 each parameter is the D_i-weighted mean of the θ_i (a convex combination; a parameter with no
    Fisher weight in any sub-policy keeps the plain mean). No step control: not a fraction of an Eq 4.11 step.
    """
    damping = check_nonneg(damping, "damping")
    if len(thetas) == 0:
        raise ValueError("kl_diag needs at least one sub-policy")
    stacked = torch.stack([t.detach() for t in thetas])
    mean = stacked.mean(0)
    with torch.no_grad():
        diag = FisherProducts(view, list(stacked), states).diagonal()
        denom = diag.mean(0) + damping
        num = (diag * (stacked - mean)).mean(0)
        corr = torch.where(denom > 0, num / torch.where(denom > 0, denom, torch.ones_like(denom)), 0.0)
    return mean + corr


def log_std_gaps(seed: int = 0, n: int = 4, spread: float = 0.3) -> dict[str, float]:
    """max |log σ(aggregate) − log σ(params_avg)| of each aggregate on a tiny float64 problem (an MLP Gaussian
    policy, N sub-policies θ_old + spread·ε_i): the log-σ argument, computed. A state-independent log σ has the
    Fisher block 2·1 in every sub-policy and no cross term with the mean's parameters, so every Fisher-weighted
    reading (Eq 4.10 dense, Eq 4.11 by CG, its line search, the diagonal Fisher) keeps params_avg's log σ to
    rounding; the exact Eq 4.7 minimiser moment-matches σ and moves it.

    >>> gaps = log_std_gaps()
    >>> gaps["Eq 4.10 (dense, undamped)"] < 1e-12, gaps["kl_exact"] > 1e-3
    (True, True)
    """
    view = PolicyView(GaussianPolicy(3, 2, hidden=(5, 4), seed=seed, log_std_init=-0.5).double())
    states = torch.randn(24, 3, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    t0 = view.get_flat()
    gens = [torch.Generator().manual_seed(seed * 1000 + i + 1) for i in range(n)]
    thetas = [t0 + spread * torch.randn(t0.shape, generator=g, dtype=torch.float64) for g in gens]
    avg = view.params(torch.stack(thetas).mean(0))["log_std"]
    aggregates = {
        "Eq 4.10 (dense, undamped)": kl_avg_dense(view, thetas, states, damping=0.0),
        "Eq 4.11 (CG, λ = 0.1)": kl_avg(view, thetas, states, t0, cg_iters=10, damping=0.1),
        "Eq 4.11 + line search": kl_avg(view, thetas, states, t0, cg_iters=10, damping=0.1, line_search=True),
        "diagonal Fisher": kl_diag(view, thetas, states),
        "kl_exact": kl_exact(view, thetas, states, iters=10),
    }
    return {k: float((view.params(v)["log_std"] - avg).abs().max()) for k, v in aggregates.items()}
