"""The fast training updates are SB3's updates: same data, same seed -> same parameters (to float tolerance).

Tolerance: every parameter within ATOL = 1e-5 (absolute) of SB3's after the whole ``train()`` call
(10 epochs x 4 minibatches here; the closed-form gradient differs from autograd only in float rounding,
measured ~1e-7). The twins are also checked to have moved far more than ATOL, so equality is not vacuous.
"""

from __future__ import annotations

import copy
import io

import numpy as np
import pytest
import torch as th
from stable_baselines3 import PPO
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from thesis_repro.envs import make_env
from thesis_repro.learners.fast import FastPPO, ppo_epochs, rollout_tensors
from thesis_repro.learners.kernels import _ManualActorCritic
from thesis_repro.learners.policies import SCNPolicy

ATOL = 1e-5
STATS = ("policy_gradient_loss", "value_loss", "approx_kl", "clip_fraction", "entropy_loss", "loss", "n_updates")


def _venv(n: int = 2) -> VecNormalize:
    return VecNormalize(DummyVecEnv([lambda i=i: make_env("Hopper", seed=i) for i in range(n)]), norm_reward=False)


def _twins(policy="MlpPolicy", activation=th.nn.Tanh, **kw) -> tuple[FastPPO, PPO]:
    """A FastPPO after two training iterations (non-trivial Adam state, stale rollout -> clipping active),
    and an SB3 PPO with identical parameters, optimiser state, buffer and progress."""
    args = dict(n_steps=128, batch_size=64, n_epochs=10, seed=0, device="cpu")
    args.update(kw)
    pk = dict(net_arch=dict(pi=[32, 32], vf=[32, 32]), activation_fn=activation, optimizer_kwargs={"fused": True})
    fast = FastPPO(policy, _venv(), policy_kwargs=pk, **args)
    fast.learn(512)
    sb3 = PPO(policy, _venv(), policy_kwargs=pk, **args)
    sb3.set_logger(Logger(None, []))
    sb3.policy.load_state_dict(fast.policy.state_dict())
    sb3.policy.optimizer.load_state_dict(copy.deepcopy(fast.policy.optimizer.state_dict()))
    sb3.rollout_buffer = copy.deepcopy(fast.rollout_buffer)
    sb3._current_progress_remaining = fast._current_progress_remaining
    sb3._n_updates = fast._n_updates
    return fast, sb3


def _max_diff(a: th.nn.Module, b: th.nn.Module) -> float:
    return max((p - q).abs().max().item() for p, q in zip(a.parameters(), b.parameters(), strict=True))


CASES = {
    "mlp": dict(),
    "scn": dict(policy=SCNPolicy),
    "scn+entropy": dict(policy=SCNPolicy, ent_coef=0.01),
    "relu+no-adv-norm+vf-clip": dict(activation=th.nn.ReLU, normalize_advantage=False, clip_range_vf=0.1),
    "target_kl": dict(target_kl=0.003),  # stops in epoch 9 of 10
    "odd-batch": dict(batch_size=48),  # last minibatch smaller (256 = 5 x 48 + 16)
}


@pytest.mark.filterwarnings("ignore:You have specified a mini-batch size")
@pytest.mark.parametrize("case", list(CASES))
def test_fast_train_equals_sb3_train(case):
    fast, sb3 = _twins(**CASES[case])
    before = copy.deepcopy(fast.policy)
    n_updates = fast._n_updates
    np.random.seed(123)
    sb3.train()
    np.random.seed(123)
    fast.train()
    assert fast.fast_path is True
    assert _max_diff(fast.policy, sb3.policy) < ATOL
    assert _max_diff(fast.policy, before) > 100 * ATOL  # the update did move the parameters
    for key in STATS:
        ref, got = sb3.logger.name_to_value[f"train/{key}"], fast.logger.name_to_value[f"train/{key}"]
        assert got == pytest.approx(ref, rel=1e-4, abs=1e-6), key
    epochs = fast._n_updates - n_updates
    assert (1 < epochs < fast.n_epochs) if case == "target_kl" else (epochs == fast.n_epochs)


def test_generic_path_equals_sb3_train():
    """``manual=False`` (autograd through ``evaluate_actions``, used for unusual policies) is SB3's update too."""
    fast, sb3 = _twins(policy=SCNPolicy)
    np.random.seed(7)
    sb3.train()
    np.random.seed(7)
    kw = dict(n_epochs=fast.n_epochs, batch_size=fast.batch_size, clip_range=0.2, max_grad_norm=fast.max_grad_norm)
    stats = ppo_epochs(fast.policy, fast.policy.optimizer, rollout_tensors(fast.rollout_buffer), manual=False, **kw)
    assert stats["fast_path"] is False and stats["epochs"] == fast.n_epochs
    assert _max_diff(fast.policy, sb3.policy) < ATOL


