"""The thesis protocol's learners: EPOpt ranks complete episodes by their full return,
MAML-DG / Reptile-DG hold one domain Θ_i per meta-batch, ARPL's δ is §3.2.1's ε ∇_s‖π_θ(s)‖. Each setting has
a named other option (fragments, a new domain every episode, the rescaled δ); each test below fails on it."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from tests.interrupt import Interrupt
from thesis_repro.learners import meta, train_config, train_job
from thesis_repro.learners import multidomain as md
from thesis_repro.learners import train as lt
from thesis_repro.learners.arpl import ARPLVecEnv, arpl_perturbation
from thesis_repro.learners.policy_file import read_state_dict

th.set_num_threads(1)

TINY = dict(n_envs=2, n_steps=64, batch_size=32, max_episode_steps=20, n_epochs=2)
DOM = dict(perturbation="dom", sigma=0.2)


def tiny(algo: str, timesteps: int = 10**6, seed: int = 0, **kw) -> dict:
    return train_config(algo, "Hopper", seed, timesteps, **{**TINY, **kw})


def model_for(cfg: dict):
    return lt.build_model(cfg, lt._wrap(cfg, lt.make_train_venv(cfg), None))


# ------------------------------------------------------------------------------------ EPOpt (item 2)
def only_complete_episodes(starts: np.ndarray, ends: np.ndarray, mask: np.ndarray) -> bool:
    """True iff every kept step belongs to an episode that ends in the buffer (finite ``ends`` at its last
    step), and every such episode is kept or dropped whole."""
    for e in range(starts.shape[1]):
        seg = md.trajectory_segments(starts[:, e])
        for s in np.unique(seg):
            steps = np.flatnonzero(seg == s)
            kept = mask[steps, e]
            if kept.any() and not (kept.all() and np.isfinite(ends[steps[-1], e])):
                return False
    return True


def test_complete_episode_mask_keeps_whole_episodes_ranked_by_full_return():
    # env 0: an episode from the previous batch ends at t=1 (full return 50, only 2 steps here), then one of
    # steps 2-5 (return 4), then a fragment still running (partial return 0.1: the worst partial return).
    # env 1: episodes 0-2 (return 3) and 3-7 (return 6).
    starts = np.zeros((8, 2))
    starts[[2, 6], 0] = 1
    starts[[0, 3], 1] = 1
    rewards = np.ones((8, 2))
    rewards[6:, 0] = 0.05
    ends = np.full((8, 2), np.nan)
    ends[1, 0], ends[5, 0], ends[2, 1], ends[7, 1] = 50.0, 4.0, 3.0, 6.0
    mask = md.complete_episode_mask(starts, ends, 0.5)  # 4 ranked: keep the 2 worst full returns (3 and 4)
    assert mask[:, 0].tolist() == [False, False, True, True, True, True, False, False]
    assert mask[:, 1].tolist() == [True, True, True, False, False, False, False, False]
    assert only_complete_episodes(starts, ends, mask)
    # the old ranking (fragments by partial return) keeps the running fragment and the 2-step tail: it fails
    old = md.epopt_mask(starts, rewards, 0.5)
    assert old[6:, 0].all() and old[:2, 0].all() and not only_complete_episodes(starts, ends, old)
    # no episode ended: nothing kept; an end not followed by a start is an error
    assert not md.complete_episode_mask(np.zeros((4, 1)), np.full((4, 1), np.nan), 0.1).any()
    bad = np.full((4, 1), np.nan)
    bad[1, 0] = 1.0
    with pytest.raises(ValueError, match="episode start must follow"):
        md.complete_episode_mask(np.zeros((4, 1)), bad, 0.1)


class _Episodes(BaseCallback):
    """Every finished training episode (VecMonitor's full return and length), per iteration."""

    def __init__(self) -> None:
        super().__init__()
        self.per_iteration: list[list[tuple[int, float, int]]] = []

    def _on_rollout_start(self) -> None:
        self.per_iteration.append([])

    def _on_step(self) -> bool:
        for e, info in enumerate(self.locals["infos"]):
            if "episode" in info:
                self.per_iteration[-1].append((e, float(info["episode"]["r"]), int(info["episode"]["l"])))
        return True


def test_epopt_trains_only_on_complete_episodes_with_their_full_returns(monkeypatch):
    cfg = tiny("ppo-epopt", epopt_warm_start=1, epsilon=0.3, max_episode_steps=40)
    assert cfg["sb3"]["epopt_rank"] == "episodes"
    seen: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    real = md.complete_episode_mask

    def spy(starts, ends, eps):
        out = real(starts, ends, eps)
        seen.append((np.array(starts), np.array(ends), out))
        return out

    monkeypatch.setattr(md, "complete_episode_mask", spy)
    model, episodes = model_for(cfg), _Episodes()
    model.learn(4 * 128, callback=episodes)
    assert len(seen) == 3  # iteration 1 is the warm start (all steps, eps = 1)
    assert model.last_train_stats["ranked_episodes"] > 0
    crossed = 0
    for (starts, ends, mask), finished in zip(seen, episodes.per_iteration[1:], strict=True):
        assert only_complete_episodes(starts, ends, mask) and mask.any()
        # the ranked returns are exactly the episodes VecMonitor finished in this batch (full returns)
        assert sorted(ends[np.isfinite(ends)].tolist()) == sorted(r for _, r, _ in finished)
        seg = [md.trajectory_segments(starts[:, e]) for e in range(starts.shape[1])]
        for e, r, length in finished:  # an episode that began in an earlier batch: longer than its part here
            (t,) = np.flatnonzero(ends[:, e] == r)
            in_batch = int((seg[e] == seg[e][t]).sum())
            assert in_batch <= length
            crossed += in_batch < length
    assert crossed > 0  # some ranked episodes started before the batch: ranked by their FULL return


def test_epopt_fragment_ranking_is_a_named_option():
    model = model_for(tiny("ppo-epopt", epopt_rank="fragments"))
    assert model.epopt_rank == "fragments" and model.epopt_warm_start == 100 and model.epopt_warmup == 0
    with pytest.raises(ValueError, match="valid epopt_ranks are: 'episodes', 'fragments'"):
        tiny("ppo-epopt", epopt_rank="trajectories")
    with pytest.raises(ValueError, match=r"set epopt_warm_start .*, not epopt_warmup"):
        tiny("ppo-epopt", epopt_warmup=3)


# -------------------------------------------------------------------- one domain per meta-batch (item 3)
class _Domains(BaseCallback):
    """The factor values of every step, keyed by (iteration, domain): the steps of D_i (and D'_i)."""

    def __init__(self) -> None:
        super().__init__()
        self.iteration = -1
        self.thetas: dict[tuple[int, int], set[tuple[float, ...]]] = {}
        self.steps: dict[tuple[int, int], int] = {}

    def _on_rollout_start(self) -> None:
        self.iteration += 1

    def _on_step(self) -> bool:
        key = (self.iteration, self.model._domain_envs.index(self.locals["env"]))
        self.thetas.setdefault(key, set()).add(tuple(sorted(self.locals["infos"][0]["factors"].items())))
        self.steps[key] = self.steps.get(key, 0) + 1
        return True


@pytest.mark.parametrize("algo", ["ppo-maml-dg", "ppo-reptile-dg"])
def test_one_domain_per_meta_batch(algo):
    batches = 2 if algo == "ppo-maml-dg" else 1  # D_i and D'_i, or D_i
    runs = {}
    for per_batch in (True, False):
        model, cb = model_for(tiny(algo, domain_per_batch=per_batch, **DOM)), _Domains()
        assert model.domain_per_batch is per_batch
        model.learn(3 * 2 * 64 * batches, callback=cb)
        runs[per_batch] = cb
    thesis = runs[True]
    assert sorted(thesis.steps) == [(i, d) for i in range(3) for d in range(2)]
    assert set(thesis.steps.values()) == {64 * batches}
    # every step of D_i (and D'_i) of domain i in an iteration ran in ONE domain Θ_i (20-step episodes: several
    # episodes per batch, so several resets kept it) ...
    assert all(len(thetas) == 1 for thetas in thesis.thetas.values())
    # ... and Θ_i is drawn anew per domain and iteration
    assert len({next(iter(t)) for t in thesis.thetas.values()}) == len(thesis.thetas)
    # false (a new domain every episode, 20-step episodes): batches span several domains
    assert any(len(thetas) > 1 for thetas in runs[False].thetas.values())


def test_a_held_domain_survives_resets_and_the_setting_is_validated():
    from thesis_repro.envs import make_env
    from thesis_repro.envs.wrappers import DomainShift

    env = make_env("Hopper", "dom", 0.2, seed=0, max_episode_steps=5)
    assert isinstance(env, DomainShift)
    held = env.hold_domain()
    for _ in range(3):
        assert env.reset()[1]["factors"] == held
    env.release_domain()
    assert env.reset()[1]["factors"] != held
    with pytest.raises(ValueError, match="unknown hyperparameter of 'ppo-epopt' 'domain_per_batch'"):
        train_config("ppo-epopt", "Hopper", 0, 100, protocol="thesis", domain_per_batch=True)
    with pytest.raises(ValueError, match="domain_per_batch must be true or false"):
        train_config("ppo-maml-dg", "Hopper", 0, 100, protocol="thesis", domain_per_batch="yes")


# --------------------------------------------------------------------------------------- ARPL (item 4)
def _tiny_policy(seed: int = 0):
    from gymnasium import spaces
    from stable_baselines3.common.policies import ActorCriticPolicy

    th.manual_seed(seed)
    obs, act = spaces.Box(-10, 10, (3,)), spaces.Box(-1, 1, (2,))
    return ActorCriticPolicy(obs, act, lambda _: 3e-4, net_arch=dict(pi=[4], vf=[4]), activation_fn=th.nn.Tanh)


def test_arpl_delta_is_epsilon_times_the_gradient_of_the_action_norm():
    pol = _tiny_policy()
    w1, b1 = (p.detach().double().numpy() for p in pol.mlp_extractor.policy_net[0].parameters())
    w2, b2 = (p.detach().double().numpy() for p in pol.action_net.parameters())
    s = np.random.default_rng(1).normal(size=(5, 3))
    eps = 0.3
    # by hand: m = W2 tanh(W1 s + b1) + b2; grad_s ||m|| = W1^T (1 - h^2) * (W2^T m/||m||)
    h = np.tanh(s @ w1.T + b1)
    m = h @ w2.T + b2
    grad = (((m / np.linalg.norm(m, axis=1, keepdims=True)) @ w2) * (1 - h**2)) @ w1
    delta = arpl_perturbation(pol, s, eps, delta="gradient")
    np.testing.assert_allclose(delta, eps * grad, rtol=1e-4, atol=1e-7)
    # the rescaled form rescales it to length eps: another vector (|grad| != 1 here)
    rescaled = arpl_perturbation(pol, s, eps, delta="rescaled")
    np.testing.assert_allclose(rescaled, eps * grad / np.linalg.norm(grad, axis=1, keepdims=True), rtol=1e-4)
    assert not np.allclose(rescaled, eps * grad, rtol=1e-2)


def test_arpl_form_follows_the_setting():
    for delta, form in ((None, "gradient"), ("rescaled", "rescaled")):
        over = {} if delta is None else {"arpl": {"epsilon": 0.2, "prob": 0.5, "delta": delta}}
        cfg = train_config("ppo-arpl", "Hopper", 0, 1000, **over)
        venv = lt._wrap(cfg, lt.make_train_venv(cfg), None)
        assert isinstance(venv, ARPLVecEnv) and venv.delta == form
        venv.close()
    with pytest.raises(ValueError, match="valid arpl.deltas are: 'gradient', 'rescaled'"):
        train_config("ppo-arpl", "Hopper", 0, 1000, protocol="thesis", arpl={"epsilon": 0.2, "prob": 0.5, "delta": "x"})


# ------------------------------------------------------------------------- exact resume of the new state
@pytest.mark.parametrize(
    ("algo", "over"),
    [
        ("ppo-epopt", {**DOM, "epopt_warm_start": 1}),
        ("ppo-maml-dg", DOM),
        ("ppo-reptile-dg", DOM),
        ("ppo-arpl", {"n_envs": 2, "n_steps": 64}),
    ],
)
def test_thesis_protocol_runs_resume_exactly(tmp_path, algo, over):
    timesteps = 1024 if algo == "ppo-maml-dg" else 512
    kw = {k: v for k, v in TINY.items() if k not in ("max_episode_steps",)}
    cfg = train_config(algo, "Hopper", 3, timesteps, protocol="thesis", max_episode_steps=30, checkpoint_every=1,
                       **{**kw, **over})  # fmt: skip
    straight = train_job(cfg, tmp_path / "straight")
    with pytest.raises(KeyboardInterrupt):
        train_job(cfg, tmp_path / "resumed", callback=Interrupt(at=timesteps // 2 + 37))
    resumed = train_job(cfg, tmp_path / "resumed")
    assert resumed["resumed_from"] > 0
    for key in ("episode_returns", "episode_lengths", "curve_return"):
        assert np.array_equal(straight[key], resumed[key], equal_nan=True), key
    a, b = (read_state_dict(tmp_path / r / "out" / "policy.pth") for r in ("straight", "resumed"))
    assert all(th.equal(a[k], b[k]) for k in a)


# ------------------------------------------------------------- MAML-DG's outer update: cached gradient objects
def _two_outer_updates(per_batch: bool) -> tuple[th.Tensor, float]:
    model = model_for(tiny("ppo-maml-dg", seed=2, domain_per_batch=per_batch, **DOM))
    np.random.seed(7)
    model.learn(2 * 2 * 2 * 64)  # two iterations: two outer updates
    return th.cat([p.detach().reshape(-1) for p in model.policy.parameters()]), float(np.random.rand())


@pytest.mark.parametrize("per_batch", [True, False])
def test_maml_outer_update_with_cached_gradient_objects_is_bit_identical(monkeypatch, per_batch):
    """The PPO outer update builds each sub-policy's gradient recorder and closed-form path once per update;
    rebuilding them for every gradient (the earlier code) gives the same parameters, bit for bit."""
    cached, draw = _two_outer_updates(per_batch)
    real, calls = meta.post_adaptation_gradient, []

    def fresh(policy, data, recorder=None, manual=None, **kw):
        calls.append(recorder is not None and manual is not None)  # the update passed its caches ...
        return real(policy, data, **kw)  # ... which are dropped: fresh objects for every gradient

    monkeypatch.setattr(meta, "post_adaptation_gradient", fresh)
    rebuilt, draw_rebuilt = _two_outer_updates(per_batch)
    assert calls and all(calls)
    assert th.equal(cached, rebuilt) and draw == draw_rebuilt
