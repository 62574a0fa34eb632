"""Training throughput (env steps/s, wall clock incl. gradient updates) of our PPO setup vs SB3 defaults.

(a) ``PPO("MlpPolicy", 1 env)`` with SB3's defaults (n_steps 2048, batch 64, 10 epochs, 64-64 tanh);
(b) ``n_envs`` (8) environments in one process (DummyVecEnv + VecMonitor + VecNormalize), ``n_steps``
256 each, so the batch stays the thesis's 2048, same epochs/minibatch, SB3's default (unfused) Adam;
(c) our ``ppo`` config = (b) with fused Adam (same update, one CPU kernel).
Both with ``torch.set_num_threads(1)`` (how cache jobs run), same seed, same number of steps.
Optionally (``off_policy_steps`` > 0) SAC and DDPG with our configs (their 1 gradient step per env step,
resp. 50 per 100, dominate). Called by ``make bench`` via :mod:`thesis_repro.bench`.

>>> out = bench_training(steps=4096)  # doctest: +SKIP
>>> out["ratio"] > 1  # doctest: +SKIP
True
"""

from __future__ import annotations

import time
from typing import Any

import torch as th
from stable_baselines3 import PPO

from thesis_repro.envs import make_env
from thesis_repro.learners.config import train_config
from thesis_repro.learners.train import _wrap, build_model, make_train_venv
from thesis_repro.validation import check_positive


def _rate(model: Any, steps: int) -> float:
    t0 = time.perf_counter()
    model.learn(total_timesteps=steps)
    return model.num_timesteps / (time.perf_counter() - t0)


def bench_training(env: str = "Hopper", steps: int = 20_000, off_policy_steps: int = 0) -> dict[str, float]:
    """Steps/s of SB3-default PPO (1 env) vs our batched PPO; prints one line each and the ratio."""
    check_positive(steps, "steps")
    threads = th.get_num_threads()
    th.set_num_threads(1)
    try:
        base = PPO("MlpPolicy", make_env(env, seed=0), seed=0, device="cpu", verbose=0)
        sb3_default = _rate(base, steps)
        print(f"PPO SB3 defaults, 1 env:            {sb3_default:8.0f} steps/s", flush=True)
        cfg = train_config("ppo", env, 0, steps, optimizer_kwargs={"eps": 1e-5, "fused": False})
        unfused = _rate(build_model(cfg, _wrap(cfg, make_train_venv(cfg), None)), steps)
        n, k = cfg["n_envs"], cfg["sb3"]["n_steps"]
        print(f"PPO {n} envs x {k} steps, unfused Adam: {unfused:8.0f} steps/s  ({unfused / sb3_default:.2f}x)")
        cfg = train_config("ppo", env, 0, steps)
        ours = _rate(build_model(cfg, _wrap(cfg, make_train_venv(cfg), None)), steps)
        print(f"PPO ours ({n} envs, fused Adam):       {ours:8.0f} steps/s  ({ours / sb3_default:.2f}x)")
        out = {
            "ppo_sb3_default_steps_per_s": sb3_default,
            "ppo_8env_unfused_steps_per_s": unfused,
            "ppo_ours_steps_per_s": ours,
            "ratio": ours / sb3_default,
        }
        for algo in ("sac", "ddpg") if off_policy_steps > 0 else ():
            cfg = train_config(algo, env, 0, off_policy_steps, learning_starts=min(1000, off_policy_steps // 4))
            out[f"{algo}_steps_per_s"] = rate = _rate(
                build_model(cfg, _wrap(cfg, make_train_venv(cfg), None)), off_policy_steps
            )
            print(f"{algo.upper()} ours:                         {rate:8.0f} steps/s")
        return out
    finally:
        th.set_num_threads(threads)
