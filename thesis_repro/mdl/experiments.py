"""Chapter-4 experiment plumbing shared by the ``fig-4.x`` notebooks: run-cache jobs, tidy frames, verdicts.

Training runs are ``Job("thesis_repro.mdl.train:train_job", cfg)`` built by :func:`run_config` from a
figure's settings, so notebooks that use the same (algorithm, condition, seed, budget) share one cached
run. Evaluations are cached jobs too (:func:`evaluate_job`): wind sweeps, mass × friction grids and
observation/action-noise sweeps of the deterministic (mean-action) policy, under testing seeds.

>>> conditions("4.1")[0]
{'panel': 'a', 'c_a': 0.001, 'wind': [-0.5, 0.5]}
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro import reference
from thesis_repro.cache import Job, RunCache, run_jobs
from thesis_repro.mdl.config import mdl_config

TRAIN_FN = "thesis_repro.mdl.train:train_job"
EVAL_FN = "thesis_repro.mdl.experiments:evaluate_job"
EVAL_KINDS: tuple[str, ...] = ("wind", "shift", "obs", "act")


def conditions(figure: str, panels: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """Training conditions (panel, c_a, wind range) of a chapter-4 figure, from the thesis table.

    ``panels`` keeps only those panels (ignored for single-panel figures); ``None`` keeps all.
    """
    rows = reference.load("chapter4_conditions")
    rows = rows[rows["figure"] == figure]
    if rows.empty:
        raise ValueError(f"no chapter-4 conditions for figure {figure!r}")
    if panels is not None and len(rows) > 1:
        unknown = sorted(set(panels) - set(rows["panel"]))
        if unknown:
            raise ValueError(f"unknown panels {unknown} of figure {figure}; valid panels are: {list(rows['panel'])}")
        rows = rows[rows["panel"].isin(list(panels))]
    return [
        {"panel": r.panel, "c_a": float(r.action_penalty), "wind": [float(r.wind_low), float(r.wind_high)]}
        for r in rows.itertuples()
    ]


def label(cond: dict[str, Any]) -> str:
    """Panel title such as ``"c_a=0.001, ξ~U(-0.5,0.5)"``."""
    return f"c_a={cond['c_a']:g}, ξ~U({cond['wind'][0]:g},{cond['wind'][1]:g})"


def run_config(settings: dict[str, Any], algo: str, cond: dict[str, Any], seed: int, env: str | None = None):
    """The training config of one run; depends only on the run's identity and the budget keys of ``settings``."""
    extra = {k: settings[k] for k in ("n_domains", "steps_per_domain") if k in settings}
    return mdl_config(
        algo,
        env or settings["env"],
        seed,
        int(settings["timesteps"]),
        c_a=cond["c_a"],
        wind=list(cond["wind"]),
        max_episode_steps=settings["max_episode_steps"],
        **extra,
    )


def train_runs(
    settings: dict[str, Any],
    algos: Sequence[str],
    conds: Sequence[dict[str, Any]],
    env: str | None = None,
    n_jobs: int | None = None,
) -> pd.DataFrame:
    """Train (or load) every (algo, condition, seed); one row per run with its config and cached result."""
    keys, jobs = [], []
    for cond in conds:
        for algo in algos:
            for seed in range(int(settings["train_seeds"])):
                keys.append({"algo": algo, "panel": cond["panel"], "condition": label(cond), "seed": seed})
                jobs.append(Job(TRAIN_FN, run_config(settings, algo, cond, seed, env)))
    results = run_jobs(jobs, n_jobs=n_jobs, desc="mdl training")
    return pd.DataFrame([{**k, "config": j.config, "result": r} for k, j, r in zip(keys, jobs, results, strict=True)])


