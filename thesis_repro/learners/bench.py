"""Training throughput (env steps per CPU-second, gradient updates included) of the kit's learners vs SB3.

One line per throughput target, each ``measured value, ratio, target, met/not met``:

* **PPO** (Appendix-A settings: 8 envs × 256 steps, batch 64, 10 epochs, 64-64 tanh; the kit's
  :class:`~thesis_repro.learners.fast.FastPPO` + lean stepping) vs SB3's 1-env default
  (``PPO("MlpPolicy", gym.make("Hopper-v5"))``: n_steps 2048, batch 64, 10 epochs, 64-64 tanh): target >= 3x.
  For context (no target) the same kit settings trained by SB3's own ``PPO.train``, ``DummyVecEnv``, ``VecNormalize``.
* **SAC / DDPG** (the kit's configs: 64-64 ReLU, 50 gradient steps per 50 resp. 100 env steps, ...) trained by
  the kit's classes vs the same configs trained by SB3's own ``SAC.train`` / ``TD3.train`` and ``DummyVecEnv``
  (what SB3 does by default with these settings): target >= 2x. ``learning_starts`` is lowered so that the
  measured steps include gradient updates.

Rates are steps per CPU-second of this process (``time.process_time``; everything measured is single-threaded),
measured in alternating chunks (one chunk of each contender per round, after one warm-up chunk each), so
that the other work sharing the machine affects all contenders alike. Called by ``make bench`` through
:mod:`thesis_repro.core.bench`.

* **Multi-domain learners** (chapter 4, :func:`bench_multidomain`): ``joint``, ``params-avg``, ``kl-avg`` and
  ``kl-exact`` (their ``hyperparams.yaml`` settings: N = 4 domains × T = 1024 steps per iteration, Alg 3's
  per-epoch aggregation) against the kit's PPO (8 envs × 256), each built by the one training stack
  (``train_config`` + ``build_model``) and trained alternately, one iteration per chunk: target >= 0.8x the PPO
  rate. A learner the stack cannot build is reported as not available, with the reason.

>>> out = bench_training(rounds=1, ppo_chunk=2048, off_policy_chunk=200)  # doctest: +SKIP
>>> out["ppo ratio"] > 1  # doctest: +SKIP
True
"""

from __future__ import annotations

import tempfile
import time
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3 import PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor, VecNormalize

from thesis_repro.core.bench import target_line
from thesis_repro.core.validation import check_positive
from thesis_repro.envs.registry import resolve_env
from thesis_repro.learners import train as tr
from thesis_repro.learners.config import train_config

#: the throughput targets (ratios)
TARGETS: dict[str, float] = {"ppo": 3.0, "sac": 2.0, "ddpg": 2.0, "multidomain": 0.8}

_clock = time.process_time


def kit_model(algo: str, env: str, stock: bool = False, **overrides: Any) -> BaseAlgorithm:
    """The kit's model for ``train_config(algo, env, 0, ...)``; ``stock``: same settings, SB3's own ``train()``
    and rollout/exploration code, Gymnasium's env class, ``DummyVecEnv`` and ``VecNormalize`` (SB3 as is)."""
    cfg = train_config(algo, env, 0, 10**9, **overrides)
    if stock:  # Gymnasium's own registered env class, SB3's DummyVecEnv
        if cfg["perturbation"] != "none":
            raise ValueError(f"stock=True benchmarks unperturbed configs only, not {cfg['perturbation']!r}")
        fns = [lambda: gym.make(resolve_env(env), disable_env_checker=True)] * cfg["n_envs"]
        venv = VecMonitor(DummyVecEnv(fns))
        if cfg["normalize_obs"] or cfg["norm_reward"]:
            kw = dict(norm_obs=cfg["normalize_obs"], norm_reward=cfg["norm_reward"], clip_obs=cfg["clip_obs"])
            venv = VecNormalize(venv, gamma=cfg["sb3"].get("gamma", 0.99), **kw)
    else:
        venv = tr._wrap(cfg, tr.make_train_venv(cfg), None)
    model = tr.build_model(cfg, venv)
    if stock:
        base = {"PPO": PPO, "SAC": SAC, "DDPG": TD3}[cfg["class"]]
        model.train = types.MethodType(base.train, model)  # SB3's own update, on the same model
        if isinstance(model, OnPolicyAlgorithm):  # and SB3's own policy forward while collecting
            model.collect_rollouts = types.MethodType(OnPolicyAlgorithm.collect_rollouts, model)
        else:
            model._sample_action = types.MethodType(OffPolicyAlgorithm._sample_action, model)
    return model


