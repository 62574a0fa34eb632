"""Exact resume: a training run interrupted at an arbitrary step and rerun ends bit-identical to one that was
never interrupted, for every learner class (simulators mid-episode, domain/noise wrappers, the observation
filter, ARPL's attack draws, the multi-domain learners' per-domain views, off-policy replay and OU noise)."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

from tests.interrupt import Interrupt
from thesis_repro.learners import train_config, train_job
from thesis_repro.learners.policy_file import read_state_dict
from thesis_repro.learners.resume import ResumeMismatch, capture, restore

OFF = {"learning_starts": 40, "buffer_size": 2000, "train_freq": 16, "gradient_steps": 2, "batch_size": 32}
PPO = {"n_steps": 64, "n_envs": 2, "batch_size": 32, "n_epochs": 2}
MD = {"n_steps": 64, "batch_size": 32, "n_epochs": 2}

# (algo, env, overrides): one learner per class, plus the wrappers that carry state across steps
CASES = [
    ("ppo", "Hopper", PPO),
    ("ppo-arpl", "Hopper", PPO),
    ("ppo-mdl", "Walker2d", PPO),  # a new domain per episode: MjModel edits mid-run
    ("ppo-envnoise", "Hopper", PPO),
    ("ppo-scn-16", "InvertedPendulum", PPO),
    ("trpo", "Hopper", {"n_steps": 64, "n_envs": 2}),
    ("ppo-epopt", "Hopper", {**MD, "perturbation": "dom", "sigma": 0.2}),
    ("ppo-maml-dg", "Hopper", {**MD, "perturbation": "dom", "sigma": 0.2}),
    ("ppo-reptile-dg", "Hopper", {**MD, "perturbation": "dom", "sigma": 0.2}),
    ("kl-avg", "Walker2d", {**MD, "wind": [-2.0, 2.0]}),
    ("sac", "Hopper", OFF),
    ("ddpg", "Hopper", OFF),
]


def _params(workdir) -> dict[str, th.Tensor]:
    return read_state_dict(workdir / "out" / "policy.pth")


@pytest.mark.parametrize(("algo", "env", "over"), CASES, ids=[c[0] for c in CASES])
def test_interrupted_and_resumed_run_is_bit_identical_to_an_uninterrupted_one(tmp_path, algo, env, over):
    timesteps = 640 if algo not in ("ppo-maml-dg",) else 1280
    cfg = train_config(algo, env, 3, timesteps, max_episode_steps=60, checkpoint_every=1, **over)
    straight = train_job(cfg, tmp_path / "straight")
    # an interrupt at an arbitrary step (mid-iteration, mid-episode), then another one after the resume
    first, second = (293, 517) if algo != "ppo-maml-dg" else (593, 1037)
    with pytest.raises(KeyboardInterrupt):
        train_job(cfg, tmp_path / "resumed", callback=Interrupt(at=first))
    with pytest.raises(KeyboardInterrupt):
        train_job(cfg, tmp_path / "resumed", callback=Interrupt(at=second))
    resumed = train_job(cfg, tmp_path / "resumed")
    assert 0 < resumed["resumed_from"] <= second
    for key in ("episode_returns", "episode_lengths", "episode_timesteps", "curve_return"):
        assert np.array_equal(straight[key], resumed[key], equal_nan=True), key
    a, b = _params(tmp_path / "straight"), _params(tmp_path / "resumed")
    assert a.keys() == b.keys() and all(th.equal(a[k], b[k]) for k in a)
    if cfg["normalize_obs"]:
        x, y = (np.load(tmp_path / run / "out" / "obs_norm.npz") for run in ("straight", "resumed"))
        assert np.array_equal(x["mean"], y["mean"]) and np.array_equal(x["var"], y["var"])


def test_a_checkpoint_without_live_state_is_discarded_and_the_run_starts_afresh(tmp_path, capsys):
    cfg = train_config("ppo", "InvertedPendulum", 0, 384, max_episode_steps=60, checkpoint_every=1, **PPO)
    straight = train_job(cfg, tmp_path / "straight")
    with pytest.raises(KeyboardInterrupt):
        train_job(cfg, tmp_path / "old", callback=Interrupt(at=200))
    for ckpt in (tmp_path / "old").glob("ckpt-*"):
        (ckpt / "live.pkl").unlink()  # as an older kit wrote it
    res = train_job(cfg, tmp_path / "old")
    assert "starting afresh" in capsys.readouterr().out
    assert res["resumed_from"] == 0 and np.array_equal(res["episode_returns"], straight["episode_returns"])


def test_restore_writes_arrays_in_place_and_rejects_another_structure():
    class Sim:
        def __init__(self, n: int):
            self.memory = np.zeros(n)
            self.view = self.memory[1:]  # e.g. a factor's target array: a view into simulator memory
            self.pairs = ((self.view, np.ones(n - 1)),)
            self.rng = np.random.default_rng(1)
            self.episodes: list[float] = []

    a = Sim(3)
    a.memory[:] = [1, 2, 3]
    a.episodes += [5.0, 6.0]
    saved = capture(a)
    b = Sim(3)
    restore(b, saved)
    assert b.memory.tolist() == [1, 2, 3] and b.view.base is b.memory and b.pairs[0][0].base is b.memory
    assert b.episodes == [5.0, 6.0] and b.rng.random() == a.rng.random()
    other = Sim(3)
    other.rng = np.zeros(2)  # another structure: an array where the run had a generator
    with pytest.raises(ResumeMismatch, match="rng"):
        restore(other, saved)