def test_unusual_policy_falls_back_and_manual_true_refuses():
    model = FastPPO("MlpPolicy", make_env("InvertedPendulum", seed=0), n_steps=64, batch_size=32, use_sde=True, seed=0)
    assert _ManualActorCritic.build(model.policy) is None
    model.learn(64)
    assert model.fast_path is False
    data = rollout_tensors(model.rollout_buffer)
    with pytest.raises(ValueError, match="no closed-form PPO path"):
        ppo_epochs(model.policy, model.policy.optimizer, data, n_epochs=1, batch_size=32, clip_range=0.2, manual=True)


@pytest.mark.parametrize("algo", ["ppo", "ppo-16", "ppo-scn", "ppo-scn-16", "ppo-ent", "ppo-arpl", "ppo-obsnoise"])
def test_kit_ppo_configs_train_with_the_closed_form_path(algo):
    from thesis_repro.learners.config import train_config
    from thesis_repro.learners.train import _wrap, build_model, make_train_venv

    cfg = train_config(algo, "Hopper", 0, 1000, n_envs=1)
    model = build_model(cfg, _wrap(cfg, make_train_venv(cfg), None))
    assert isinstance(model, FastPPO)
    assert _ManualActorCritic.build(model.policy) is not None


def test_rollout_tensors_matches_sb3_get_order_and_selects_columns():
    fast, _ = _twins(n_epochs=1)
    buf = copy.deepcopy(fast.rollout_buffer)  # FastPPO never flattens the buffer: layout (T, n_envs, ...)
    assert not buf.generator_ready
    data = rollout_tensors(buf)
    np.random.seed(0)
    (batch,) = buf.get(None)  # SB3's own flattening (now in place), one batch with permuted rows
    np.random.seed(0)
    perm = th.as_tensor(np.random.permutation(256))
    for name, ref in [("observations", batch.observations), ("advantages", batch.advantages)]:
        assert th.equal(getattr(data.index(perm), name), ref)
    flat = rollout_tensors(buf)  # after get(): same rows
    assert all(th.equal(getattr(flat, f), getattr(data, f)) for f in ("observations", "old_log_prob", "returns"))
    col = rollout_tensors(buf, env_index=1)
    assert th.equal(col.returns, data.returns[128:])
    mask = np.zeros((128, 2), dtype=bool)
    mask[::3, 0] = mask[5:9, 1] = True
    sub = rollout_tensors(buf, mask=mask)
    assert th.equal(sub.actions, th.cat([data.actions[:128][mask[:, 0]], data.actions[128:][mask[:, 1]]]))
    assert th.equal(rollout_tensors(buf, env_index=0, mask=mask[:, 0]).actions, data.actions[:128][mask[:, 0]])
    with pytest.raises(ValueError, match="env_index must be in"):
        rollout_tensors(buf, env_index=2)


def test_fastppo_zip_loads_as_sb3_ppo():
    model = FastPPO("MlpPolicy", make_env("InvertedPendulum", seed=0), n_steps=64, batch_size=32, seed=0)
    model.learn(64)
    blob = io.BytesIO()
    model.save(blob)
    blob.seek(0)
    loaded = PPO.load(blob, device="cpu")
    obs = np.random.default_rng(0).normal(size=(5, 4)).astype(np.float32)
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])


# ---- cheaper stepping, same transitions ------------------------------------------------------------------
def _same(a, b) -> bool:
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b)
    return type(a) is type(b) and a == b


@pytest.mark.parametrize("task", ["Hopper", "Walker2d", "HalfCheetah", "InvertedPendulum"])
@pytest.mark.parametrize("perturbation", ["none", "obs", "act", "env", "dom"])
def test_lean_env_steps_exactly_like_gymnasium(task, perturbation, monkeypatch):
    import thesis_repro.envs.make as make_module
    from thesis_repro.envs import make_env

    kw = dict(perturbation=perturbation, sigma=0.3, max_episode_steps=40, seed=3)
    lean = make_env(task, **kw)
    monkeypatch.setattr(make_module, "lean_spec", lambda env_id: env_id)  # Gymnasium's own registered env
    ref = make_env(task, **kw)
    assert type(lean.unwrapped) is not type(ref.unwrapped) or task not in ("Hopper", "Walker2d")
    rng = np.random.default_rng(0)
    n_done = 0
    for _ in range(300):
        a = rng.uniform(-1.5, 1.5, size=lean.action_space.shape)  # also outside the bounds
        out_lean, out_ref = lean.step(a.copy()), ref.step(a.copy())
        assert all(_same(x, y) for x, y in zip(out_lean, out_ref, strict=True))
        if out_ref[2] or out_ref[3]:
            n_done += 1
            assert all(_same(x, y) for x, y in zip(lean.reset(), ref.reset(), strict=True))
    assert n_done >= 5  # episode ends (terminations and time limits) were exercised


