"""The exact Eq 4.7 aggregate (``kl_exact``, the kit's, not the thesis's) and the linear-Gaussian closed forms.

:func:`kl_exact` minimises the true Eq 4.7 objective by Newton-CG from :func:`~thesis_repro.mdl.aggregate.params_avg`,
on the products of :mod:`thesis_repro.mdl.aggregate`; :func:`linear_gaussian_optima` gives Eq 4.7's and Eq 4.10's
closed forms for a policy whose mean is linear in θ, what ``tests/test_aggregate.py`` and the analysis page hold
both aggregates against.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from thesis_repro.core.validation import check_nonneg
from thesis_repro.mdl.aggregate import FisherProducts, PolicyView, _KLToTargets, conjugate_gradient, gaussian_kl


def kl_exact(
    view: PolicyView,
    thetas: Sequence[Tensor],
    states: Tensor,
    *,
    iters: int = 10,
    cg_iters: int = 20,
    cg_rtol: float = 1e-3,
    damping: float = 1e-3,
    tol: float = 1e-10,
    ftol: float | None = None,
    info: dict | None = None,
) -> Tensor:
    """Minimise the TRUE Eq 4.7 objective F(θ) = Σ_i E_s KL(π_θi ‖ π_θ) from θ_0 = :func:`params_avg`.

    Each of at most ``iters`` iterations takes a Newton-CG step on F/N whose curvature is the Fisher of the
    AGGREGATE, I(θ) (Eq 4.9 at θ, not at the θ_i as Eq 4.8 uses): the Gauss-Newton matrix of the KL sum
    with the Hessian of the KL in the aggregate's (μ, log σ) replaced by its value at moment matching,
    diag(σ⁻², 2) — positive semi-definite everywhere, and the exact Hessian at the optimum of a
    linear-Gaussian policy (Fisher scoring). Solve (I(θ) + λ·1) d = −∇(F/N) by CG (``cg_iters`` products,
    relative tolerance ``cg_rtol``, damping λ = ``damping`` on the mean Fisher as in :func:`kl_avg`), then
    backtrack (1, ½, ¼, ... 2⁻²⁰) until the Armijo condition F(θ + t d) ≤ F(θ) + 10⁻⁴ t ∇F·d holds. So F
    never increases, and the result is never worse than params_avg on Eq 4.7. Stops early when the
    predicted decrease ½|∇F·d| ≤ ``tol`` (nats) + ``ftol``·F, when a step lowers F by at most ``ftol``·F
    (that step is kept), or when no step decreases F. ``ftol`` is relative: by default 100 machine epsilons
    of θ's dtype (1.2e-5 in float32), i.e. F no longer moves beyond its own rounding — without it a float32
    run spends its remaining iterations backtracking on rounding noise. ``info`` (if given) receives
    ``objective`` (F at θ_0..θ_k), ``step_sizes``, ``cg_residuals`` (relative) and ``iters`` (k).

    >>> from thesis_repro.mdl.aggregate import GaussianPolicy, eq47_objective, kl_avg, params_avg
    >>> pol = GaussianPolicy(3, 2, hidden=(4,), seed=0)
    >>> view = PolicyView(pol)
    >>> s = torch.randn(32, 3, generator=torch.Generator().manual_seed(0))
    >>> t0 = view.get_flat()
    >>> thetas = [t0 + 0.3 * torch.randn(t0.shape, generator=torch.Generator().manual_seed(i)) for i in range(3)]
    >>> info = {}
    >>> new = kl_exact(view, thetas, s, iters=10, info=info)
    >>> f = info["objective"]  # Eq 4.7 at params_avg, then after each iteration
    >>> abs(f[0] - eq47_objective(view, params_avg(thetas), thetas, s)) < 1e-5, f[-1] < f[0]
    (True, True)
    >>> eq47_objective(view, new, thetas, s) <= eq47_objective(view, kl_avg(view, thetas, s), thetas, s)
    True
    """
    if len(thetas) == 0:
        raise ValueError("kl_exact needs at least one sub-policy")
    if iters < 0:
        raise ValueError(f"iters must be >= 0, got {iters}")
    if cg_iters < 1:
        raise ValueError(f"cg_iters must be >= 1, got {cg_iters}")
    damping = check_nonneg(damping, "damping")
    cg_rtol = check_nonneg(cg_rtol, "cg_rtol")
    tol = check_nonneg(tol, "tol")
    ftol = torch.finfo(thetas[0].dtype).eps if ftol is None else check_nonneg(ftol, "ftol")
    thetas = [t.detach() for t in thetas]
    n = len(thetas)
    kl_to = _KLToTargets(view, thetas, states)
    targets = [(m, ls) for m, ls, _ in kl_to.targets]

    def mean_obj(theta: Tensor) -> Tensor:  # F(θ)/N, differentiable in θ (the gradient's graph)
        mean, log_std = view.dist(theta, states)
        return sum(gaussian_kl(m, ls, mean, log_std).mean() for m, ls in targets) / n  # type: ignore[return-value]

    def mean_obj_value(theta: Tensor) -> float:  # float(mean_obj(θ)), the same number without a graph
        return float(sum(kl_to.kls(theta)) / n)

    theta = torch.stack(thetas).mean(0)
    f = mean_obj_value(theta)
    history, steps, residuals = [n * f], [], []
    for _ in range(iters):
        t = theta.detach().requires_grad_(True)
        (grad,) = torch.autograd.grad(mean_obj(t), t)

        fisher = FisherProducts(view, [theta], states)

        def avp(v: Tensor, fisher: FisherProducts = fisher) -> Tensor:
            return fisher(v)[0] + damping * v

        d, res = conjugate_gradient(avp, -grad, cg_iters, rtol=cg_rtol)
        residuals.append(res / max(float(grad.norm()), 1e-30))
        slope = float(grad @ d)
        if not slope < 0 or -0.5 * slope <= tol / n + ftol * f:
            break
        step, accepted = 1.0, False
        with torch.no_grad():
            for _ in range(21):
                f_new = mean_obj_value(theta + step * d)
                if f_new <= f + 1e-4 * step * slope:
                    accepted = True
                    break
                step *= 0.5
        if not accepted:
            break
        converged = f - f_new <= ftol * f
        theta, f = (theta + step * d).detach(), f_new
        history.append(n * f)
        steps.append(step)
        if converged:
            break
    if info is not None:
        info.update(objective=history, step_sizes=steps, cg_residuals=residuals, iters=len(steps))
    return theta.detach()


def linear_gaussian_optima(view: PolicyView, thetas: Sequence[Tensor], states: Tensor) -> dict[str, Tensor]:
    """Closed forms for a policy whose mean is LINEAR in θ and whose log-std is a parameter ``log_std``.

    * ``"eq47"`` — the exact argmin of Eq 4.7: mean parameters = the plain average (the mean of π_θ is
      then the average of the sub-policies' means), σ_a² = (1/N) Σ_i [σ_ia² + E_s (μ_ia(s) − μ̄_a(s))²]
      (moment matching per action dimension);
    * ``"eq410"`` — Eq 4.10 (undamped): the mean parameters of action dimension a are averaged with weights
      σ_ia⁻² / Σ_j σ_ja⁻² (the Fisher's mean block is E_s[φφᵀ]/σ_ia², its log-std block 2·1), and log σ is
      the plain average of the log σ_i.

    Requires a view over ``log_std`` and the parameters of one linear layer mapping states to means
    (e.g. ``GaussianPolicy(obs, act, hidden=())``).
    """
    if "log_std" not in view.names:
        raise ValueError(f"linear_gaussian_optima needs a 'log_std' parameter; the view has {list(view.names)}")
    thetas = [t.detach() for t in thetas]
    avg = torch.stack(thetas).mean(0)
    with torch.no_grad():
        dists = [view.dist(t, states) for t in thetas]
        mu_bar = torch.stack([m for m, _ in dists]).mean(0)
        var = torch.stack([torch.exp(2 * ls) + (m - mu_bar) ** 2 for m, ls in dists]).mean(0).mean(0)  # (A,)
    eq47 = view.params(avg)
    eq47 = {k: v.clone() for k, v in eq47.items()}
    eq47["log_std"] = 0.5 * torch.log(var).to(avg.dtype)
    parts = [view.params(t) for t in thetas]
    prec = torch.stack([torch.exp(-2 * p["log_std"]) for p in parts])  # (N, A)
    w = prec / prec.sum(0)
    eq410 = {}
    for k in view.names:
        vals = torch.stack([p[k] for p in parts])  # (N, A, ...) for the mean layer
        if k == "log_std":
            eq410[k] = vals.mean(0)
        else:
            eq410[k] = (w.view(w.shape + (1,) * (vals.dim() - 2)) * vals).sum(0)
    flat = {name: torch.cat([d[k].reshape(-1) for k in view.names]) for name, d in (("eq47", eq47), ("eq410", eq410))}
    return flat
