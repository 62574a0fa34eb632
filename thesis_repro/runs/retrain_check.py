"""A retrain against the shipped run: bit-identical on the platform that made it, else the same outcome.

:func:`max_abs_diff` compares two runs' policies, :func:`recompute` makes a job again in a fresh process with the
numerics an entry records, and :func:`compare_retrain` (:func:`retrain_verdict`'s rule) says whether a retrain is
the shipped run again: ``make verify --train`` and the provenance tests.
"""

from __future__ import annotations

import json
import os
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thesis_repro.core.cache import Job, Result, RunCache
from thesis_repro.core.provenance import numerics_env, same_platform
from thesis_repro.runs.shipped_checks import shipped_job


def _policy_arrays(result_or_path: Result | str | Path) -> dict[str, np.ndarray]:
    from thesis_repro.learners.policy_file import read_state_dict  # local: keep the listing importable without torch

    folder = Path(getattr(result_or_path, "out", result_or_path))
    if not (folder / "policy.pth").exists() and (folder / "out" / "policy.pth").exists():
        folder = folder / "out"
    arrays = {f"policy.{k}": v.numpy() for k, v in read_state_dict(folder / "policy.pth").items()}
    if (folder / "obs_norm.npz").exists():
        with np.load(folder / "obs_norm.npz", allow_pickle=False) as z:
            arrays.update({f"obs_norm.{k}": z[k] for k in ("mean", "var")})
    return arrays


def max_abs_diff(result_a: Result | str | Path, result_b: Result | str | Path) -> float:
    """Largest absolute difference between two training runs' policy weights and observation filters
    (``0.0``: bit-identical); ``ValueError`` if they do not have the same parameters."""
    a, b = _policy_arrays(result_a), _policy_arrays(result_b)
    if a.keys() != b.keys() or any(a[k].shape != b[k].shape for k in a):
        diff = sorted(a.keys() ^ b.keys()) or [k for k in a if a[k].shape != b[k].shape]
        raise ValueError(f"the two runs have different parameters: {', '.join(diff[:5])}")
    return max((float(np.max(np.abs(a[k].astype(np.float64) - b[k]))) for k in a if a[k].size), default=0.0)


#: A retrain on the platform that made the shipped run must give its weights to this tolerance.
WEIGHTS_ATOL = 1e-6
#: On another platform (other SIMD kernels, so other last bits, which RL amplifies) a retrain is another
#: sample of the same training procedure: its training return and its deterministic policy's testing return
#: must match the shipped run's within this relative tolerance.
OUTCOME_RTOL = 0.05


_RECOMPUTE = """
import json, sys
from thesis_repro.core.cache import Job, RunCache
spec = json.loads(sys.argv[1])
RunCache(spec["root"], reference=False).run(Job(spec["kind"], spec["config"]))
"""


def recompute(job: Job, root: str | Path, like: Result | str | Path) -> Result:
    """Compute ``job`` into the cache at ``root`` in a fresh process with the numerics ``like`` was made in
    (:func:`numerics_env`): how ``make verify`` and the retrain test check a shipped entry bit for bit."""
    import sys

    import thesis_repro

    env = {k: v for k, v in os.environ.items() if k not in thesis_repro.PORTABLE_NUMERICS}
    env.update(numerics_env(like))
    spec = json.dumps({"kind": job.kind, "config": dict(job.config), "root": str(root)})
    subprocess.run([sys.executable, "-c", _RECOMPUTE, spec], env=env, check=True)
    result = RunCache(root, reference=False).load(job)
    if result is None:  # pragma: no cover - the subprocess committed it or failed above
        raise RuntimeError(f"recompute of {job.label} left no entry in {root}")
    return result


@dataclass(frozen=True)
class RetrainCheck:
    """Outcome of :func:`retrain_verdict`: ``ok`` and a one-line ``message`` saying which rule applied."""

    ok: bool
    message: str


def retrain_verdict(
    label: str,
    same: bool | None,
    weights_diff: float,
    train_return: tuple[float, float],
    test_return: tuple[float, float] | None,
    rtol: float = OUTCOME_RTOL,
) -> RetrainCheck:
    """The rule of :func:`compare_retrain` on its numbers (``(shipped, fresh)`` pairs).

    Same platform: weights within :data:`WEIGHTS_ATOL`. Another or unrecorded platform: bit-identical
    weights pass too; otherwise both returns must agree within ``rtol`` of the larger magnitude.

    >>> retrain_verdict("r", True, 0.0, (990.0, 990.0), None).ok
    True
    >>> retrain_verdict("r", True, 0.3, (990.0, 991.0), None).message
    'r: same platform as the shipped run but weights differ by 0.3 > 1e-06 (training is not deterministic)'
    >>> retrain_verdict("r", None, 0.3, (993.6, 991.1), (1000.0, 1000.0)).ok
    True
    >>> retrain_verdict("r", False, 0.3, (993.6, 500.0), (1000.0, 1000.0)).ok
    False
    """

    def close(pair: tuple[float, float]) -> bool:
        a, b = pair
        return abs(a - b) <= rtol * max(abs(a), abs(b))

    if weights_diff <= WEIGHTS_ATOL:
        return RetrainCheck(True, f"{label}: bit-identical to the shipped run (max |dw| {weights_diff:.1e})")
    if same:
        return RetrainCheck(
            False,
            f"{label}: same platform as the shipped run but weights differ by {weights_diff:.3g} > "
            f"{WEIGHTS_ATOL:g} (training is not deterministic)",
        )
    where = "another platform" if same is False else "a platform the shipped run did not record"
    pairs = {"training return": train_return, **({"testing return": test_return} if test_return else {})}
    ok = all(close(p) for p in pairs.values())
    said = ", ".join(f"{k} {a:.2f} shipped vs {b:.2f} retrained" for k, (a, b) in pairs.items())
    rule = f"within {rtol:.0%}" if ok else f"NOT within {rtol:.0%}"
    return RetrainCheck(ok, f"{label}: retrained on {where} (weights differ by {weights_diff:.3g}); {said}: {rule}")


def compare_retrain(shipped: Result, fresh: Result, n_rollouts: int = 5, rtol: float = OUTCOME_RTOL) -> RetrainCheck:
    """Is ``fresh`` (a retrain from scratch) the shipped training run again? See :func:`retrain_verdict`.

    Across platforms both final policies are also tested on the unperturbed task (``n_rollouts`` testing
    seeds, the same for both) and their mean returns compared.
    """
    same = same_platform(shipped)
    diff = max_abs_diff(shipped, fresh)
    test = None
    if diff > WEIGHTS_ATOL and not same:
        from thesis_repro.evaluation import evaluate  # local: the listing stays importable without the envs
        from thesis_repro.learners import load_policy

        cfg = shipped_job(shipped.path).config
        env, steps = cfg["env"], cfg.get("max_episode_steps") or 1000
        a, b = (
            float(evaluate(load_policy(r), env, "none", [0.0], n_rollouts, max_episode_steps=steps).mean())
            for r in (shipped, fresh)
        )
        test = (a, b)
    train = (float(shipped["train_return"]), float(fresh["train_return"]))
    return retrain_verdict(shipped.path.name.rsplit("__", 1)[0], same, diff, train, test, rtol)
