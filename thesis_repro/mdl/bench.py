"""Benchmark: env steps per CPU-second of the multi-domain learners (chapter 4) vs plain kit PPO.

``joint``, ``params-avg``, ``kl-avg`` and ``kl-exact`` (their ``hyperparams.yaml`` settings: N = 4 domains ×
T = 1024 steps per iteration, Alg 3's per-epoch aggregation) and the kit's PPO (8 envs × 256) are each built
by the one training stack (``train_config`` + ``build_model``) and trained alternately, one iteration per chunk
(:func:`thesis_repro.learners.bench.interleaved`). Target (issue 7): every multi-domain learner >= 0.8x the
PPO rate. A learner the stack cannot build yet is reported as not available, with the reason.

>>> r = bench_multidomain(rounds=1)  # doctest: +SKIP
>>> sorted(r)[:2]  # doctest: +SKIP
['joint ratio', 'joint steps/s']
"""

from __future__ import annotations

from typing import Any

import torch as th

from thesis_repro.bench import target_line
from thesis_repro.learners.bench import TARGETS, _learn_chunk, interleaved, kit_model

ALGOS: tuple[str, ...] = ("joint", "params-avg", "kl-avg", "kl-exact")


def _iteration_steps(model: Any) -> int:
    return int(model.n_steps) * int(model.env.num_envs)


def bench_multidomain(env: str = "Hopper", rounds: int = 3, algos: tuple[str, ...] = ALGOS) -> dict[str, float]:
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
            except Exception as err:  # the multi-domain stack is being rebuilt; say so instead of failing
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
