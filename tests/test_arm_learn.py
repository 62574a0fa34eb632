"""Learning and transfer for the 2-D arm (chapter 5): CMA-ES driver, HOSVD, Matrix SVD, Algorithm 5."""

from __future__ import annotations

import numpy as np
import pytest

from thesis_repro.arm import learn, transfer


# ---------------------------------------------------------------- CMA-ES driver
def test_cma_lockstep_batches_every_generation_in_one_call():
    calls = []

    def evaluate(X):
        calls.append(X.shape)
        return ((X - np.arange(X.shape[0])[:, None, None]) ** 2).sum(-1)

    res = learn.cma_lockstep(evaluate, np.zeros((3, 5)), 0.5, generations=80, popsize=8, seed=0)
    assert calls == [(3, 8, 5)] * 80  # one call per generation, whole populations of all problems
    np.testing.assert_allclose(res.x, np.arange(3)[:, None] * np.ones((3, 5)), atol=0.05)
    assert res.curve.shape == res.success.shape == res.best.shape == (3, 80)
    assert np.all(np.diff(res.best, axis=1) <= 0)  # best-so-far is monotone
    np.testing.assert_allclose(res.total_cost, 8 * res.curve.sum(axis=1))
    assert res.trials[-1] == 8 * 80


def test_cma_lockstep_is_seeded_and_records_task_cost_not_fitness():
    def evaluate(X):
        cost = (X**2).sum(-1)
        return cost + 100.0, cost, (cost < 0.01).astype(float)

    a = learn.cma_lockstep(evaluate, np.ones((2, 3)), 0.3, generations=20, seed=4)
    b = learn.cma_lockstep(evaluate, np.ones((2, 3)), 0.3, generations=20, seed=4)
    np.testing.assert_array_equal(a.curve, b.curve)
    assert a.curve.max() < 50  # the regularised fitness (+100) is not what the curve records
    assert 0.0 <= a.success.min() and a.success.max() <= 1.0


def test_cma_lockstep_rejects_bad_arguments():
    with pytest.raises(ValueError, match="sigma0"):
        learn.cma_lockstep(lambda X: X.sum(-1), np.zeros((1, 2)), 0.0, generations=2)
    with pytest.raises(ValueError, match="generations"):
        learn.cma_lockstep(lambda X: X.sum(-1), np.zeros((1, 2)), 0.1, generations=0)


# ---------------------------------------------------------------- HOSVD (Algorithm 4)
def test_hosvd_exact_at_full_rank_and_factors_orthonormal():
    W = np.random.default_rng(0).normal(size=(7, 2, 5))
    t = transfer.hosvd(W, W.shape)
    np.testing.assert_allclose(t.to_tensor(), W, atol=1e-10)
    for U in t.factors:
        np.testing.assert_allclose(U.T @ U, np.eye(U.shape[1]), atol=1e-10)
    # Eq 5.11: G = X ×1 U1ᵀ ×2 U2ᵀ ×3 U3ᵀ, checked with an explicit einsum
    U1, U2, U3 = t.factors
    np.testing.assert_allclose(t.core, np.einsum("dap,di,aj,pk->ijk", W, U1, U2, U3), atol=1e-10)


def test_hosvd_truncation_matches_mode_svd_and_low_rank_tensor_is_recovered():
    rng = np.random.default_rng(1)
    G = rng.normal(size=(3, 2, 2))
    Us = [np.linalg.qr(rng.normal(size=(n, r)))[0] for n, r in ((8, 3), (2, 2), (6, 2))]
    X = np.einsum("ijk,di,aj,pk->dap", G, *Us)
    t = transfer.hosvd(X, (3, 2, 2))
    np.testing.assert_allclose(t.to_tensor(), X, atol=1e-10)  # rank-(3,2,2) tensor recovered exactly
    assert t.latent().shape == (8, 2, 2)
    np.testing.assert_allclose(transfer.compose(t.latent(), t.factors[2]), np.moveaxis(X, 2, 0), atol=1e-10)
    with pytest.raises(ValueError, match="ranks"):
        transfer.hosvd(X, (9, 2, 2))


def test_matrix_svd_shapes_and_full_rank_reconstruction():
    W = np.random.default_rng(2).normal(size=(6, 2, 4))
    L, S = transfer.matrix_svd(W, 4)
    assert L.shape == (6, 2, 4) and S.shape == (4, 4)
    np.testing.assert_allclose(transfer.compose(L, S), np.moveaxis(W, 2, 0), atol=1e-10)


