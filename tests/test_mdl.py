"""Tests of the multi-domain learners: aggregation math (Eq 4.6-4.11) and each learner's defining step."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.optimize import minimize

from thesis_repro.mdl import aggregate as agg

torch.set_num_threads(1)  # tiny ops: threads only add contention on the shared 2-core machine


def _setup(seed: int = 0, n: int = 3, scale: float = 0.05, hidden=(4,), n_states: int = 64):
    torch.manual_seed(seed)
    pol = agg.GaussianPolicy(3, 2, hidden=hidden, seed=seed, log_std_init=-0.5)
    view = agg.PolicyView(pol)
    states = torch.randn(n_states, 3, generator=torch.Generator().manual_seed(seed + 100))
    t0 = view.get_flat()
    gen = torch.Generator().manual_seed(seed + 1)
    thetas = [t0 + scale * torch.randn(t0.shape, generator=gen) for _ in range(n)]
    return view, states, t0, thetas


def test_params_avg_eq_4_6_flat_and_state_dict():
    a, b = torch.tensor([1.0, 2.0]), torch.tensor([3.0, 6.0])
    assert torch.equal(agg.params_avg([a, b]), torch.tensor([2.0, 4.0]))
    sd = agg.params_avg([{"w": a, "n": torch.tensor(3)}, {"w": b, "n": torch.tensor(3)}])
    assert torch.equal(sd["w"], torch.tensor([2.0, 4.0])) and sd["n"].item() == 3
    with pytest.raises(ValueError, match="at least one"):
        agg.params_avg([])


def test_fvp_matches_dense_fim_and_fim_is_psd():
    view, states, t0, _ = _setup()
    fim = agg.fisher_matrix(view, t0, states)
    assert torch.allclose(fim, fim.T, atol=1e-6)
    assert torch.linalg.eigvalsh(fim.double()).min() > -1e-6
    v = torch.randn(t0.shape, generator=torch.Generator().manual_seed(5))
    assert torch.allclose(agg.fisher_vector_product(view, t0, states, v), fim @ v, atol=1e-5)
    # log-std block is analytic: 2 * identity (state-independent log-std)
    assert view.names[0] == "log_std"
    assert torch.allclose(fim[:2, :2], 2.0 * torch.eye(2), atol=1e-6)
    assert torch.allclose(fim[:2, 2:], torch.zeros(2, view.numel - 2), atol=1e-6)


def test_quadratic_approximation_matches_true_kl_for_small_steps():
    view, states, t0, _ = _setup()
    v = torch.randn(t0.shape, generator=torch.Generator().manual_seed(7))
    v = v / v.norm()
    fim = agg.fisher_matrix(view, t0, states).double()
    for eps in (1e-2, 3e-3):
        true = agg.mean_kl(view, t0, t0 + eps * v, states).item()
        quad = 0.5 * eps**2 * (v.double() @ fim @ v.double()).item()
        assert true == pytest.approx(quad, rel=0.05)


def test_closed_form_equals_numerical_argmin_of_eq_4_8():
    view, states, _, thetas = _setup(n=4, n_states=128)
    fims = [agg.fisher_matrix(view, t, states).double().numpy() for t in thetas]
    th = [t.double().numpy() for t in thetas]

    def objective(x):
        d = [ti - x for ti in th]
        val = sum(di @ f @ di for di, f in zip(d, fims, strict=True))
        grad = -2 * sum(f @ di for di, f in zip(d, fims, strict=True))
        return val, grad

    x0 = np.mean(th, axis=0)
    res = minimize(objective, x0, jac=True, method="L-BFGS-B", options={"maxiter": 5000, "gtol": 1e-12, "ftol": 1e-16})
    closed = agg.kl_avg_dense(view, thetas, states, damping=0.0).double().numpy()
    assert objective(closed)[0] <= res.fun + 1e-9
    np.testing.assert_allclose(closed, res.x, atol=2e-3)
    # and it differs from the Euclidean mean (the FIMs are not equal)
    assert objective(closed)[0] < objective(x0)[0] - 1e-6


def test_identical_subpolicies_are_returned_unchanged():
    view, states, t0, thetas = _setup()
    same = [thetas[0].clone() for _ in range(4)]
    for damping in (0.0, 0.1):
        out = agg.kl_avg(view, same, states, t0, cg_iters=10, damping=damping)
        assert torch.allclose(out, thetas[0], atol=1e-6)
    assert torch.allclose(agg.params_avg(same), thetas[0])


def test_equal_fisher_matrices_reduce_kl_avg_to_params_avg():
    # a linear-Gaussian policy with only the log-std moved has FIM independent of theta... use a
    # policy whose mean is linear in θ with fixed log-std: then I(θ_i) are all equal.
    pol = agg.GaussianPolicy(3, 2, hidden=(), seed=0)
    names = [n for n, _ in pol.named_parameters() if n != "log_std"]
    view = agg.PolicyView(pol, names)
    states = torch.randn(50, 3, generator=torch.Generator().manual_seed(1))
    t0 = view.get_flat()
    gen = torch.Generator().manual_seed(2)
    thetas = [t0 + torch.randn(t0.shape, generator=gen) for _ in range(4)]
    f = [agg.fisher_matrix(view, t, states) for t in thetas]
    assert all(torch.allclose(f[0], fi, atol=1e-6) for fi in f)
    out = agg.kl_avg(view, thetas, states, t0, cg_iters=20, damping=0.0)
    assert torch.allclose(out, agg.params_avg(thetas), atol=1e-5)


def test_huge_damping_gives_params_avg():
    view, states, t0, thetas = _setup()
    out = agg.kl_avg(view, thetas, states, t0, cg_iters=10, damping=1e8)
    assert torch.allclose(out, agg.params_avg(thetas), atol=1e-6)


@pytest.mark.parametrize("damping", [1e-2, 0.1])
def test_cg_solve_agrees_with_dense_solve(damping):
    view, states, t0, thetas = _setup(n=4)
    info: dict = {}
    cg = agg.kl_avg(view, thetas, states, t0, cg_iters=60, damping=damping, info=info)
    dense = agg.kl_avg_dense(view, thetas, states, damping=damping)
    assert info["cg_residual"] < 1e-3
    assert torch.allclose(cg, dense, atol=1e-4)
    # theta_old cancels out of Eq 4.11
    other = agg.kl_avg(view, thetas, states, None, cg_iters=60, damping=damping)
    assert torch.allclose(cg, other, atol=1e-4)


def test_conjugate_gradient_on_spd_system():
    a = torch.tensor([[4.0, 1.0], [1.0, 3.0]])
    b = torch.tensor([1.0, 2.0])
    x, res = agg.conjugate_gradient(lambda v: a @ v, b, iters=10)
    assert torch.allclose(x, torch.linalg.solve(a, b), atol=1e-6) and res < 1e-5
    with pytest.raises(ValueError, match="iters"):
        agg.conjugate_gradient(lambda v: a @ v, b, iters=0)


def test_view_errors_and_entropy():
    pol = agg.GaussianPolicy(2, 1, hidden=(3,))
    with pytest.raises(ValueError, match="valid names"):
        agg.PolicyView(pol, ["nope"])
    view = agg.PolicyView(pol)
    with pytest.raises(ValueError, match="shape"):
        view.params(torch.zeros(3))
    with pytest.raises(ValueError, match="damping"):
        agg.kl_avg(view, [view.get_flat()], torch.zeros(2, 2), damping=-1.0)
    h = agg.entropy(view, view.get_flat(), torch.zeros(4, 2)).item()
    assert h == pytest.approx(0.5 * np.log(2 * np.pi * np.e))  # log_std = 0, one action dim
    t = view.get_flat() + 1.0
    view.set_flat(t)
    assert torch.equal(view.get_flat(), t)


def test_sb3_view_selects_actor_parameters():
    import gymnasium as gym
    from stable_baselines3.common.policies import ActorCriticPolicy

    obs = gym.spaces.Box(-1, 1, (3,))
    act = gym.spaces.Box(-1, 1, (2,))
    pol = ActorCriticPolicy(obs, act, lambda _: 3e-4, net_arch=dict(pi=[8], vf=[8]))
    view = agg.PolicyView.from_sb3(pol)
    assert not any("value" in n for n in view.names) and "log_std" in view.names
    s = torch.randn(5, 3)
    mean, log_std = view.dist(view.get_flat(), s)
    dist = pol.get_distribution(s)
    assert torch.allclose(mean, dist.distribution.mean, atol=1e-6)
    assert torch.allclose(log_std.exp(), dist.distribution.stddev, atol=1e-6)


# ------------------------------------------------------------------------------------------ learners
from thesis_repro.mdl import train as mt  # noqa: E402
from thesis_repro.mdl.config import ALGORITHMS, mdl_config  # noqa: E402

TINY = dict(
    n_domains=2,
    steps_per_domain=32,
    batch_size=32,
    max_episode_steps=20,
    n_epochs=2,
    wind=[-0.5, 0.5],
    checkpoint_every=1,
)


def test_epopt_keeps_only_the_worst_epsilon_fraction():
    scores = np.random.default_rng(0).normal(size=40)
    for eps in (0.05, 0.1, 0.5, 1.0):
        keep = mt.worst_fraction(scores, eps)
        k = int(np.ceil(eps * 40))
        assert keep.sum() == k
        assert scores[keep].max() <= scores[~keep].min() if k < 40 else keep.all()
    assert mt.worst_fraction(np.array([3.0]), 0.01).tolist() == [True]
    with pytest.raises(ValueError, match="epsilon"):
        mt.worst_fraction(scores, 0.0)
    assert mt.trajectory_segments(np.array([0, 0, 1, 0, 1])).tolist() == [0, 0, 1, 1, 2]


def test_reptile_meta_gradient_is_pi_minus_adapted():
    torch.manual_seed(0)
    m = torch.nn.Linear(3, 2)
    before = {k: v.clone() for k, v in m.state_dict().items()}
    adapted = {k: v + torch.randn_like(v) for k, v in before.items()}
    opt = torch.optim.SGD(m.parameters(), lr=0.25)
    mt.reptile_meta_step(m, adapted, opt)
    for name, p in m.named_parameters():
        assert torch.allclose(p.grad, before[name] - adapted[name])
        assert torch.allclose(p, before[name] + 0.25 * (adapted[name] - before[name]))
    # Adam's first step moves every coordinate by ~lr towards pi'
    m2 = torch.nn.Linear(3, 2)
    b2 = {k: v.clone() for k, v in m2.state_dict().items()}
    mt.reptile_meta_step(m2, {k: v + 1.0 for k, v in b2.items()}, torch.optim.Adam(m2.parameters(), lr=1e-3))
    for name, p in m2.named_parameters():
        assert torch.allclose(p - b2[name], torch.full_like(p, 1e-3), atol=1e-6)


def test_fomaml_meta_step_uses_mean_of_given_gradients():
    m = torch.nn.Linear(2, 1)
    before = {k: v.clone() for k, v in m.state_dict().items()}
    grads = [{k: torch.full_like(v, float(i)) for k, v in before.items()} for i in (1, 2, 3)]
    mt.fomaml_meta_step(m, grads, torch.optim.SGD(m.parameters(), lr=1.0))
    for name, p in m.named_parameters():
        assert torch.allclose(p, before[name] - 2.0)
    with pytest.raises(ValueError, match="at least one"):
        mt.fomaml_meta_step(m, [], torch.optim.SGD(m.parameters(), lr=1.0))


def test_maml_gradient_is_taken_at_adapted_parameters_on_fresh_data():
    cfg = mdl_config("ppo-maml-dg", "Hopper", 0, 10**6, **{**TINY, "max_grad_norm": 1e9})
    tr = mt.MultiDomainTrainer(cfg)
    try:
        start = {k: v.clone() for k, v in tr.main.policy.state_dict().items()}
        w = tr.workers[0]
        tr._collect(0, start)
        w.n_epochs = 1
        w.train()  # adapted pi_0
        adapted = {k: v.clone() for k, v in w.policy.state_dict().items()}
        assert any(not torch.equal(adapted[k], start[k]) for k in start)
        buf = tr._collect(0, None)  # D'_0 with pi_0
        g = mt.post_adaptation_gradient(w)
        assert all(torch.equal(v, adapted[k]) for k, v in w.policy.state_dict().items())  # unchanged
        # the PPO loss at pi_0 on D'_0, by hand (ratio = 1 on fresh data)
        data = next(buf.get(buf.buffer_size))
        w.policy.zero_grad()
        values, logp, ent = w.policy.evaluate_actions(data.observations, data.actions)
        assert torch.allclose(logp, data.old_log_prob, atol=1e-5)
        adv = (data.advantages - data.advantages.mean()) / (data.advantages.std() + 1e-8)
        loss = (
            -(adv * torch.exp(logp - data.old_log_prob)).mean()
            + cfg["vf_coef"] * torch.nn.functional.mse_loss(data.returns, values.flatten())
            - cfg["ent_coef"] * ent.mean()
        )
        loss.backward()
        for n, p in w.policy.named_parameters():
            assert torch.allclose(g[n], p.grad, atol=1e-5), n
    finally:
        tr.close()


def test_merge_buffers_with_masks():
    cfg = mdl_config("joint", "Hopper", 0, 10**6, **TINY)
    tr = mt.MultiDomainTrainer(cfg)
    try:
        bufs = [tr._collect(i, None) for i in range(2)]
        masks = [np.zeros((32, 1), bool), np.ones((32, 1), bool)]
        masks[0][:10] = True
        merged = mt.merge_buffers(bufs, masks)
        assert merged.buffer_size == 42 and merged.observations.shape == (42, 1, 11)
        assert np.allclose(merged.rewards[10:, 0], bufs[1].rewards[:, 0])
    finally:
        tr.close()


def test_aggregators_with_zero_learning_rate_keep_theta_old():
    for algo in ("params_avg", "kl_avg"):
        tr = mt.MultiDomainTrainer(mdl_config(algo, "Hopper", 0, 10**6, **{**TINY, "learning_rate": 0.0}))
        try:
            before = tr.view.get_flat()
            row = tr.iterate()
            assert torch.allclose(tr.view.get_flat(), before, atol=1e-6)
            assert np.allclose(row["kl"], 0.0, atol=1e-8)
        finally:
            tr.close()


@pytest.mark.parametrize("algo", ALGORITHMS)
def test_train_job_curves_artefacts_and_resume(algo, tmp_path):
    cfg = mdl_config(algo, "Hopper", 1, 128, **({**TINY, "epsilon": 0.3} if algo == "ppo-epopt" else TINY))
    (tmp_path / "out").mkdir()
    res = mt.train_job(cfg, tmp_path)
    per_iter = 2 * 64 if algo == "ppo-maml-dg" else 64
    n = int(np.ceil(128 / per_iter))
    assert res["timesteps"].tolist() == [per_iter * (i + 1) for i in range(n)]
    assert res["kl"].shape == (n, 2) and res["entropy"].shape == (n,)
    assert np.isfinite(res["kl"]).all() == (algo in ("params_avg", "kl_avg"))
    if algo == "ppo-epopt":
        assert (res["kept_fraction"] < 1.0).all()
    for name in ("model.zip", "vecnormalize.pkl", "policy.pth", "obs_norm.npz", "learner.json"):
        assert (tmp_path / "out" / name).exists(), name
    act = mt.load_policy(tmp_path / "out")(np.zeros((4, 11)))
    assert act.shape == (4, 3) and np.abs(act).max() <= 1.0
    # resume: a checkpoint at the last iteration means nothing is left to do
    res2 = mt.train_job(cfg, tmp_path)
    assert res2["timesteps"].tolist() == res["timesteps"].tolist()


def test_config_errors():
    with pytest.raises(ValueError, match="valid algorithms"):
        mdl_config("maml", "Hopper", 0, 100)
    with pytest.raises(ValueError, match="wind"):
        mdl_config("joint", "Hopper", 0, 100, wind=[1.0, -1.0])
    with pytest.raises(ValueError, match="epsilon"):
        mdl_config("ppo-epopt", "Hopper", 0, 100, epsilon=0.0)


def test_reward_eq_4_12_and_wind_per_episode():
    from thesis_repro.mdl.envs import make_mdl_env

    for c_a in (0.001, 0.1, 1.0):
        env = make_mdl_env("Walker2d", c_a=c_a, wind=(-2.5, 2.5), seed=0)
        winds = set()
        for ep in range(3):
            _, info = env.reset(seed=ep)
            winds.add(info["factors"]["wind"])
            a = np.full(6, 0.5)
            _, r, term, _, info = env.step(a)
            assert not term
            assert r == pytest.approx(info["x_velocity"] + 1.0 - c_a * float(a @ a))
            assert -2.5 <= info["factors"]["wind"] <= 2.5
        assert len(winds) == 3  # a new wind every episode
        env.close()
    with pytest.raises(ValueError, match="wind"):
        make_mdl_env("Hopper", "dom", 0.2, wind=(-0.5, 0.5))


def test_joint_trains_on_chapter3_domain_randomisation():
    cfg = mdl_config("joint", "Hopper", 0, 64, **{**TINY, "wind": None, "perturbation": "dom", "sigma": 0.2})
    tr = mt.MultiDomainTrainer(cfg)
    try:
        before = tr.view.get_flat()
        row = tr.iterate()
        assert row["timesteps"] == 64 and not torch.allclose(tr.view.get_flat(), before)
    finally:
        tr.close()


def test_line_search_never_worse_than_params_avg_on_true_kl():
    view, states, t0, thetas = _setup(n=4, scale=0.1)

    def total(t):
        return sum(float(agg.mean_kl(view, ti, t, states)) for ti in thetas)

    info: dict = {}
    out = agg.kl_avg(view, thetas, states, t0, cg_iters=20, damping=0.01, info=info, line_search=True)
    assert info["step_fraction"] in (1.0, 0.5, 0.25, 0.125, 0.0)
    assert total(out) <= total(agg.params_avg(thetas)) + 1e-9
