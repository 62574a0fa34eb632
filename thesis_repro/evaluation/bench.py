"""Evaluation throughput on ONE task (Hopper-v5, an untrained SB3 PPO 64-64 MlpPolicy), in env-steps/s.

(a) :class:`~thesis_repro.evaluation.BatchedEvaluator` (n_envs copies, one batched forward per step),
(b) a per-step ``model.predict`` loop on one env, (c) raw ``mujoco.mj_step(model, data, frame_skip)``
(the physics alone, no Python env), plus (d) ``env.step`` without a policy for reference. Rates are
steps per CPU-second of this process (see ``_clock``).
Hopper is built with ``terminate_when_unhealthy=False`` so every episode runs the full horizon: the
numbers measure stepping, not resets of a falling robot.

>>> out = bench_evaluation(seconds=0.2, horizon=100, rounds=1)  # doctest: +SKIP
"""

from __future__ import annotations

import os
import time
from typing import Any

import gymnasium as gym
import numpy as np

TASK = "Hopper-v5"
HORIZON = 1000
#: CPU time of this process, not wall time: the 2 cores are shared by several engineers, and CPU time is
#: far less sensitive to their load (all measured code is single-threaded: torch threads = 1).
_clock = time.process_time


def _make(**_: Any) -> gym.Env:
    return gym.make(TASK, terminate_when_unhealthy=False, max_episode_steps=HORIZON, disable_env_checker=True)


def _model() -> Any:
    from stable_baselines3 import PPO  # local (as below): start-up time of the benchmark registry

    return PPO("MlpPolicy", _make(), policy_kwargs={"net_arch": [64, 64]}, seed=0, device="cpu")


def raw_physics(seconds: float) -> float:
    """Steps/s of ``mujoco.mj_step`` × frame_skip on the env's own model (random controls)."""
    import mujoco  # local: start-up time

    env = _make()
    env.reset(seed=0)
    u = env.unwrapped
    m, d, skip = u.model, u.data, u.frame_skip
    ctrl = np.random.default_rng(0).uniform(-1, 1, size=(256, m.nu))
    n, t0 = 0, _clock()
    while _clock() - t0 < seconds:
        for i in range(256):
            d.ctrl[:] = ctrl[i]
            mujoco.mj_step(m, d, skip)
        n += 256
    env.close()
    return n / (_clock() - t0)


def env_step(seconds: float) -> float:
    """Steps/s of ``env.step`` with a fixed action (no policy)."""
    env = _make()
    env.reset(seed=0)
    a = np.zeros(env.action_space.shape)
    n, t0 = 0, _clock()
    while _clock() - t0 < seconds:
        for _ in range(100):
            _, _, term, trunc, _ = env.step(a)
            if term or trunc:
                env.reset()
        n += 100
    env.close()
    return n / (_clock() - t0)


def predict_loop(model: Any, seconds: float) -> float:
    """Steps/s of the usual loop: ``model.predict`` then ``env.step`` on one env."""
    env = _make()
    obs, _ = env.reset(seed=0)
    n, t0 = 0, _clock()
    while _clock() - t0 < seconds:
        for _ in range(100):
            action, _ = model.predict(obs, deterministic=True)
            obs, _, term, trunc, _ = env.step(action)
            if term or trunc:
                obs, _ = env.reset()
        n += 100
    env.close()
    return n / (_clock() - t0)


def batched(model: Any, n_envs: int, horizon: int) -> tuple[float, float]:
    """Steps/s of the batched evaluator (env construction included) and the mean episode length."""
    from thesis_repro.evaluation import BatchedEvaluator, sb3_policy, test_seeds  # local: loads torch and SB3

    ev = BatchedEvaluator(sb3_policy(model), _make, n_envs=n_envs, max_episode_steps=horizon)
    t0 = _clock()
    out = ev.run([{}], test_seeds(0, n_envs))
    dt = _clock() - t0
    return float(out.lengths.sum() / dt), float(out.lengths.mean())


def bench_evaluation(seconds: float = 1.0, n_envs: int = 16, horizon: int = HORIZON, rounds: int = 3) -> dict:
    """Measure (a) batched, (b) predict loop, (c) raw physics, (d) env.step; print ratios vs the targets.

    The four measurements are interleaved over ``rounds`` (the machine is shared; load hits all of them
    alike) and the median of each is reported. (a) runs ``n_envs`` full episodes of ``horizon`` steps.
    """
    import torch  # local: start-up time

    torch.set_num_threads(1)
    model = _model()
    runs: dict[str, list[float]] = {"a": [], "b": [], "c": [], "d": []}
    for _ in range(rounds):
        runs["c"].append(raw_physics(seconds))
        runs["d"].append(env_step(seconds))
        runs["b"].append(predict_loop(model, seconds))
        runs["a"].append(batched(model, n_envs, horizon)[0])
    a, b, c, d = (float(np.median(runs[k])) for k in "abcd")
    print(f"  task {TASK} (terminate_when_unhealthy=False), untrained PPO MlpPolicy 64-64, torch threads=1,")
    print(f"  steps per CPU-second, median of {rounds} interleaved rounds; load average {os.getloadavg()[0]:.1f}")
    print(f"  (a) batched evaluator, n_envs={n_envs}, episodes of {horizon} steps: {a:9,.0f} env-steps/s")
    print(f"  (b) model.predict loop, 1 env:                              {b:9,.0f} env-steps/s")
    print(f"  (c) raw mujoco.mj_step x frame_skip (physics only):          {c:9,.0f} steps/s")
    print(f"  (d) gymnasium env.step, no policy (reference):               {d:9,.0f} steps/s")
    ok_b = "MET" if a / b >= 10 else "NOT MET"
    ok_c = "MET" if a / c >= 0.5 else "NOT MET"
    print(f"  a/b = {a / b:.2f}x  (target >= 10x: {ok_b}; the ceiling here is c/b = {c / b:.2f}x: even free policy")
    print("         inference cannot step faster than the physics, so 10x is unreachable on this CPU)")
    print(f"  a/c = {a / c:.2f}x  (target >= 0.5x: {ok_c}; aim >= 0.7x: {'MET' if a / c >= 0.7 else 'NOT MET'};")
    print(f"         the env's own Python overhead alone gives d/c = {d / c:.2f}x)")
    return {
        "batched_steps_per_s": a,
        "predict_steps_per_s": b,
        "raw_steps_per_s": c,
        "env_steps_per_s": d,
        "a_over_b": a / b,
        "a_over_c": a / c,
    }
