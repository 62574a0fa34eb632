"""Chapter-3 learners: config resolution, SCN, PPO-16, ARPL, entropy, resume, load_policy, determinism."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch as th

from tests.interrupt import Interrupt
from thesis_repro.core.cache import Job, RunCache, canonical_json
from thesis_repro.learners import ALGORITHMS, load_policy, snapshots, train_config, train_job
from thesis_repro.learners import train as lt
from thesis_repro.learners.arpl import ARPLVecEnv, arpl_perturbation, mean_action
from thesis_repro.learners.train import _wrap, build_model, make_train_venv

ENV = "InvertedPendulum"
TINY = {"n_steps": 64, "n_envs": 2, "batch_size": 32, "n_epochs": 2}


def tiny(algo: str = "ppo", timesteps: int = 512, seed: int = 0, **kw) -> dict:
    over = dict(TINY) if algo.startswith(("ppo", "trpo")) else {}
    if algo == "trpo":
        over.pop("n_epochs")
    over.update(kw)
    return train_config(algo, ENV, seed, timesteps, max_episode_steps=100, **over)


def model_for(cfg: dict):
    return build_model(cfg, _wrap(cfg, make_train_venv(cfg), None))


# ---- configuration -------------------------------------------------------------------------------


def test_algorithms_and_appendix_values():
    for name in (
        "ppo",
        "trpo",
        "ddpg",
        "sac",
        "ppo-16",
        "ppo-scn",
        "ppo-scn-16",
        "ppo-ent",
        "ppo-arpl",
        "ppo-obsnoise",
        "ppo-actnoise",
        "ppo-envnoise",
        "ppo-mdl",
    ):
        assert name in ALGORITHMS
    ppo = train_config("ppo", "Hopper", 0, 4_000_000)
    assert ppo["n_envs"] * ppo["sb3"]["n_steps"] == 2048
    assert (ppo["sb3"]["n_epochs"], ppo["sb3"]["batch_size"], ppo["sb3"]["learning_rate"]) == (10, 64, 3e-4)
    assert (ppo["sb3"]["gae_lambda"], ppo["sb3"]["gamma"], ppo["sb3"]["clip_range"]) == (0.98, 0.99, 0.2)
    assert ppo["normalize_obs"] and ppo["net_arch"] == {"pi": [64, 64], "vf": [64, 64]}
    assert ppo["activation"] == "tanh"
    trpo = train_config("trpo", "Hopper", 0, 1000)
    assert trpo["n_envs"] * trpo["sb3"]["n_steps"] == 1024
    assert (trpo["sb3"]["target_kl"], trpo["sb3"]["cg_max_steps"], trpo["sb3"]["cg_damping"]) == (0.01, 10, 0.1)
    assert (trpo["sb3"]["n_critic_updates"], trpo["sb3"]["learning_rate"]) == (5, 1e-3)
    ddpg = train_config("ddpg", "Hopper", 0, 1000)
    assert (ddpg["actor_lr"], ddpg["critic_lr"], ddpg["critic_l2"]) == (1e-4, 1e-3, 0.01)
    assert ddpg["action_noise"] == {"type": "ou", "sigma": 0.2} and ddpg["sb3"]["tau"] == 0.01
    sac = train_config("sac", "Hopper", 0, 1000)
    assert sac["sb3"]["ent_coef"] == 0.2 and sac["sb3"]["learning_rate"] == 1e-3
    for algo, pert in (("ppo-obsnoise", "obs"), ("ppo-actnoise", "act"), ("ppo-envnoise", "env"), ("ppo-mdl", "dom")):
        cfg = train_config(algo, "Hopper", 0, 1000)
        assert (cfg["perturbation"], cfg["sigma"], cfg["class"]) == (pert, 0.2, "PPO")
    assert train_config("ppo-scn-16", "Hopper", 0, 1)["policy"] == "scn"
    assert train_config("ppo-ent", "Hopper", 0, 1)["sb3"]["ent_coef"] > 0


def test_config_is_plain_json_and_overrides_apply():
    cfg = train_config("ppo", "Hopper", 3, 5000, n_steps=32, snapshot_every=2048, sigma=0.1, perturbation="obs")
    assert json.loads(canonical_json(cfg)) == cfg
    assert (cfg["seed"], cfg["timesteps"], cfg["sb3"]["n_steps"], cfg["snapshot_every"]) == (3, 5000, 32, 2048)
    assert (cfg["perturbation"], cfg["sigma"]) == ("obs", 0.1)
    # overriding one variant does not leak into the base entry (deep copies)
    assert train_config("ppo", "Hopper", 0, 1)["sb3"]["n_steps"] == 256


@pytest.mark.parametrize(
    ("args", "kwargs", "match"),
    [
        (("ppo-typo", ENV, 0, 10), {}, "valid algorithms are: 'ppo'"),
        (("ppo", "Hoppr", 0, 10), {}, "unknown env 'Hoppr'; valid envs are: 'InvertedPendulum'"),
        (("ppo", ENV, 0, 10), {"n_step": 64}, "n_steps"),
        (("ppo", ENV, 0, 10), {"perturbation": "wind"}, "valid perturbations are"),
        (("ppo", ENV, 0, 10), {"sigma": -1}, "sigma"),
        (("ppo", ENV, -1, 10), {}, "seed"),
        (("ppo", ENV, 0, 0), {}, "timesteps"),
        (("ppo", ENV, 0, 10), {"n_envs": 0}, "n_envs"),
        (("ppo-arpl", ENV, 0, 10), {"arpl": {"epsilon": 0.1}}, "keys"),
        (("sac", ENV, 0, 10), {"policy": "scn"}, "on-policy"),
    ],
)
def test_config_errors(args, kwargs, match):
    with pytest.raises(ValueError, match=match):
        train_config(*args, **kwargs)


CH3 = ("ppo", "trpo", "ddpg", "sac", "ppo-16", "ppo-scn", "ppo-scn-16", "ppo-ent", "ppo-arpl",
       "ppo-obsnoise", "ppo-actnoise", "ppo-envnoise", "ppo-mdl")  # fmt: skip
WRAPPER = {"obs": "ObservationNoise", "act": "ActionNoise", "env": "EnvironmentNoise", "dom": "DomainShift"}


@pytest.mark.parametrize("algo", CH3)
def test_every_learner_builds_with_its_training_perturbation(algo):
    kw = {"buffer_size": 1000} if algo in ("ddpg", "sac") else {}
    cfg = tiny(algo, **kw)
    venv = make_train_venv(cfg)
    env, chain = venv.venv.envs[0], []
    while env is not None:
        chain.append(type(env).__name__)
        env = getattr(env, "env", None)
    if cfg["perturbation"] != "none":
        assert WRAPPER[cfg["perturbation"]] in chain
    else:
        assert not set(WRAPPER.values()) & set(chain)
    model = build_model(cfg, _wrap(cfg, venv, None))
    assert any(c.__name__.startswith(cfg["class"]) for c in type(model).__mro__)  # FastPPO is a PPO
    assert model.seed == 0


# ---- architectures ----------------------------------------------------------------------------


def _linears(seq):
    return [(m.in_features, m.out_features) for m in seq if isinstance(m, th.nn.Linear)]


def test_ppo16_and_ppo_network_shapes():
    small = model_for(tiny("ppo-16")).policy
    assert _linears(small.mlp_extractor.policy_net) == [(4, 16), (16, 16)]
    assert _linears(small.mlp_extractor.value_net) == [(4, 16), (16, 16)]
    assert (small.action_net.in_features, small.action_net.out_features) == (16, 1)
    big = model_for(tiny("ppo")).policy
    assert _linears(big.mlp_extractor.policy_net) == [(4, 64), (64, 64)]
    assert isinstance(big.mlp_extractor.policy_net[1], th.nn.Tanh)


def test_scn_mean_is_linear_plus_nonlinear_stream():
    pol = model_for(tiny("ppo-scn-16")).policy
    assert _linears(pol.mlp_extractor.value_net) == [(4, 16), (16, 16)]
    assert pol.action_net.in_features == 4 + 16
    with th.no_grad():
        pol.action_net.weight.normal_()
        pol.action_net.bias.normal_()
        x = th.as_tensor(np.random.default_rng(0).normal(size=(6, 4)), dtype=th.float32)
        mu = mean_action(pol, x)
        th.testing.assert_close(mu, pol.linear_stream(x) + pol.nonlinear_stream(x))
        d = 4
        w, b = pol.action_net.weight.clone(), pol.action_net.bias.clone()
        pol.action_net.weight[:, d:] = 0  # nonlinear stream off: the controller is affine K s + b
        th.testing.assert_close(mean_action(pol, x), x @ w[:, :d].T + b)
        y = x.flip(0)
        mix = 0.3 * mean_action(pol, x) + 0.7 * mean_action(pol, y)
        th.testing.assert_close(mean_action(pol, 0.3 * x + 0.7 * y), mix)
        pol.action_net.weight.copy_(w)
        pol.action_net.weight[:, :d] = 0  # linear stream off: only the MLP remains
        pol.action_net.bias.zero_()
        th.testing.assert_close(mean_action(pol, x), pol.mlp_extractor.policy_net(x) @ w[:, d:].T)
        assert th.linalg.norm(pol.nonlinear_stream(x)) > 0


def test_ppo_ent_coefficient_reaches_sb3():
    assert model_for(tiny("ppo-ent")).ent_coef == pytest.approx(0.01)
    assert model_for(tiny("ppo")).ent_coef == 0.0
    assert model_for(tiny("ppo-ent", ent_coef=0.05)).ent_coef == pytest.approx(0.05)


def test_ddpg_split_learning_rates_and_critic_l2():
    model = model_for(tiny("ddpg", buffer_size=1000))
    groups = model.critic.optimizer.param_groups
    assert [g["weight_decay"] for g in groups] == [0.01, 0.0]
    assert [tuple(p.shape) for p in groups[0]["params"]] == [(64, 5), (64, 64)]  # hidden weights only
    model._update_learning_rate([model.actor.optimizer, model.critic.optimizer])
    assert model.actor.optimizer.param_groups[0]["lr"] == 1e-4
    assert all(g["lr"] == 1e-3 for g in groups)


# ---- ARPL --------------------------------------------------------------------------------------


def test_arpl_direction_increases_action_norm_and_has_norm_epsilon():
    pol = model_for(tiny("ppo-arpl")).policy
    with th.no_grad():
        for p in pol.parameters():
            p.normal_(0, 0.5)
    rng = np.random.default_rng(1)
    s = rng.normal(size=(32, 4)).astype(np.float32)
    eps = 1e-3
    delta = arpl_perturbation(pol, s, eps)
    assert np.all(np.linalg.norm(delta, axis=1) <= eps * (1 + 1e-5))

    def norm(x):
        with th.no_grad():
            return th.linalg.vector_norm(mean_action(pol, th.as_tensor(x)), dim=-1).numpy()

    gain = norm(s + delta) - norm(s)
    assert np.all(gain > 0)
    rand = rng.normal(size=s.shape).astype(np.float32)
    rand *= eps / np.linalg.norm(rand, axis=1, keepdims=True)
    assert np.all(gain >= norm(s + rand) - norm(s) - 1e-6)  # steepest ascent beats a random direction


def test_arpl_wrapper_attacks_the_configured_fraction():
    cfg = tiny("ppo-arpl", arpl={"epsilon": 0.5, "prob": 1.0, "delta": "rescaled"})  # length epsilon exactly
    venv = _wrap(cfg, make_train_venv(cfg), None)
    assert isinstance(venv, ARPLVecEnv)
    model = build_model(cfg, venv)
    venv.policy = model.policy
    clean = venv.venv.reset()
    attacked = venv._attack(clean)
    assert np.allclose(np.linalg.norm(attacked - clean, axis=1), 0.5, atol=1e-4)
    venv.prob = 0.0
    assert np.array_equal(venv._attack(clean), clean)


# ---- training job ------------------------------------------------------------------------------


def test_resume_after_interruption_continues_from_checkpoint(tmp_path):
    cfg = tiny(timesteps=768, checkpoint_every=128, snapshot_every=256)
    with pytest.raises(KeyboardInterrupt):
        train_job(cfg, tmp_path, callback=Interrupt(at=400))
    ckpts = sorted(tmp_path.glob("ckpt-*"))
    assert len(ckpts) == 1 and int(ckpts[0].name.split("-")[1]) == 384  # last iteration boundary
    out = train_job(cfg, tmp_path)
    assert out["resumed_from"] == 384
    assert out["timesteps_done"] == 768
    assert out["snapshots"] == [0, 256, 512, 768]
    assert np.all(np.diff(out["episode_timesteps"]) >= 0) and out["episode_timesteps"][0] <= 384
    assert (tmp_path / "out" / "model.zip").exists() and (tmp_path / "out" / "vecnormalize.pkl").exists()


def test_train_job_through_cache_and_load_policy():
    cfg = tiny(timesteps=512, snapshot_every=256)
    res = RunCache().run(Job("train", cfg))
    assert res["timesteps_done"] == 512 and res["n_episodes"] > 0
    assert res["train_return"] == pytest.approx(np.mean(res["episode_returns"][-100:]))
    assert res["curve_timesteps"].tolist() == [128, 256, 384, 512]
    assert res["curve_return"][-1] == pytest.approx(res["train_return"])
    assert snapshots(res) == [0, 256, 512]

    pol = load_policy(res)
    obs = np.random.default_rng(0).normal(size=(7, 4))
    a = pol(obs)
    assert a.shape == (7, 1) and np.array_equal(a, pol(obs))  # deterministic
    assert pol(obs[0]).shape == (1,) and np.allclose(pol(obs[0]), a[0])
    assert np.all(np.abs(a) <= 3.0)
    # mean action of the saved normalisation: recompute by hand from the saved statistics
    with np.load(res.out / "obs_norm.npz") as z:
        x = np.clip((obs - z["mean"]) / np.sqrt(z["var"] + z["epsilon"]), -z["clip_obs"], z["clip_obs"])
        assert not np.allclose(z["mean"], 0)
    with th.no_grad():
        mu = mean_action(pol.net, th.as_tensor(x, dtype=th.float32)).numpy()
    assert np.allclose(a, np.clip(mu, -3, 3), atol=1e-6)
    # a snapshot is a different (earlier) policy
    first = load_policy(res, snapshot=0)
    assert not np.allclose(first(obs), a)
    with pytest.raises(ValueError, match="valid snapshots are"):
        load_policy(res, snapshot=3)


def test_same_seed_same_result(tmp_path):
    a = train_job(tiny(timesteps=256, seed=5), tmp_path / "a")
    b = train_job(tiny(timesteps=256, seed=5), tmp_path / "b")
    c = train_job(tiny(timesteps=256, seed=6), tmp_path / "c")
    assert np.array_equal(a["episode_returns"], b["episode_returns"])
    assert not np.array_equal(a["episode_returns"], c["episode_returns"])
    obs = np.random.default_rng(0).normal(size=(5, 4))
    assert np.array_equal(load_policy(tmp_path / "a" / "out")(obs), load_policy(tmp_path / "b" / "out")(obs))
    assert not np.array_equal(load_policy(tmp_path / "a" / "out")(obs), load_policy(tmp_path / "c" / "out")(obs))


OFF_POLICY_TINY = {"learning_starts": 50, "buffer_size": 1000, "train_freq": 10, "gradient_steps": 2}


@pytest.mark.parametrize("algo", [a for a in CH3 if a != "ppo"])  # ppo: test_resume_after_interruption_...
def test_resume_other_learners(tmp_path, algo):
    """Every chapter-3 learner checkpoints and resumes (in env steps) through the one train_job; the
    multi-domain learners: tests/test_mdl.py."""
    cfg = tiny(algo, timesteps=384, checkpoint_every=100, **(OFF_POLICY_TINY if algo in ("sac", "ddpg") else {}))
    with pytest.raises(KeyboardInterrupt):
        train_job(cfg, tmp_path, callback=Interrupt(at=260))
    out = train_job(cfg, tmp_path)
    assert 0 < out["resumed_from"] < 260 and out["timesteps_done"] >= 384
    assert load_policy(tmp_path / "out")(np.zeros((2, 4))).shape == (2, 1)


@pytest.mark.parametrize(
    ("algo", "kw"),
    [
        ("trpo", {}),
        ("sac", {"learning_starts": 50, "buffer_size": 1000, "train_freq": 10, "gradient_steps": 2}),
        ("ddpg", {"learning_starts": 50, "buffer_size": 1000, "train_freq": 10, "gradient_steps": 2}),
        ("ppo-obsnoise", {}),
    ],
)
def test_other_learners_train_and_load(tmp_path, algo, kw):
    out = train_job(tiny(algo, timesteps=256, **kw), tmp_path)
    assert out["timesteps_done"] >= 256
    pol = load_policy(tmp_path / "out")
    a = pol(np.random.default_rng(0).normal(size=(3, 4)))
    assert a.shape == (3, 1) and np.all(np.abs(a) <= 3.0)
    assert np.array_equal(a, pol(np.random.default_rng(0).normal(size=(3, 4))))


def test_training_env_seeds_stay_below_the_testing_range_also_after_a_resume(tmp_path, monkeypatch):
    """Training env seeds are < 2**32 (testing seeds are >= 2**32), however large the run seed; SB3's own rule
    (seed + i) could reach 2**32."""
    seen: list[int] = []
    original = lt.TrainingVecEnv.seed

    def recording(self, seed=None):
        out = original(self, seed)
        seen.extend(out)
        return out

    monkeypatch.setattr(lt.TrainingVecEnv, "seed", recording)
    cfg = tiny(timesteps=384, seed=2**32 - 1, checkpoint_every=128)
    with pytest.raises(KeyboardInterrupt):
        train_job(cfg, tmp_path, callback=Interrupt(at=200))
    assert train_job(cfg, tmp_path)["resumed_from"] == 128
    # a resumed run restores its envs' state exactly (tests/test_resume.py): whatever seeding the rebuild
    # does is overwritten, and every seed drawn stays below the testing range
    assert seen and all(0 <= s < 2**32 for s in seen)
    assert all(lt.env_seed(s, i) < 2**32 for s in (0, 2**32 - 1, 2**63) for i in range(16))


def _private_tmp(tmp_path: Path, monkeypatch) -> Path:
    """A fresh system temp dir, and SB3 back on its default logger folder (conftest points SB3_LOGDIR away)."""
    import tempfile

    monkeypatch.delenv("SB3_LOGDIR", raising=False)
    monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(tempfile, "tempdir", None)  # re-read TMPDIR
    return tmp_path / "tmp"


def test_training_leaves_no_logger_folders(tmp_path, monkeypatch):
    tmp = _private_tmp(tmp_path, monkeypatch)
    train_job(tiny(timesteps=128), tmp_path / "run")
    assert not list(tmp.glob("SB3-*"))


def test_bench_chunks_leave_no_logger_folders(tmp_path, monkeypatch):
    from stable_baselines3 import PPO

    from thesis_repro.learners.bench import _learn_chunk

    tmp = _private_tmp(tmp_path, monkeypatch)
    chunk = _learn_chunk(PPO("MlpPolicy", "InvertedPendulum-v5", n_steps=64, batch_size=64, n_epochs=1), 64)
    assert chunk() == 64 and chunk() == 64
    assert not list(tmp.glob("SB3-*"))