@pytest.mark.parametrize("kind", transfer.STRATEGIES)
def test_subspace_initialisation_shapes(kind):
    D, A, P = 9, 2, 5
    W = np.random.default_rng(3).normal(size=(D, A, P))
    sub = transfer.make_subspace(W, kind, (4, 2, 3))
    L = sub.latent(sub.theta0)
    assert L.shape == (D, A, 3) and sub.s0.shape == (P, 3)
    assert transfer.compose(L, sub.s0[0]).shape == (D, A)
    n_theta = 4 * 2 * 3 + D * 4 + A * 2 if kind == "tensor" else D * A * 3
    assert sub.theta0.shape == (n_theta,)
    batched = sub.latent(np.tile(sub.theta0, (2, 3, 1)))
    assert batched.shape == (2, 3, D, A, 3)


def test_unknown_strategy_names_valid_choices():
    with pytest.raises(ValueError, match="'tensor', 'matrix'"):
        transfer.make_subspace(np.ones((3, 2, 2)), "cp")


def test_alternation_improves_toy_objective():
    rng = np.random.default_rng(4)
    W_src = rng.normal(size=(6, 2, 5))
    target = W_src[:, :, 0] + 0.3 * rng.normal(size=(6, 2))  # close to, but outside, the source span

    def objective(W):
        cost = ((W - target) ** 2).sum(axis=(-2, -1))
        return cost, (cost < 0.5).astype(float)

    res = transfer.alternate(
        objective,
        transfer.make_subspace(W_src, "tensor", (4, 2, 3)),
        2,
        rounds=2,
        generations=25,
        sigma_s=0.1,
        sigma_L=0.05,
        seed=0,
    )
    assert res.curve.shape == (2, 100) and res.phases[:25] == ["s"] * 25 and res.phases[25] == "L"
    final = objective(res.W)[0]
    start = res.curve[:, :3].mean(axis=1)
    assert np.all(final < 0.5 * start)
    # the L phases bring a further improvement over the s-only phase of round 1
    assert np.all(res.curve[:, -5:].mean(axis=1) < res.curve[:, 20:25].mean(axis=1))


# ---------------------------------------------------------------- the arm: objective, MTL, strategies
from thesis_repro.arm import RBFPolicy, baselines, curriculum, sample_tasks, simulate  # noqa: E402  # noqa: E402


def test_arm_objective_matches_simulate_row_by_row():
    rng = np.random.default_rng(5)
    tasks = sample_tasks("bic", 2, rng)
    W = np.tile(RBFPolicy(n_basis=6).default_params(), (2, 3, 1, 1))
    W[..., :6, :] += 0.3 * rng.normal(size=(2, 3, 6, 2))
    fit, cost, succ = learn.arm_objective("bic", tasks)(W)
    assert fit.shape == cost.shape == succ.shape == (2, 3)
    ref = simulate("bic", tasks[1], W[1, 2])
    assert cost[1, 2] == pytest.approx(float(ref.task_cost[0]))
    shaped_fit, shaped_cost, _ = learn.arm_objective("bic", tasks, shaped=True)(W)
    np.testing.assert_allclose(shaped_cost, cost)  # the curve's task cost is never the shaped one
    assert np.all(shaped_fit >= cost - 1e-12)


def test_closed_loop_adapter_reproduces_simulate_for_a_pd_controller():
    rng = np.random.default_rng(6)
    pol = RBFPolicy(n_basis=8)
    for family in ("reach", "throw", "bic", "cast"):
        tasks = sample_tasks(family, 4, rng)
        W = np.tile(pol.default_params(), (4, 1, 1))
        W[:, :8] += 0.2 * rng.normal(size=(4, 8, 2))
        xd, vd = pol.desired(W)
        kp, kd = pol.gains(W)
        ref = simulate(family, tasks, W)

        def pd(t, p, v, kp=kp, kd=kd, xd=xd, vd=vd):
            return kp * (xd[:, t] - p) + kd * (vd[:, t] - v)

        got = baselines.closed_loop_simulate(family, tasks, pd, 4)
        np.testing.assert_allclose(got.task_cost, ref.task_cost)
        np.testing.assert_array_equal(got.success, ref.success)


@pytest.mark.parametrize(("kind", "n_params"), [("ella", 8), ("rbf-ella", 250), ("fcnn", 66)])
def test_competitor_policies_shapes_and_parameter_counts(kind, n_params):
    pol = baselines.ClosedLoopPolicy(kind)
    assert pol.n_params == n_params  # ELLA: [x, v, t, 1] per actuator; RBF-ELLA: 5x5x5 tiles per actuator
    theta = np.random.default_rng(0).normal(size=(3, n_params))
    a = pol.action(theta, 10, np.zeros((3, 2)), np.zeros((3, 2)))
    assert a.shape == (3, 2) and np.all(np.isfinite(a))
    np.testing.assert_allclose(pol.action(np.zeros((3, n_params)), 10, np.ones((3, 2)), np.ones((3, 2))), 0.0)