def curves_frame(runs: pd.DataFrame) -> pd.DataFrame:
    """Long frame of training curves: one row per (run, iteration) with return, length, entropy, mean KL."""
    parts = []
    for row in runs.itertuples():
        r = row.result
        kl = np.asarray(r["kl"], dtype=float)
        parts.append(
            pd.DataFrame(
                {
                    "algo": row.algo,
                    "panel": row.panel,
                    "condition": row.condition,
                    "seed": row.seed,
                    "iteration": r["iteration"],
                    "timesteps": r["timesteps"],
                    "return": r["ep_return"],
                    "length": r["ep_length"],
                    "entropy": r["entropy"],
                    "kl_to_aggregate": np.nanmean(kl, axis=1) if np.isfinite(kl).any() else np.full(len(kl), np.nan),
                }
            )
        )
    return pd.concat(parts, ignore_index=True)


def evaluate_job(config: dict[str, Any], workdir: Path) -> dict[str, Any]:
    """Run-cache job: testing returns ``(len(values), n_rollouts)`` of a trained run under one kind of shift.

    ``config = {"train": <train config>, "kind": wind|shift|obs|act, "values": [...], "n_rollouts": n,
    "seed": s, "c_a": c}``; "shift" values are ``{"body_mass": r, "friction": r}`` dicts (no wind).
    """
    from thesis_repro.evaluation.evaluator import BatchedEvaluator, test_seeds
    from thesis_repro.mdl.envs import make_mdl_env
    from thesis_repro.mdl.train import load_policy

    trained = RunCache().run(Job(TRAIN_FN, config["train"]))
    policy = load_policy(trained)
    train = config["train"]
    base = {"env": train["env"], "c_a": config["c_a"], "max_episode_steps": train["max_episode_steps"] or 1000}
    kind = config["kind"]
    if kind not in EVAL_KINDS:
        raise ValueError(f"unknown evaluation kind {kind!r}; valid kinds are: {EVAL_KINDS}")
    conds = []
    for v in config["values"]:
        if kind == "wind":
            conds.append({**base, "wind": float(v)})
        elif kind == "shift":
            conds.append({**base, "ratios": dict(v)})
        else:
            conds.append({**base, "perturbation": kind, "sigma": float(v)})
    ev = BatchedEvaluator(policy, lambda **c: make_mdl_env(**c), n_envs=16, max_episode_steps=base["max_episode_steps"])
    out = ev.run(conds, test_seeds(int(config["seed"]), int(config["n_rollouts"])))
    return {"returns": out.returns, "lengths": out.lengths}


def evaluate_runs(
    runs: pd.DataFrame, kind: str, values: Iterable[Any], n_rollouts: int, seed: int = 0, n_jobs: int | None = None
) -> pd.DataFrame:
    """Evaluate every run of ``runs`` under ``kind``; long frame with one row per (run, value) (mean return)."""
    values = list(values)
    jobs = [
        Job(
            EVAL_FN,
            {
                "train": row.config,
                "kind": kind,
                "values": values,
                "n_rollouts": int(n_rollouts),
                "seed": seed,
                "c_a": row.config["c_a"],
            },
        )
        for row in runs.itertuples()
    ]
    results = run_jobs(jobs, n_jobs=n_jobs, desc=f"mdl eval {kind}")
    rows = []
    for row, res in zip(runs.itertuples(), results, strict=True):
        for v, ret in zip(values, np.asarray(res["returns"]), strict=True):
            item = {
                "algo": row.algo,
                "panel": row.panel,
                "condition": row.condition,
                "seed": row.seed,
                "return": float(np.mean(ret)),
            }
            if kind == "shift":
                item.update(mass=float(v["body_mass"]), friction=float(v["friction"]))
            else:
                item["value"] = float(v)
            rows.append(item)
    return pd.DataFrame(rows)


def compare(frame: pd.DataFrame, value: str, by: Sequence[str] = ("panel",), ours: str = "kl_avg") -> pd.DataFrame:
    """Mean of ``value`` per (by..., algo) and whether ``ours`` is the best algorithm in each group."""
    table = frame.groupby([*by, "algo"])[value].mean().unstack("algo")
    table["best"] = table.idxmax(axis=1)
    table[f"{ours}_best"] = table["best"] == ours
    return table