def interleaved(chunks: dict[str, Callable[[], int]], rounds: int) -> dict[str, float]:
    """Steps per CPU-second of each ``chunk()`` (returns its env steps), run alternately ``rounds`` times after
    one warm-up call each."""
    check_positive(rounds, "rounds")
    steps = dict.fromkeys(chunks, 0)
    secs = dict.fromkeys(chunks, 0.0)
    for fn in chunks.values():
        fn()
    for _ in range(rounds):
        for name, fn in chunks.items():
            t0 = _clock()
            steps[name] += fn()
            secs[name] += _clock() - t0
    return {name: steps[name] / secs[name] for name in chunks}


def _learn_chunk(model: BaseAlgorithm, steps: int) -> Callable[[], int]:
    model.set_logger(Logger(None, []))  # SB3's default logger would leave an SB3-<timestamp> temp folder per learn()

    def chunk() -> int:
        before = model.num_timesteps
        model.learn(steps, reset_num_timesteps=False)
        return model.num_timesteps - before

    return chunk


def bench_training(
    env: str = "Hopper", rounds: int = 3, ppo_chunk: int = 4096, off_policy_chunk: int = 1000
) -> dict[str, float]:
    """Measure and print the PPO, SAC and DDPG lines (see module docstring); returns rates and ratios."""
    check_positive(ppo_chunk, "ppo_chunk")
    check_positive(off_policy_chunk, "off_policy_chunk")
    threads = th.get_num_threads()
    th.set_num_threads(1)  # as the cache jobs run
    out: dict[str, float] = {}
    try:
        sb3 = PPO("MlpPolicy", gym.make(resolve_env(env)), seed=0, device="cpu")
        chunks = {
            "sb3": _learn_chunk(sb3, ppo_chunk),
            "kit": _learn_chunk(kit_model("ppo", env), ppo_chunk),
            "kit-stock": _learn_chunk(kit_model("ppo", env, stock=True), ppo_chunk),
        }
        r = interleaved(chunks, rounds)
        out.update({"ppo sb3-default steps/s": r["sb3"], "ppo kit steps/s": r["kit"]})
        out["ppo kit-settings-sb3-train steps/s"] = r["kit-stock"]
        out["ppo ratio"] = target_line(
            f"PPO {env} (App. A) kit vs SB3 1-env default",
            f"{r['kit']:,.0f} vs {r['sb3']:,.0f} steps/s",
            r["kit"] / r["sb3"],
            TARGETS["ppo"],
        )
        print(
            f"  context: kit settings run by SB3 as is: {r['kit-stock']:,.0f} steps/s "
            f"({r['kit-stock'] / r['sb3']:.2f}x SB3 default); the fast update + stepping add "
            f"{r['kit'] / r['kit-stock']:.2f}x",
            flush=True,
        )
        for algo in ("sac", "ddpg"):
            kw = {"learning_starts": 100, "buffer_size": 100_000}
            chunks = {
                "stock": _learn_chunk(kit_model(algo, env, stock=True, **kw), off_policy_chunk),
                "kit": _learn_chunk(kit_model(algo, env, **kw), off_policy_chunk),
            }
            r = interleaved(chunks, rounds)
            out[f"{algo} sb3-train steps/s"], out[f"{algo} kit steps/s"] = r["stock"], r["kit"]
            out[f"{algo} ratio"] = target_line(
                f"{algo.upper()} {env} (kit config) kit vs SB3 as is",
                f"{r['kit']:,.0f} vs {r['stock']:,.0f} steps/s",
                r["kit"] / r["stock"],
                TARGETS[algo],
            )
        return out
    finally:
        th.set_num_threads(threads)


def _fill_replay(model: BaseAlgorithm, n: int) -> None:
    """Fill ``model``'s replay buffer up to ``n`` rows by repeating the rows it holds (the speed of sampling
    from a large buffer depends on its size, not on its values)."""
    buf = model.replay_buffer  # type: ignore[attr-defined]
    k = buf.pos
    for name in ("observations", "next_observations", "actions", "rewards", "dones", "timeouts"):
        a = getattr(buf, name)
        a[k:n] = np.resize(a[:k], (n - k, *a.shape[1:]))
    buf.pos = n