def test_lean_vec_env_matches_dummy_vec_env():
    from stable_baselines3.common.vec_env import VecMonitor

    from thesis_repro.envs import make_env
    from thesis_repro.envs.vec import LeanVecEnv

    def stack(cls):
        fns = [lambda i=i: make_env("Hopper", "dom", 0.2, max_episode_steps=30, seed=i) for i in range(3)]
        return VecNormalize(VecMonitor(cls(fns)), norm_reward=True)

    lean, ref = stack(LeanVecEnv), stack(DummyVecEnv)
    assert _same(lean.reset(), ref.reset())
    rng = np.random.default_rng(1)
    n_done = 0
    for _ in range(200):
        a = rng.uniform(-1, 1, size=(3, 3))
        (o1, r1, d1, i1), (o2, r2, d2, i2) = lean.step(a), ref.step(a)
        assert _same(o1, o2) and _same(r1, r2) and _same(d1, d2)
        for x, y in zip(i1, i2, strict=True):
            for info in (x, y):
                info.get("episode", {}).pop("t", None)  # wall-clock time of VecMonitor
            assert _same(x, y)
        n_done += int(d1.sum())
    assert n_done >= 10
    assert _same(lean.venv.venv.reset_infos, ref.venv.venv.reset_infos)


# ---- SAC / DDPG: same replay samples -> same parameters ---------------------------------------------------
def _off_policy_twin(model):
    """A deep copy of ``model`` (parameters, optimisers, replay buffer, counters) sharing its envs."""
    env, vn = model.env, model._vec_normalize_env
    model.env = model._vec_normalize_env = None
    try:
        twin = copy.deepcopy(model)
    finally:
        model.env, model._vec_normalize_env = env, vn
    twin.env, twin._vec_normalize_env = env, vn
    twin.set_logger(Logger(None, []))
    return twin


def _off_policy_model(kind: str):
    from thesis_repro.envs import make_env
    from thesis_repro.learners.algos import DDPGSplit
    from thesis_repro.learners.fast_offpolicy import FastDDPG, FastSAC

    pk = {"net_arch": [32, 32], "activation_fn": th.nn.ReLU, "optimizer_kwargs": {"fused": True}}
    common = dict(buffer_size=5000, learning_starts=200, train_freq=50, gradient_steps=50, seed=0, device="cpu")
    if kind.startswith("sac"):
        ent = "auto" if kind == "sac-auto" else 0.2
        return FastSAC(
            "MlpPolicy", make_env("Hopper", seed=0), batch_size=128, ent_coef=ent, policy_kwargs=pk, **common
        )
    venv = VecNormalize(DummyVecEnv([lambda: make_env("Hopper", seed=0)]), norm_reward=False)
    if kind == "ddpg":  # the kit's DDPG: split learning rates and critic L2 (Adam weight decay)
        return DDPGSplit("MlpPolicy", venv, actor_lr=1e-4, critic_lr=1e-3, critic_l2=0.01, policy_kwargs=pk, **common)
    model = FastDDPG("MlpPolicy", venv, policy_kwargs={**pk, "n_critics": 2}, **common)
    model.policy_delay, model.target_policy_noise, model.target_noise_clip = 2, 0.2, 0.5  # TD3 settings
    return model


@pytest.mark.parametrize("kind", ["sac", "sac-auto", "ddpg", "td3-settings"])
def test_fast_off_policy_train_equals_sb3_train(kind):
    from stable_baselines3 import SAC, TD3

    model = _off_policy_model(kind)
    model.learn(400)  # 200 random steps, then 4 x 50 fast gradient steps
    assert model.fast_path is True
    ref, before = _off_policy_twin(model), _off_policy_twin(model)
    sb3_train = SAC.train if kind.startswith("sac") else TD3.train
    np.random.seed(11)
    th.manual_seed(11)
    sb3_train(ref, 50, model.batch_size)
    np.random.seed(11)
    th.manual_seed(11)
    model.train(50, model.batch_size)
    assert _max_diff(model.policy, ref.policy) < ATOL  # actor, critic and target networks
    assert _max_diff(model.policy, before.policy) > 100 * ATOL
    if kind == "sac-auto":
        assert model.log_ent_coef.item() == pytest.approx(ref.log_ent_coef.item(), abs=ATOL)
        assert model.log_ent_coef.item() != before.log_ent_coef.item()
    for key, value in ref.logger.name_to_value.items():
        assert model.logger.name_to_value[key] == pytest.approx(value, rel=1e-4, abs=1e-6), key


