"""Benchmark: per-iteration cost of kl_avg relative to params_avg and joint (one run each, Walker2d).

>>> r = bench_kl_avg(iterations=1, steps_per_domain=64, max_episode_steps=50)  # doctest: +SKIP
>>> sorted(r)[:2]  # doctest: +SKIP
['iterations', 'kl_avg/joint']
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch

from thesis_repro.mdl.config import mdl_config
from thesis_repro.mdl.train import MultiDomainTrainer


def bench_kl_avg(env: str = "Walker2d", iterations: int = 1, **overrides: Any) -> dict[str, float]:
    """Seconds per training iteration (N=4 domains x 1024 steps by default) of joint, params_avg and kl_avg.

    The first iteration of each learner is a warm-up and not timed (``iterations`` are timed after it).
    Returns the per-iteration seconds and the ratios ``kl_avg/params_avg`` and ``kl_avg/joint``.
    """
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations!r}")
    torch.set_num_threads(1)
    out: dict[str, float] = {"iterations": float(iterations)}
    for algo in ("joint", "params_avg", "kl_avg"):
        trainer = MultiDomainTrainer(mdl_config(algo, env, 0, 10**9, **overrides))
        try:
            trainer.iterate()
            times = []
            for _ in range(iterations):
                t0 = time.perf_counter()
                trainer.iterate()
                times.append(time.perf_counter() - t0)
        finally:
            trainer.close()
        out[f"{algo}_s_per_iter"] = float(np.mean(times))
    out["kl_avg/params_avg"] = out["kl_avg_s_per_iter"] / out["params_avg_s_per_iter"]
    out["kl_avg/joint"] = out["kl_avg_s_per_iter"] / out["joint_s_per_iter"]
    return out


if __name__ == "__main__":
    for k, v in bench_kl_avg().items():
        print(f"{k:>24s}: {v:.3f}")
