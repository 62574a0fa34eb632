"""The SAC/DDPG speed-ups of ``thesis_repro.learners.fast`` are exact: each replaced operation gives the same bits
(whole training runs: ``tests/test_speed_identity.py``)."""

from __future__ import annotations

import copy

import gymnasium as gym
import numpy as np
import torch as th

from thesis_repro.learners.fast_offpolicy import FastSAC, _Numbers, _polyak, _polyak_factor, _replay_sample
from thesis_repro.learners.kernels import _ones_like_steps


def _values(seed: int, shape=(257, 9)) -> th.Tensor:
    g = th.Generator().manual_seed(seed)
    x = th.randn(shape, generator=g) * th.exp(th.randn(shape, generator=g) * 8)  # many magnitudes
    x.view(-1)[:6] = th.tensor([0.0, -0.0, 1e-40, -1e-40, 3e38, -7.5])
    return x


def test_numbers_give_the_same_bits_as_python_scalars():
    n = _Numbers(th.float32)
    x = _values(0)
    for c in (2, 1, 1e-6, 0.5, 0.99, -1.0 / 128, 2.0 / 64, -20, float(np.log(np.sqrt(2 * np.pi)))):
        assert th.equal((x * c).view(th.int32), (x * n(c)).view(th.int32))
        assert th.equal((x + c).view(th.int32), (x + n(c)).view(th.int32))
        assert th.equal((x - c).view(th.int32), (x - n(c)).view(th.int32))
        assert th.equal(th.rsub(x, c).view(th.int32), th.rsub(x, n(c)).view(th.int32))
        assert th.equal(x >= c, x >= n(c)) and th.equal(x <= c, x <= n(c))
    assert n.of(0.99, th.zeros(2, dtype=th.float64)) == 0.99 and n.of(th.ones(1), x) is not None


def test_polyak_factor_and_step_counters_give_the_same_bits():
    tau = 0.01
    params = [_values(i, (64, 65)) for i in range(3)]
    a, b = [_values(10 + i, (64, 65)) for i in range(3)], [_values(10 + i, (64, 65)) for i in range(3)]
    for _ in range(5):
        _polyak(params, a, tau)
        _polyak(params, b, tau, _polyak_factor(b, tau))
    assert all(th.equal(x.view(th.int32), y.view(th.int32)) for x, y in zip(a, b, strict=True))
    s1, s2 = [th.tensor(float(k)) for k in range(4)], [th.tensor(float(k)) for k in range(4)]
    one = _ones_like_steps(s2)
    for _ in range(3):
        th._foreach_add_(s1, 1)
        th._foreach_add_(s2, one)
    assert all(th.equal(x, y) for x, y in zip(s1, s2, strict=True))


def test_replay_sample_take_path_equals_advanced_indexing():
    # 600 random steps fill the 500-step buffer and wrap (no gradient step: only the sampling is under test)
    m = FastSAC("MlpPolicy", gym.make("InvertedPendulum-v5"), learning_starts=10_000, buffer_size=500, seed=0)
    m.learn(600)
    buf = m.replay_buffer
    assert buf.full
    np.random.seed(3)
    fast = _replay_sample(m, 64)
    after = np.random.get_state()[1].copy()
    np.random.seed(3)
    inds = np.random.randint(0, buf.buffer_size if buf.full else buf.pos, size=64)
    envs = np.random.randint(0, high=buf.n_envs, size=(64,))
    assert np.array_equal(after, np.random.get_state()[1])  # the same draws
    dones = (buf.dones[inds, envs] * (1 - buf.timeouts[inds, envs])).reshape(-1, 1)
    ref = [buf.observations[inds, envs, :], buf.actions[inds, envs, :], buf.next_observations[inds, envs, :], dones]
    ref.append(buf.rewards[inds, envs].reshape(-1, 1))
    for got, want in zip(fast[:5], ref, strict=True):
        assert got.numpy().dtype == want.dtype and np.array_equal(got.numpy(), want)


def test_fast_sac_deep_copies_and_saves_without_its_exploration_cache(tmp_path):
    m = FastSAC("MlpPolicy", gym.make("InvertedPendulum-v5"), learning_starts=10, seed=0)
    m.learn(100)
    assert m._actor_cache is not None
    twin = copy.deepcopy(m)
    assert twin._actor_cache is None and m._actor_cache is not None
    m.save(tmp_path / "m.zip")
    assert FastSAC.load(tmp_path / "m.zip")._actor_cache is None


def test_stacked_actor_forwards_train_the_same_bits_on_the_study_tasks():
    """One actor forward of a batch's observations and next observations (``FastSAC.stack_actor``) against two, on
    short runs of the locomotion tasks' shapes with the shipped batch of 128 (and a batch that is no multiple of 16,
    which keeps two forwards): the same weights, bit for bit, after 150 gradient steps."""
    from thesis_repro.learners import train as tr
    from thesis_repro.learners import train_config

    th.set_num_threads(1)
    for env, batch in (("Walker2d", 128), ("Hopper", 128), ("Hopper", 40)):  # HalfCheetah: Walker2d's shapes
        cfg = train_config("sac", env, 2, 10**6, learning_starts=100, batch_size=batch, max_episode_steps=80)
        weights = []
        for stack in (True, False):
            model = tr.build_model(cfg, tr._wrap(cfg, tr.make_train_venv(cfg), None))
            model.stack_actor = stack
            model.learn(250)
            weights.append({k: v.clone() for k, v in model.policy.state_dict().items()})
        assert weights[0].keys() == weights[1].keys()
        assert all(th.equal(weights[0][k], weights[1][k]) for k in weights[0]), (env, batch)
