"""Tests of the exact Eq 4.7 aggregate (kl_exact), its objective and the linear-Gaussian closed forms.

The literal Eq 4.6/4.10/4.11 aggregates are tested in ``tests/test_mdl.py``.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.optimize import minimize
from torch.distributions import Normal, kl_divergence

from thesis_repro.mdl import aggregate as agg
from thesis_repro.mdl import exact

torch.set_num_threads(1)  # tiny ops: threads only add contention on the shared 2-core machine


def _linear(seed: int = 0, n: int = 4, obs: int = 3, act: int = 2, scale: float = 0.5, n_states: int = 200):
    """Linear-Gaussian policy (mean = W s + b, state-independent log-std) in float64, N perturbed copies."""
    pol = agg.GaussianPolicy(obs, act, hidden=(), seed=seed).double()
    view = agg.PolicyView(pol)
    states = torch.randn(n_states, obs, generator=torch.Generator().manual_seed(seed + 1), dtype=torch.float64)
    t0 = view.get_flat()
    gen = torch.Generator().manual_seed(seed + 2)
    thetas = [t0 + scale * torch.randn(t0.shape, generator=gen, dtype=torch.float64) for _ in range(n)]
    return view, states, thetas


def _mlp(seed: int, n: int = 4, scale: float = 0.2, hidden=(8,), n_states: int = 128):
    pol = agg.GaussianPolicy(3, 2, hidden=hidden, seed=seed, log_std_init=-0.5)
    view = agg.PolicyView(pol)
    states = torch.randn(n_states, 3, generator=torch.Generator().manual_seed(seed + 10))
    t0 = view.get_flat()
    gen = torch.Generator().manual_seed(seed + 20)
    return view, states, [t0 + scale * torch.randn(t0.shape, generator=gen) for _ in range(n)]


def _scipy_argmin(view, thetas, states, x0):
    """Independent minimiser of the true Eq 4.7 (L-BFGS-B on float64 autograd gradients)."""
    th = [t.double() for t in thetas]

    def fun(x):
        t = torch.tensor(x, dtype=torch.float64, requires_grad=True)
        m, ls = view.dist(t, states)
        val = sum(agg.gaussian_kl(*view.dist(ti, states), m, ls).mean() for ti in th)
        (g,) = torch.autograd.grad(val, t)
        return float(val.detach()), g.numpy()

    res = minimize(fun, x0.double().numpy(), jac=True, method="L-BFGS-B", options={"maxiter": 5000, "gtol": 1e-11})
    return torch.tensor(res.x, dtype=torch.float64), float(res.fun)


# --------------------------------------------------------------------------------- Eq 4.7 objective
def test_eq47_terms_are_kl_from_each_subpolicy_to_the_aggregate():
    """Direction of Eq 4.7: KL(π_θi ‖ π_θ), checked against torch.distributions."""
    view, states, thetas = _linear(n=3)
    theta = agg.params_avg(thetas) + 0.1
    kls = agg.eq47_kls(view, theta, thetas, states)
    m, ls = view.dist(theta, states)
    for k, t in zip(kls, thetas, strict=True):
        mi, lsi = view.dist(t, states)
        ref = kl_divergence(Normal(mi, lsi.exp()), Normal(m, ls.exp())).sum(-1).mean()
        rev = kl_divergence(Normal(m, ls.exp()), Normal(mi, lsi.exp())).sum(-1).mean()
        assert float(k) == pytest.approx(float(ref), rel=1e-10)
        assert abs(float(k) - float(rev)) > 1e-3  # the other direction is a different number
    assert agg.eq47_objective(view, theta, thetas, states) == pytest.approx(float(kls.sum()), rel=1e-12)
    assert agg.eq47_objective(view, thetas[0], thetas[:1], states) == 0.0
    with pytest.raises(ValueError, match="at least one sub-policy"):
        agg.eq47_kls(view, theta, [], states)


# ------------------------------------------------------------------------- linear-Gaussian closed forms
def test_closed_form_eq47_optimum_matches_numerical_argmin():
    """Derivation check: plain-average mean, moment-matched σ² = mean_i[σ_i² + E_s(μ_i − μ̄)²]."""
    view, states, thetas = _linear()
    closed = exact.linear_gaussian_optima(view, thetas, states)["eq47"]
    x, fmin = _scipy_argmin(view, thetas, states, agg.params_avg(thetas))
    np.testing.assert_allclose(closed.numpy(), x.numpy(), atol=1e-5)
    assert agg.eq47_objective(view, closed, thetas, states) <= fmin + 1e-9
    # the mean parameters ARE the plain average; only log σ moves (and moves up: the σ_i spread + mean spread)
    avg = view.params(agg.params_avg(thetas))
    got = view.params(closed)
    for k in view.names:
        if k != "log_std":
            assert torch.allclose(got[k], avg[k], atol=1e-12)
    assert (got["log_std"] > avg["log_std"]).all()


def test_closed_form_eq410_is_the_precision_weighted_average():
    """Undamped Eq 4.10 on a linear-Gaussian policy = the 1/σ_i²-weighted average of the mean parameters."""
    view, states, thetas = _linear()
    closed = exact.linear_gaussian_optima(view, thetas, states)["eq410"]
    dense = agg.kl_avg_dense(view, thetas, states, damping=0.0)
    assert torch.allclose(dense, closed, atol=1e-9)
    cg = agg.kl_avg(view, thetas, states, cg_iters=200, damping=0.0, cg_rtol=1e-12)
    assert torch.allclose(cg, closed, atol=1e-7)
    # hand-computed weights for the first weight entry (action dim 0)
    p = [view.params(t) for t in thetas]
    prec = torch.stack([torch.exp(-2 * q["log_std"][0]) for q in p])
    expect = (prec * torch.stack([q["mean_net.0.weight"][0, 0] for q in p])).sum() / prec.sum()
    assert float(view.params(closed)["mean_net.0.weight"][0, 0]) == pytest.approx(float(expect), rel=1e-12)
    # ... which is NOT the Eq 4.7 optimum: its Eq 4.7 value is higher than the exact one's
    optimum = exact.linear_gaussian_optima(view, thetas, states)["eq47"]
    assert agg.eq47_objective(view, closed, thetas, states) > agg.eq47_objective(view, optimum, thetas, states) + 0.1


def test_aggregate_fisher_is_the_hessian_at_the_eq47_optimum():
    """Gauss-Newton claim: at the Eq 4.7 optimum, ∇²(F/N) = I(θ) of the aggregate (linear-Gaussian case)."""
    view, states, thetas = _linear(n=3, obs=2, act=2)
    opt = exact.linear_gaussian_optima(view, thetas, states)["eq47"]
    n = len(thetas)

    def f(t):
        m, ls = view.dist(t, states)
        return sum(agg.gaussian_kl(*view.dist(ti, states), m, ls).mean() for ti in thetas) / n

    hess = torch.autograd.functional.hessian(f, opt)
    fim = agg.fisher_matrix(view, opt, states)
    assert torch.allclose(hess, fim, atol=1e-8)


# ---------------------------------------------------------------------------------------- kl_exact
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_kl_exact_reaches_the_closed_form_optimum(dtype):
    view, states, thetas = _linear()
    if dtype == torch.float32:
        view.module.float()
        states, thetas = states.float(), [t.float() for t in thetas]
    opt = exact.linear_gaussian_optima(view, thetas, states)["eq47"]
    info: dict = {}
    got = exact.kl_exact(view, thetas, states, iters=30, cg_iters=50, damping=0.0, info=info)
    assert got.dtype == dtype
    assert torch.allclose(got, opt, atol=1e-6 if dtype == torch.float64 else 1e-4)
    f_opt = agg.eq47_objective(view, opt, thetas, states)
    assert info["objective"][-1] == pytest.approx(f_opt, rel=1e-6 if dtype == torch.float64 else 1e-5)
    assert info["iters"] <= 10  # Fisher scoring: a handful of Newton steps, not a first-order crawl


def test_kl_exact_beats_params_avg_and_kl_avg_on_random_mlps():
    for seed in range(4):
        view, states, thetas = _mlp(seed)
        info: dict = {}
        ex = exact.kl_exact(view, thetas, states, iters=30, info=info)
        f_ex = agg.eq47_objective(view, ex, thetas, states)
        f_pa = agg.eq47_objective(view, agg.params_avg(thetas), thetas, states)
        f_ka = agg.eq47_objective(view, agg.kl_avg(view, thetas, states, cg_iters=50, damping=0.1), thetas, states)
        f_k0 = agg.eq47_objective(view, agg.kl_avg_dense(view, thetas, states, damping=0.0), thetas, states)
        assert f_ex < f_pa - 1e-3 and f_ex < f_ka and f_ex < f_k0
        # monotone decrease over the iterations, starting at params_avg's value
        obj = np.array(info["objective"])
        assert obj[0] == pytest.approx(f_pa, rel=1e-5)
        assert (np.diff(obj) <= 0).all() and len(obj) == info["iters"] + 1
        assert obj[-1] == pytest.approx(f_ex, rel=1e-5)
        assert all(0 < s <= 1 for s in info["step_sizes"])


def test_kl_exact_is_close_to_an_independent_local_minimum():
    view, states, thetas = _mlp(0, scale=0.1, hidden=(4,), n_states=64)
    view.module.double()
    states, thetas = states.double(), [t.double() for t in thetas]
    ex = exact.kl_exact(view, thetas, states, iters=100, cg_iters=50, cg_rtol=1e-6, damping=1e-6)
    _, fmin = _scipy_argmin(view, thetas, states, agg.params_avg(thetas))
    f_pa = agg.eq47_objective(view, agg.params_avg(thetas), thetas, states)
    f_ex = agg.eq47_objective(view, ex, thetas, states)
    assert f_ex - fmin < 1e-3 * (f_pa - fmin)  # closes > 99.9 % of params_avg's excess over the minimum


def test_kl_exact_fixed_points_and_zero_iterations():
    view, states, thetas = _mlp(1)
    same = [thetas[0].clone() for _ in range(3)]
    info: dict = {}
    out = exact.kl_exact(view, same, states, info=info)
    assert torch.allclose(out, thetas[0], atol=1e-6) and info["objective"][-1] < 1e-10
    assert torch.equal(exact.kl_exact(view, thetas, states, iters=0), agg.params_avg(thetas))


def test_kl_exact_bad_arguments():
    view, states, thetas = _mlp(0)
    with pytest.raises(ValueError, match="at least one sub-policy"):
        exact.kl_exact(view, [], states)
    with pytest.raises(ValueError, match="iters must be >= 0"):
        exact.kl_exact(view, thetas, states, iters=-1)
    with pytest.raises(ValueError, match="cg_iters must be >= 1"):
        exact.kl_exact(view, thetas, states, cg_iters=0)
    with pytest.raises(ValueError, match="damping"):
        exact.kl_exact(view, thetas, states, damping=-1.0)
    with pytest.raises(ValueError, match="cg_rtol"):
        exact.kl_exact(view, thetas, states, cg_rtol=float("nan"))
    with pytest.raises(ValueError, match="shape"):
        exact.kl_exact(view, [torch.zeros(3)], states)
    with pytest.raises(ValueError, match="log_std"):
        exact.linear_gaussian_optima(agg.PolicyView(view.module, ["mean_net.0.weight"]), thetas, states)


# ------------------------------------------------------------------ closed-form batched Fisher products
def _sb3_actor(hidden=(8, 8), activation=torch.nn.Tanh, obs_dim: int = 5, act_dim: int = 3, seed: int = 0):
    import gymnasium as gym
    from stable_baselines3.common.policies import ActorCriticPolicy

    torch.manual_seed(seed)
    obs, act = gym.spaces.Box(-1, 1, (obs_dim,)), gym.spaces.Box(-1, 1, (act_dim,))
    kw = dict(net_arch=dict(pi=list(hidden), vf=[4]), activation_fn=activation, log_std_init=-0.3)
    return ActorCriticPolicy(obs, act, lambda _: 3e-4, **kw)


def _perturbed(view, n: int, scale: float, seed: int):
    t0 = view.get_flat()
    gen = torch.Generator().manual_seed(seed)
    return [t0 + scale * torch.randn(t0.shape, generator=gen, dtype=t0.dtype) for _ in range(n)]


@pytest.mark.parametrize("activation", [torch.nn.Tanh, torch.nn.ReLU])
def test_closed_form_fvp_equals_the_autograd_fvp_on_sb3_policies(activation):
    """The batched closed-form I(θ_i) v of FisherProducts = fisher_vector_product (jvp + vjp) per domain."""
    pol = _sb3_actor(activation=activation)
    view = agg.PolicyView.from_sb3(pol)
    assert view.mlp is not None and view.mlp.activations == ("tanh",) * 2 if activation is torch.nn.Tanh else True
    thetas = _perturbed(view, 4, 0.1, 1)
    states = torch.randn(64, 5, generator=torch.Generator().manual_seed(2))
    fp = agg.FisherProducts(view, thetas, states)
    assert fp.closed_form
    gen = torch.Generator().manual_seed(3)
    shared = torch.randn(view.numel, generator=gen)
    stack = torch.randn(4, view.numel, generator=gen)
    ref_shared = torch.stack([agg.fisher_vector_product(view, t, states, shared) for t in thetas])
    ref_stack = torch.stack([agg.fisher_vector_product(view, t, states, v) for t, v in zip(thetas, stack, strict=True)])
    scale = float(ref_stack.abs().max())
    assert torch.allclose(fp(shared), ref_shared, rtol=1e-5, atol=1e-6 * scale)
    assert torch.allclose(fp(stack), ref_stack, rtol=1e-5, atol=1e-6 * scale)
    assert torch.allclose(fp.mean(shared), ref_shared.mean(0), rtol=1e-5, atol=1e-6 * scale)
    # the fast dist path is the SB3 policy's own distribution
    for t in thetas[:2]:
        view.set_flat(t)
        mean, log_std = view.dist(t, states)
        d = pol.get_distribution(states).distribution
        assert torch.equal(mean, d.mean) and torch.allclose(log_std.exp(), d.stddev)


def test_closed_form_fvp_equals_the_dense_fisher_in_float64():
    """Exactness (not just agreement in float32): GaussianPolicy MLP and linear policy vs the dense FIM."""
    for hidden in ((6, 5), ()):
        pol = agg.GaussianPolicy(3, 2, hidden=hidden, seed=4, log_std_init=-0.4).double()
        view = agg.PolicyView(pol)
        assert view.mlp is not None
        thetas = _perturbed(view, 3, 0.2, 5)
        states = torch.randn(40, 3, generator=torch.Generator().manual_seed(6), dtype=torch.float64)
        fp = agg.FisherProducts(view, thetas, states)
        vs = torch.randn(3, view.numel, generator=torch.Generator().manual_seed(7), dtype=torch.float64)
        dense = torch.stack([agg.fisher_matrix(view, t, states) @ v for t, v in zip(thetas, vs, strict=True)])
        assert torch.allclose(fp(vs), dense, rtol=1e-10, atol=1e-12)


def test_fisher_products_fall_back_to_autograd_for_other_views():
    pol = agg.GaussianPolicy(3, 2, hidden=(4,), seed=0)
    partial = agg.PolicyView(pol, [n for n, _ in pol.named_parameters() if n != "log_std"])
    custom = agg.PolicyView(pol, dist_fn=lambda m, s: m(s))
    states = torch.randn(16, 3, generator=torch.Generator().manual_seed(0))
    for view in (partial, custom):
        assert view.mlp is None
        thetas = _perturbed(view, 2, 0.1, 0)
        fp = agg.FisherProducts(view, thetas, states)
        v = torch.ones(view.numel)
        assert not fp.closed_form
        ref = torch.stack([agg.fisher_vector_product(view, t, states, v) for t in thetas])
        assert torch.equal(fp(v), ref)
    with pytest.raises(ValueError, match="v must have shape"):
        fp(torch.ones(3))
    with pytest.raises(ValueError, match="at least one policy"):
        agg.FisherProducts(custom, [], states)


def test_kl_avg_and_kl_exact_are_unchanged_by_the_closed_form():
    """Same aggregates whether the products are closed-form or autograd (a view without the MLP spec)."""
    view, states, thetas = _mlp(3, hidden=(6, 6))
    view.module.double()  # float64: the two paths differ only by rounding, which Newton steps would amplify
    states, thetas = states.double(), [t.double() for t in thetas]
    slow = agg.PolicyView(view.module, dist_fn=lambda m, s: m(s))
    assert view.mlp is not None and slow.mlp is None
    for fn in (
        lambda v: agg.kl_avg(v, thetas, states, cg_iters=10, damping=0.1),
        lambda v: exact.kl_exact(v, thetas, states, iters=5, damping=0.1),  # well-conditioned: CG is stable
    ):
        assert torch.allclose(fn(view), fn(slow), rtol=1e-9, atol=1e-10)


def test_kl_exact_stops_when_the_objective_no_longer_moves():
    """ftol: a step that lowers F by <= ftol·F ends the iterations (float32 rounding, not progress)."""
    view, states, thetas = _mlp(0)
    loose, strict = {}, {}
    exact.kl_exact(view, thetas, states, iters=30, ftol=1e-2, info=loose)
    exact.kl_exact(view, thetas, states, iters=30, ftol=0.0, info=strict)
    assert loose["iters"] < strict["iters"]
    f = loose["objective"]
    assert all(a - b > 1e-2 * a for a, b in zip(f[:-2], f[1:-1], strict=True))  # every step but the last moved F
    assert strict["objective"][-1] <= f[-1] <= f[0]
    with pytest.raises(ValueError, match="ftol"):
        exact.kl_exact(view, thetas, states, ftol=-1.0)


# ------------------------------------------------------------------------ relative CG tolerance
def test_cg_tolerance_is_relative():
    gen = torch.Generator().manual_seed(0)
    m = torch.randn(30, 30, generator=gen, dtype=torch.float64)
    a = m @ m.T + 0.1 * torch.eye(30, dtype=torch.float64)
    b = torch.randn(30, generator=gen, dtype=torch.float64)
    calls = []

    def avp(v):
        calls.append(1)
        return a @ v

    counts = []
    for scale in (1e-6, 1.0, 1e6):  # same number of products whatever the scale of b
        calls.clear()
        x, res = agg.conjugate_gradient(avp, scale * b, iters=500, rtol=1e-4)
        assert res <= 1e-4 * scale * float(b.norm())
        counts.append(len(calls))
        assert torch.allclose(x, scale * torch.linalg.solve(a, b), rtol=1e-2, atol=0)
    assert counts[0] == counts[1] == counts[2] < 500
    with pytest.raises(ValueError, match="cg_rtol"):
        agg.conjugate_gradient(avp, b, rtol=-1.0)


def test_kl_avg_cg_rtol_controls_accuracy():
    view, states, thetas = _mlp(2)
    dense = agg.kl_avg_dense(view, thetas, states, damping=0.1)
    loose, tight = {}, {}
    a = agg.kl_avg(view, thetas, states, cg_iters=200, damping=0.1, cg_rtol=0.3, info=loose)
    b = agg.kl_avg(view, thetas, states, cg_iters=200, damping=0.1, cg_rtol=1e-5, info=tight)
    assert tight["cg_residual"] < loose["cg_residual"]
    assert (b - dense).norm() < (a - dense).norm()
    assert torch.allclose(b, dense, atol=1e-4)


# ------------------------------------------------------------------- analysis page computations
def test_analysis_problems_and_tables():
    from thesis_repro.mdl import kl_analysis as ka

    with pytest.raises(ValueError, match="valid problem kinds are: 'perturb', 'update'"):
        ka.make_problem(0, kind="shuffle")
    with pytest.raises(ValueError, match="n_domains"):
        ka.make_problem(0, n_domains=1)
    p = ka.make_problem(0, hidden=(4,), n_states=32)
    assert len(p.thetas) == 4 and all(t.dtype == torch.float64 for t in p.thetas)
    # "update" sub-policies moved from θ_old, by a modest KL, and differently per domain
    kls = agg.eq47_kls(p.view, p.theta_old, p.thetas, p.states)
    assert (kls > 1e-4).all() and (kls < 1.0).all() and len(set(kls.tolist())) == 4
    table = ka.compare_aggregates([p], reference_iters=30)
    by = table.set_index("aggregate")
    assert (by["excess"] >= -1e-10).all()  # θ* is at least as good as every aggregate
    assert by.loc["params_avg", "dist_ratio"] == pytest.approx(1.0)
    assert by.loc["params_avg", "eq47"] == pytest.approx(p.objective(agg.params_avg(p.thetas)))
    s = ka.summarise_aggregates(table)
    assert list(s.index) == list(ka.AGGREGATES)
    assert s.loc["params_avg", "beats_params_avg"] == 0.0 and s.loc["kl_exact", "beats_params_avg"] == 1.0
    assert s.loc["params_avg", "median_eq47_vs_avg"] == pytest.approx(1.0)


def test_analysis_linear_gaussian_table_and_slopes():
    from thesis_repro.mdl import kl_analysis as ka

    lin = ka.linear_gaussian(0, n_states=64)
    assert lin.loc["kl_exact", "dist_to_closed_form"] < 1e-5
    assert lin.loc["eq4.10", "eq47"] == pytest.approx(lin.loc["closed form (Eq 4.10)", "eq47"], rel=1e-9)
    assert lin.loc["params_avg", "mean_params_minus_plain_avg"] == 0.0
    assert lin.loc["closed form (Eq 4.10)", "mean_params_minus_plain_avg"] > 1e-3
    assert lin.loc["closed form (Eq 4.7)", "eq47"] < lin.loc["params_avg", "eq47"] < lin.loc["eq4.10", "eq47"]
    assert ka.equal_fisher_check() < 1e-10
    # the true correction is O(δ²) (checked in the asymptotic range)
    sc = ka.spread_scaling([1e-3, 1e-2], hidden=(4,), n_states=32, reference_iters=30)
    assert ka.loglog_slopes(sc, ["true_step"])["true_step"] == pytest.approx(2.0, abs=0.2)
    with pytest.raises(ValueError, match="two spreads"):
        ka.loglog_slopes(sc.iloc[:1], ["true_step"])


def test_analysis_verdict_statuses():
    import pandas as pd

    from thesis_repro.claims import analysis_4_kl, report
    from thesis_repro.mdl import kl_analysis as ka

    lin = pd.DataFrame(
        {"eq47": [1.0, 3.0, 2.0, 2.5, 3.0, 1.0]},
        index=["closed form (Eq 4.7)", "closed form (Eq 4.10)", "params_avg", "kl_avg", "eq4.10", "kl_exact"],
    )

    def summary(beats_kl_avg: float) -> pd.DataFrame:
        return pd.DataFrame(
            {
                "beats_params_avg": [0.0, beats_kl_avg, 0.0, 1.0],
                "problems": [4] * 4,
                "median_dist_ratio": [1.0, 3.0, 100.0, 0.3],
                "median_excess": [1e-3, 2e-3, 1.0, 1e-9],
                "median_eq47_vs_avg": [1.0, 1.01, 100.0, 0.99],
            },
            index=list(ka.AGGREGATES),
        )

    got = [v.status for v in analysis_4_kl.kl_verdicts(summary(0.0), lin, "small")]
    assert got == [report.DOES_NOT, report.DOES_NOT, report.REPRODUCES]
    assert analysis_4_kl.kl_verdicts(summary(0.5), lin, "small")[0].status == report.PARTLY
    assert analysis_4_kl.kl_verdicts(summary(1.0), lin, "small")[0].status == report.REPRODUCES
    assert {v.status for v in analysis_4_kl.kl_verdicts(summary(1.0), lin, "smoke")} == {report.NOT_JUDGED}
    bad = lin.copy()
    bad.loc["kl_exact", "eq47"] = 1.5  # did not reach the closed form
    assert analysis_4_kl.kl_verdicts(summary(0.0), bad, "small")[2].status == report.DOES_NOT