def bench_generator_path(
    env: str = "Hopper", rounds: int = 3, chunk: int = 500, algos: tuple[str, ...] = ("sac", "ddpg")
) -> dict[str, float]:
    """What the generator's path costs beyond ``make bench``'s, in steps per CPU-second measured alternately in
    one process (see :func:`interleaved`): per learner, the bench's model (100k buffer, nearly empty) against the
    shipped config's 1M buffer filled to 900k rows, without and with the training job's bookkeeping callback
    (episodes, checkpoint and snapshot checks). Ratios near 1: the generator's training path is the bench's."""
    check_positive(chunk, "chunk")
    threads = th.get_num_threads()
    th.set_num_threads(1)
    out: dict[str, float] = {}
    try:
        for algo in algos:

            def make(buffer_size: int, filled: int, book: bool, algo: str = algo) -> Callable[[], int]:
                model = kit_model(algo, env, learning_starts=100, buffer_size=buffer_size)
                model.set_logger(Logger(None, []))
                model.learn(2000, reset_num_timesteps=False)
                if filled:
                    _fill_replay(model, filled)
                callback = None
                if book:
                    cfg = train_config(algo, env, 0, 10**9, learning_starts=100, buffer_size=buffer_size)
                    cfg["checkpoint_every"] = 0
                    state = {"episodes": [], "iterations": [], "last_snapshot": None, "last_checkpoint": 0}
                    callback = tr._Bookkeeper(cfg, Path(tempfile.mkdtemp()), state)

                def run() -> int:
                    before = model.num_timesteps
                    model.learn(chunk, reset_num_timesteps=False, callback=callback)
                    return model.num_timesteps - before

                return run

            r = interleaved(
                {
                    "bench": make(100_000, 0, False),
                    "1M": make(1_000_000, 900_000, False),
                    "job": make(1_000_000, 900_000, True),
                },
                rounds,
            )
            out[f"{algo} bench steps/s"] = r["bench"]
            out[f"{algo} 1M-buffer ratio"] = r["1M"] / r["bench"]
            out[f"{algo} training-job ratio"] = r["job"] / r["bench"]
            print(
                f"  {algo.upper()} {env}: bench path {r['bench']:,.0f} steps/CPU-s; 1M buffer filled to 900k "
                f"{r['1M'] / r['bench']:.3f}x; + the training job's bookkeeping {r['job'] / r['bench']:.3f}x",
                flush=True,
            )
        return out
    finally:
        th.set_num_threads(threads)


def bench_sac_stack(env: str = "Walker2d", rounds: int = 3, chunk: int = 500) -> dict[str, float]:
    """SAC with its two actor forwards per gradient step stacked into one (``FastSAC.stack_actor``, the same bits)
    against two, the shipped config (batch 128) on ``env``, in steps per CPU-second measured alternately in one
    process (:func:`interleaved`); prints the ratio."""
    check_positive(chunk, "chunk")
    threads = th.get_num_threads()
    th.set_num_threads(1)
    try:
        chunks = {}
        for stack in (True, False):
            model = kit_model("sac", env, learning_starts=100, buffer_size=100_000)
            model.stack_actor = stack  # type: ignore[attr-defined]
            model.set_logger(Logger(None, []))
            model.learn(1000, reset_num_timesteps=False)
            chunks["stacked" if stack else "two"] = _learn_chunk(model, chunk)
        r = interleaved(chunks, rounds)
        ratio = r["stacked"] / r["two"]
        print(
            f"  SAC {env}: one stacked actor forward {r['stacked']:,.0f} vs two {r['two']:,.0f} steps/CPU-s = "
            f"{ratio:.3f}x (the same bits)",
            flush=True,
        )
        return {"sac stacked steps/s": r["stacked"], "sac two-forward steps/s": r["two"], "sac stack ratio": ratio}
    finally:
        th.set_num_threads(threads)


# ---------------------------------------------------------------- chapter 4: the multi-domain learners
MULTIDOMAIN_ALGOS: tuple[str, ...] = ("joint", "params-avg", "kl-avg", "kl-exact")


def _iteration_steps(model: Any) -> int:
    return int(model.n_steps) * int(model.env.num_envs)


def bench_multidomain(
    env: str = "Hopper", rounds: int = 3, algos: tuple[str, ...] = MULTIDOMAIN_ALGOS
) -> dict[str, float]:
    """Steps/s of each multi-domain learner and of plain kit PPO on ``env``; prints one target line per learner."""
    threads = th.get_num_threads()
    th.set_num_threads(1)
    try:
        ppo = kit_model("ppo", env)
        chunks = {"ppo": _learn_chunk(ppo, _iteration_steps(ppo))}
        for algo in algos:
            try:
                model = kit_model(algo, env)
                chunks[algo] = _learn_chunk(model, _iteration_steps(model))
            except Exception as err:  # a learner the stack cannot build: say so, instead of failing the bench
                print(f"  {algo}: not available with the current training stack ({type(err).__name__}: {err})")
        rates = interleaved(chunks, rounds)
        out = {"ppo steps/s": rates["ppo"]}
        for algo in algos:
            if algo in rates:
                out[f"{algo} steps/s"] = rates[algo]
                out[f"{algo} ratio"] = target_line(
                    f"{algo} {env} iteration vs plain kit PPO, per env step",
                    f"{rates[algo]:,.0f} vs {rates['ppo']:,.0f} steps/s",
                    rates[algo] / rates["ppo"],
                    TARGETS["multidomain"],
                )
        return out
    finally:
        th.set_num_threads(threads)