@pytest.mark.parametrize("policy", ["MlpPolicy", SCNPolicy])
def test_fast_collect_rollouts_equals_sb3(policy):
    """The closed-form sampling forward draws the same noise and gives bit-identical rollouts."""
    import types

    args = dict(n_steps=64, batch_size=64, n_epochs=2, seed=0, device="cpu")
    ref = FastPPO(policy, _venv(), **args)  # construction seeds the global RNGs; learn right after it
    ref.collect_rollouts = types.MethodType(PPO.collect_rollouts, ref)
    ref.learn(256)
    fast = FastPPO(policy, _venv(), **args)
    fast.learn(256)
    for name in ("observations", "actions", "rewards", "values", "log_probs", "advantages", "episode_starts"):
        assert np.array_equal(getattr(ref.rollout_buffer, name), getattr(fast.rollout_buffer, name)), name
    assert _max_diff(ref.policy, fast.policy) == 0.0


def test_fused_adam_step_is_optimizer_step_bit_for_bit():
    from thesis_repro.learners.kernels import _FusedAdamStep

    def make(fused=True):
        th.manual_seed(0)
        net = th.nn.Sequential(th.nn.Linear(3, 4), th.nn.Tanh(), th.nn.Linear(4, 2))
        groups = [{"params": [net[0].weight], "weight_decay": 0.01}, {"params": [net[0].bias, *net[2].parameters()]}]
        return net, th.optim.Adam(groups, lr=1e-2, eps=1e-5, fused=fused)

    (a, opt_a), (b, opt_b) = make(), make()
    step = _FusedAdamStep(opt_b)
    assert step.ok and not _FusedAdamStep(make(fused=False)[1]).ok
    for i in range(4):
        x = th.randn(5, 3, generator=th.Generator().manual_seed(i))
        for net in (a, b):
            net.zero_grad()
            net(x).pow(2).sum().backward()
        opt_a.step()
        step()
        for g in opt_b.param_groups:  # the learning rate is read at every step
            g["lr"] *= 0.5
        for g in opt_a.param_groups:
            g["lr"] *= 0.5
    for p, q in zip(a.parameters(), b.parameters(), strict=True):
        assert th.equal(p, q) and th.equal(opt_a.state[p]["step"], opt_b.state[q]["step"])


@pytest.mark.parametrize("kind", ["sac", "ddpg"])
def test_fast_exploration_equals_sb3_sample_action(kind):
    """Closed-form exploration actions are SB3's, bit for bit: identical replay buffers and parameters."""
    import types

    from stable_baselines3.common.noise import OrnsteinUhlenbeckActionNoise
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

    def run(stock: bool):
        model = _off_policy_model(kind)  # construction seeds the global RNGs
        if kind == "ddpg":
            model.action_noise = OrnsteinUhlenbeckActionNoise(np.zeros(3), 0.2 * np.ones(3))
        if stock:
            model._sample_action = types.MethodType(OffPolicyAlgorithm._sample_action, model)
        model.learn(400)
        return model

    ref, fast = run(True), run(False)
    buf_ref, buf = ref.replay_buffer, fast.replay_buffer
    for name in ("observations", "actions", "rewards", "next_observations", "dones"):
        assert np.array_equal(getattr(buf_ref, name), getattr(buf, name)), name
    assert _max_diff(ref.policy, fast.policy) == 0.0


@pytest.mark.parametrize("n_envs", [1, 3])
def test_lean_vec_normalize_matches_vec_normalize(n_envs, tmp_path):
    from thesis_repro.envs import make_env
    from thesis_repro.envs.vec import LeanVecEnv, LeanVecNormalize

    def stack(cls):
        fns = [lambda i=i: make_env("Hopper", "obs", 0.1, max_episode_steps=30, seed=i) for i in range(n_envs)]
        return cls(LeanVecEnv(fns), norm_reward=True, clip_obs=5.0)

    lean, ref = stack(LeanVecNormalize), stack(VecNormalize)
    assert _same(lean.reset(), ref.reset())
    rng = np.random.default_rng(2)
    for _ in range(120):
        a = rng.uniform(-1, 1, size=(n_envs, 3))
        (o1, r1, d1, i1), (o2, r2, d2, i2) = lean.step(a), ref.step(a)
        assert _same(o1, o2) and _same(r1, r2) and _same(d1, d2)
        assert all(_same(x, y) for x, y in zip(i1, i2, strict=True))
        assert _same(lean.get_original_obs(), ref.get_original_obs())
        assert _same(lean.get_original_reward(), ref.get_original_reward())
    for name in ("obs_rms", "ret_rms"):
        x, y = getattr(lean, name), getattr(ref, name)
        assert np.array_equal(x.mean, y.mean) and np.array_equal(x.var, y.var) and x.count == y.count
    lean.save(str(tmp_path / "vn.pkl"))
    loaded = LeanVecNormalize.load(str(tmp_path / "vn.pkl"), stack(VecNormalize).venv)
    assert np.array_equal(loaded.obs_rms.var, lean.obs_rms.var)
