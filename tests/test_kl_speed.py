"""The shortcuts of the kl-avg / kl-exact / multi-domain speed-ups compute the same bits as the code they replace.

Whole tiny runs are checked against recorded digests by ``tests/test_speed_identity.py``; these tests pin the
pieces: the graph-free Eq 4.7 value of :func:`~thesis_repro.mdl.exact.kl_exact`'s line search, the
per-target KLs of :func:`~thesis_repro.mdl.aggregate.eq47_kls` (π_θ's forward pass once), and the sequential
learners' one-env domain views (``LeanVecNormalize``, as the training env).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

from thesis_repro.envs import make_env
from thesis_repro.envs.vec import LeanVecEnv, LeanVecNormalize
from thesis_repro.mdl import aggregate as agg


def _problem(n: int = 3, seed: int = 0):
    pol = agg.GaussianPolicy(5, 3, hidden=(16, 16), seed=seed, log_std_init=-0.3)
    view = agg.PolicyView(pol)
    gen = th.Generator().manual_seed(seed)
    states = th.randn(200, 5, generator=gen)
    t0 = view.get_flat()
    thetas = [t0 + 0.2 * th.randn(t0.shape, generator=gen) for _ in range(n)]
    return view, thetas, states


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kl_to_targets_is_gaussian_kl_per_target_bit_for_bit(seed):
    view, thetas, states = _problem(seed=seed)
    kl_to = agg._KLToTargets(view, thetas, states)
    gen = th.Generator().manual_seed(100 + seed)
    for theta in [th.stack(thetas).mean(0), thetas[0] + 0.05 * th.randn(thetas[0].shape, generator=gen)]:
        got = kl_to.kls(theta)
        with th.no_grad():
            want = [agg.mean_kl(view, t, theta, states) for t in thetas]
        assert all(th.equal(g, w) for g, w in zip(got, want, strict=True))
        # kl_exact's line-search value = its differentiable objective's value (the original mean_obj)
        n = len(thetas)
        with th.no_grad():
            mean, log_std = view.dist(theta, states)
            ref = sum(agg.gaussian_kl(*view.dist(t, states), mean, log_std).mean() for t in thetas) / n
        assert float(sum(got) / n) == float(ref)


def test_eq47_kls_is_the_stack_of_mean_kls_bit_for_bit():
    view, thetas, states = _problem(n=4)
    theta = agg.params_avg(thetas)
    with th.no_grad():
        want = th.stack([agg.mean_kl(view, t, theta, states) for t in thetas])
    assert th.equal(agg.eq47_kls(view, theta, thetas, states), want)


def test_sb3_view_kl_to_targets_bit_for_bit():
    import gymnasium as gym
    from stable_baselines3 import PPO

    model = PPO("MlpPolicy", gym.make("InvertedPendulum-v5"), seed=0, device="cpu")
    view = agg.PolicyView.from_sb3(model.policy)
    assert view.mlp is not None
    gen = th.Generator().manual_seed(0)
    t0 = view.get_flat()
    thetas = [t0 + 0.1 * th.randn(t0.shape, generator=gen) for _ in range(4)]
    states = th.randn(300, 4, generator=gen)
    theta = agg.params_avg(thetas)
    with th.no_grad():
        want = [agg.mean_kl(view, t, theta, states) for t in thetas]
    assert all(th.equal(g, w) for g, w in zip(agg._KLToTargets(view, thetas, states).kls(theta), want, strict=True))


def test_one_env_lean_vecnormalize_view_equals_sb3_vecnormalize():
    """The sequential learners' domain views: LeanVecNormalize over one env gives VecNormalize's observations,
    rewards and running statistics (its one-row moment update is exact)."""
    views = []
    for cls in (VecNormalize, LeanVecNormalize):
        venv = VecMonitor(LeanVecEnv([lambda: make_env("Hopper", seed=3)]))
        views.append(cls(venv, norm_obs=True, norm_reward=True, clip_obs=5.0, gamma=0.99))
    obs = [v.reset() for v in views]
    assert np.array_equal(obs[0], obs[1])
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(150):
        action = rng.uniform(-1, 1, size=(1, 3)).astype(np.float32)
        (o0, r0, d0, i0), (o1, r1, d1, i1) = (v.step(action) for v in views)
        assert np.array_equal(o0, o1) and np.array_equal(r0, r1) and np.array_equal(d0, d1)
        if d0[0]:
            ends += 1
            assert np.array_equal(i0[0]["terminal_observation"], i1[0]["terminal_observation"])
    assert ends > 0  # the episode-end path (terminal observation, reset) was taken
    for name in ("obs_rms", "ret_rms"):
        a, b = getattr(views[0], name), getattr(views[1], name)
        assert np.array_equal(a.mean, b.mean) and np.array_equal(a.var, b.var) and a.count == b.count