def render_cycle(
    run_result: Any, env: str, c_a: float, n_frames: int = 5, steps: int = 300, seed: int = 0
) -> tuple[list[np.ndarray], list[int]]:
    """Key frames of one gait cycle of the trained policy at ξ = 0, rendered offscreen (MUJOCO_GL=egl).

    The cycle period is the dominant period of the thigh-joint angle (FFT) over ``steps`` steps; the
    frames are ``n_frames`` evenly spaced steps of the last full cycle (fallback: of the whole episode).
    """
    os.environ.setdefault("MUJOCO_GL", "egl")
    from thesis_repro.mdl.envs import make_mdl_env
    from thesis_repro.mdl.train import load_policy

    policy = load_policy(run_result)
    e = make_mdl_env(env, c_a=c_a, wind=0.0, max_episode_steps=steps, render_mode="rgb_array")
    obs, _ = e.reset(seed=seed)
    frames, angles = [e.render()], [float(obs[2])]
    for _ in range(steps):
        obs, _, term, trunc, _ = e.step(policy(obs[None])[0])
        frames.append(e.render())
        angles.append(float(obs[2]))
        if term or trunc:
            break
    e.close()
    n = len(angles)
    period = n
    if n >= 16:
        a = np.asarray(angles) - np.mean(angles)
        spec = np.abs(np.fft.rfft(a))
        freqs = np.fft.rfftfreq(n)
        k = int(np.argmax(spec[1:]) + 1)
        period = int(round(1.0 / freqs[k])) if freqs[k] > 0 else n
    period = max(min(period, n - 1), n_frames)
    start = max(n - 1 - period, 0)
    idx = np.linspace(start, min(start + period, n - 1), n_frames).round().astype(int).tolist()
    return [frames[i] for i in idx], idx


def verdict(
    table: pd.DataFrame, ours: str = "kl_avg", easy: Sequence[str] = ("a",), tol: float = 0.1, what: str = "mean return"
) -> tuple[list[str], bool]:
    """Sentences on the thesis's chapter-4 claim for a per-panel table of a higher-is-better metric.

    Claim: ``ours`` is similar (within ``tol`` relative to the best baseline) in the ``easy`` panels and
    strictly better than every baseline in the others. Returns (one sentence per panel, claim holds).
    """
    lines, ok = [], True
    for panel, row in table.iterrows():
        algos = [c for c in row.index if c not in ("best", f"{ours}_best")]
        base = max(float(row[a]) for a in algos if a != ours)
        mine = float(row[ours])
        scale = max(abs(base), 1e-9)
        if panel in easy:
            good = mine >= base - tol * scale
            word = "similar or better" if good else "worse"
            lines.append(
                f"panel {panel}: {ours} {what} {mine:.3g} vs best baseline {base:.3g} -> {word} (thesis: similar)"
            )
        else:
            good = mine > base
            lines.append(
                f"panel {panel}: {ours} {what} {mine:.3g} vs best baseline {base:.3g} -> "
                f"{'better' if good else 'not better'} (thesis: better)"
            )
        ok &= good
    return lines, ok


def caveat(settings: dict[str, Any]) -> str:
    """The honest fine print of a run: budget vs the thesis's, and seeds."""
    it = int(settings["timesteps"]) // (int(settings.get("n_domains", 4)) * int(settings.get("steps_per_domain", 1024)))
    text = (
        f"Scale {settings['scale']}: {int(settings['timesteps'])} env steps (~{it} iterations) per run vs 4e6 in the "
        f"thesis, {settings['train_seeds']} training seed(s) vs 6."
    )
    if int(settings["train_seeds"]) < 3:
        text += " With so few seeds there are no error bars: small differences are not evidence either way."
    return text