def test_ella_policy_is_linear_in_state_and_time():
    pol = baselines.ClosedLoopPolicy("ella")
    w = np.zeros((1, 4, 2))
    w[0, 0, 0], w[0, 3, 1] = 2.0, -1.0  # a_x = 2 x/pos_scale, a_y = -1 (bias), times acc_scale
    a = pol.action(w.reshape(1, 8), 0, np.array([[0.15, 0.0]]), np.zeros((1, 2)))
    np.testing.assert_allclose(a, [[pol.acc_scale * 2 * 0.15 / pol.pos_scale, -pol.acc_scale]])
    with pytest.raises(ValueError, match="'ella', 'rbf-ella', 'fcnn'"):
        baselines.ClosedLoopPolicy("svm")


def test_mtl_refine_improves_reach_and_keeps_factor_shapes():
    rng = np.random.default_rng(7)
    tasks = sample_tasks("reach", 3, rng)
    W = np.tile(RBFPolicy(n_basis=6).default_params(), (3, 1, 1))
    W[:, :6] += 0.05 * rng.normal(size=(3, 6, 2))
    res = learn.mtl_refine("reach", tasks, W, (6, 2, 3), generations=25, sigma=0.1, popsize=8, seed=0)
    assert res.W.shape == (3, 8, 2) and res.core.shape == (6, 2, 3)
    assert [u.shape for u in res.factors] == [(8, 6), (2, 2), (3, 3)]
    assert res.curve[-5:].mean() < 0.5 * res.curve[:3].mean()
    with pytest.raises(ValueError, match="task rows"):
        learn.mtl_refine("reach", tasks[:2], transfer.hosvd(np.moveaxis(W, 0, 2), (6, 2, 3)), generations=1)


@pytest.mark.parametrize("strategy", baselines.STRATEGIES)
def test_every_strategy_gets_the_same_budget(strategy):
    rng = np.random.default_rng(8)
    targets = sample_tasks("throw", 2, rng)
    if strategy in baselines.COMPETITORS:
        sources = 0.1 * rng.normal(size=(4, baselines.ClosedLoopPolicy(strategy).n_params))
    else:
        sources = np.tile(RBFPolicy(n_basis=6).default_params(), (4, 1, 1)) + 0.1 * rng.normal(size=(4, 8, 2))
    out = baselines.learn_target(
        strategy, "throw", targets, sources, rounds=1, phase_generations=2, popsize=5, ranks=(4, 2, 3), n_basis=6
    )
    assert out["curve"].shape == out["success_curve"].shape == (2, 4)
    assert out["trials"].tolist() == [5, 10, 15, 20]
    np.testing.assert_allclose(out["total_cost"], 5 * out["curve"].sum(1))
    assert out["final_success"].shape == (2,) and set(np.unique(out["final_success"])) <= {0.0, 1.0}


def test_curriculum_job_shapes_and_conditions():
    cfg = {"n_tasks": 2, "pretrain_trials": 8, "bic_trials": 8, "popsize": 4, "ranks": [4, 2, 2], "seed": 0}
    for condition in curriculum.CONDITIONS:
        out = curriculum.curriculum_job({**cfg, "condition": condition})
        assert out["curve"].shape == out["success_curve"].shape == (2,)
        assert out["trials"].tolist() == [4, 8]
        assert 0.0 <= out["success_rate"] <= 1.0
    assert "pretrain_reach_curve" in out or "pretrain_bic_curve" in out
    with pytest.raises(ValueError, match="'CL', 'NC'"):
        curriculum.curriculum_job({**cfg, "condition": "random"})


def test_source_and_target_jobs_through_the_run_cache():
    from thesis_repro.core.cache import Job, RunCache

    src = learn.source_config("reach", n_tasks=3, generations=4, mtl_generations=3, popsize=6, ranks=[4, 2, 3])
    assert src["sim_version"] >= 1 and src["algo_version"] == learn.ALGO_VERSION
    res = RunCache().run(Job("thesis_repro.arm.learn:source_job", src))
    assert res["W"].shape == (3, 12, 2) and res["tasks"].shape == (3, 2)
    assert np.all(res["cost"] <= res["stage1_cost"] + 1e-9)  # MTL refinement is kept only where it helps
    tgt = {
        "source": src,
        "target": "bic",
        "strategy": "tensor",
        "n_targets": 2,
        "rounds": 1,
        "phase_generations": 2,
        "popsize": 5,
        "ranks": [4, 2, 3],
    }
    out = RunCache().run(Job("thesis_repro.arm.baselines:target_job", tgt))
    assert out["curve"].shape == (2, 4) and 0.0 <= out["success_rate"] <= 1.0
    assert RunCache().run(Job("thesis_repro.arm.learn:source_job", src)).from_cache
    with pytest.raises(ValueError, match="unknown source setting"):
        learn.source_config("reach", n_task=3)
