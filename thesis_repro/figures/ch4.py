"""Chapter 4, Figures 4.1-4.7 (kl_avg, kl_exact vs params_avg, joint): job grids, tidy frames and verdicts.

Every figure trains the thesis's kl_avg (Eq 4.11) and our kl_exact (the exact Eq 4.7 minimiser, issue 12)
beside the baselines params_avg and joint, and ends with one verdict per claim for EACH of the two
aggregates, judged against params_avg and joint only (:data:`JUDGED`, :data:`BASELINES`).

Training runs are ``train`` jobs of :func:`thesis_repro.learners.train_config` built by :func:`run_config`
from a figure's settings; the config depends only on the run's identity (algorithm, condition, seed) and the
budget keys of the settings, so figures with the same settings (4.1, 4.3, 4.5, 4.6) share one cached run.
Evaluations are cached jobs too: wind sweeps, mass × friction grids and observation/action-noise sweeps of
the deterministic (mean-action) policy under testing seeds.

>>> conditions("4.1")[0]
{'panel': 'a', 'c_a': 0.001, 'wind': [-0.5, 0.5]}
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro import reference, report
from thesis_repro.backends import run_jobs
from thesis_repro.cache import Job
from thesis_repro.envs import make_env
from thesis_repro.evaluation.metrics import auc
from thesis_repro.figures import budget_note, register
from thesis_repro.learners import iteration_steps, load_policy, n_iterations, train_config
from thesis_repro.validation import check_choice

EVAL_KINDS: tuple[str, ...] = ("wind", "shift", "obs", "act")
#: The thesis's spelling of the learners (figures, tables and verdicts show these names; configs use the ids).
THESIS_NAMES: dict[str, str] = {"kl-avg": "kl_avg", "params-avg": "params_avg", "kl-exact": "kl_exact"}
#: The thesis's method (the claims of chapter 4 are about it), as figures name it.
OURS = "kl_avg"
#: The aggregates whose claims each figure judges: the thesis's kl_avg and the exact Eq 4.7 minimiser (issue 12).
JUDGED: tuple[str, ...] = ("kl_avg", "kl_exact")
#: What a judged aggregate is compared with (the thesis's baselines); the other aggregate is never a baseline.
BASELINES: tuple[str, ...] = ("params_avg", "joint")


# ---------------------------------------------------------------- conditions, configs, runs
def conditions(figure: str, panels: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """Training conditions (panel, c_a, wind range) of a chapter-4 figure, from the thesis table.

    ``panels`` keeps only those panels (ignored for single-panel figures); ``None`` keeps all.
    """
    rows = reference.load("chapter4_conditions")
    rows = rows[rows["figure"] == figure]
    if rows.empty:
        raise ValueError(f"no chapter-4 conditions for figure {figure!r}")
    if panels is not None and len(rows) > 1:
        for p in panels:
            check_choice(p, list(rows["panel"]), f"panel of figure {figure}")
        rows = rows[rows["panel"].isin(list(panels))]
    return [
        {"panel": r.panel, "c_a": float(r.action_penalty), "wind": [float(r.wind_low), float(r.wind_high)]}
        for r in rows.itertuples()
    ]


def label(cond: Mapping[str, Any]) -> str:
    """Panel title such as ``"c_a=0.001, ξ~U(-0.5,0.5)"``."""
    return f"c_a={cond['c_a']:g}, ξ~U({cond['wind'][0]:g},{cond['wind'][1]:g})"


def run_config(settings: Mapping[str, Any], algo: str, cond: Mapping[str, Any], seed: int) -> dict[str, Any]:
    """The training config of one run; depends only on the run's identity and the budget keys of ``settings``."""
    # one env per domain: n_envs = N domains, n_steps = T steps per domain (learners.multidomain)
    extra = {k: settings[s] for k, s in (("n_envs", "n_domains"), ("n_steps", "steps_per_domain")) if s in settings}
    return train_config(
        algo,
        settings["env"],
        seed,
        int(settings["timesteps"]),
        c_a=cond["c_a"],
        wind=list(cond["wind"]),
        max_episode_steps=settings["max_episode_steps"],
        protocol=settings["protocol"],
        **extra,
    )


def algo_names(settings: Mapping[str, Any]) -> list[str]:
    """The thesis's names of the figure's learners, in the settings' order (hue order of the plots).

    >>> algo_names({"algos": ["kl-avg", "params-avg", "joint"]})
    ['kl_avg', 'params_avg', 'joint']
    """
    return [THESIS_NAMES.get(a, a) for a in settings["algos"]]


def runs(settings: Mapping[str, Any]) -> pd.DataFrame:
    """One row per (condition, algo, seed) of a figure: ``algo`` (thesis name), ``panel``, ``condition``,
    ``seed``, ``config``."""
    rows = []
    for cond in conditions(settings["figure"], settings["panels"]):
        for algo in settings["algos"]:
            for seed in range(int(settings["train_seeds"])):
                rows.append(
                    {
                        "algo": THESIS_NAMES.get(algo, algo),
                        "panel": cond["panel"],
                        "condition": label(cond),
                        "seed": seed,
                        "config": run_config(settings, algo, cond, seed),
                    }
                )
    return pd.DataFrame(rows)


def train_runs(settings: Mapping[str, Any], n_jobs: int | None = None) -> pd.DataFrame:
    """Train (or load) every run of :func:`runs`; adds the cached ``result`` column."""
    table = runs(settings)
    table["result"] = run_jobs([Job("train", c) for c in table["config"]], n_jobs=n_jobs, desc="ch4 training")
    return table


def curves_frame(runs: pd.DataFrame) -> pd.DataFrame:
    """Long frame of training curves: one row per (run, iteration) with return, length, entropy, mean KL."""
    parts = []
    for row in runs.itertuples():
        r = row.result
        n = len(r["curve_timesteps"])
        kl = np.asarray(r["curve_kl"], dtype=float) if "curve_kl" in r else np.full((n, 1), np.nan)
        parts.append(
            pd.DataFrame(
                {
                    "algo": row.algo,
                    "panel": row.panel,
                    "condition": row.condition,
                    "seed": row.seed,
                    "iteration": np.asarray(r["curve_timesteps"]) // iteration_steps(row.config),
                    "timesteps": r["curve_timesteps"],
                    "return": r["curve_return"],
                    "length": r["curve_length"],
                    "entropy": r["curve_entropy"],
                    "kl_to_aggregate": np.nanmean(kl, axis=1) if np.isfinite(kl).any() else np.full(len(kl), np.nan),
                }
            )
        )
    return pd.concat(parts, ignore_index=True)


# ---------------------------------------------------------------- evaluations
def mass_friction_grid(settings: Mapping[str, Any]) -> list[dict[str, float]]:
    """The ``{"body_mass": m, "friction": f}`` ratio settings of a heat map (mass × friction of the settings)."""
    return [
        {"body_mass": float(m), "friction": float(f)}
        for m, f in itertools.product(settings["mass_ratios"], settings["friction_ratios"])
    ]


def eval_jobs(runs: pd.DataFrame, kind: str, values: Iterable[Any], n_rollouts: int, seed: int = 0) -> list[Job]:
    """One evaluation job per run of ``runs`` under ``kind`` (wind | shift | obs | act) over ``values``."""
    check_choice(kind, EVAL_KINDS, "evaluation kind")
    values = list(values)
    if kind in ("obs", "act"):
        points: dict[str, Any] = {"perturbation": kind, "sigmas": [float(v) for v in values]}
    else:  # fixed wind ξ per point, or mass × friction ratios (no wind)
        points = {"perturbation": "none", "ratios": [{"wind": float(v)} if kind == "wind" else dict(v) for v in values]}
    return [
        Job(
            "evaluate",
            {
                "train": row.config,
                "test": {
                    **points,
                    "n_rollouts": int(n_rollouts),
                    "seed": int(seed),
                    "max_episode_steps": int(row.config["max_episode_steps"] or 1000),
                    "c_a": row.config["c_a"],
                },
            },
        )
        for row in runs.itertuples()
    ]


def evaluate_runs(
    runs: pd.DataFrame, kind: str, values: Iterable[Any], n_rollouts: int, seed: int = 0, n_jobs: int | None = None
) -> pd.DataFrame:
    """Evaluate every run of ``runs`` under ``kind``; long frame with one row per (run, value) (mean return)."""
    values = list(values)
    results = run_jobs(eval_jobs(runs, kind, values, n_rollouts, seed), n_jobs=n_jobs, desc=f"ch4 eval {kind}")
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


# ---------------------------------------------------------------- job grids of the figures
def _values(kind: str, settings: Mapping[str, Any]) -> list[Any]:
    """The evaluation grid of ``kind`` from a figure's settings (``wind0``: wind off, Fig 4.2)."""
    if kind == "shift":
        return mass_friction_grid(settings)
    return {"wind": settings["winds"], "wind0": [0.0], "obs": settings["sigmas"], "act": settings["sigmas"]}[kind]


def _grid(*evals: str) -> Any:
    """Job grid: every training job, then for each kind of ``evals`` one evaluation job per run."""

    def grid(settings: Mapping[str, Any]) -> list[Job]:
        table = runs(settings)
        jobs = [Job("train", c) for c in table["config"]]
        for kind in evals:
            jobs += eval_jobs(table, kind.removesuffix("0"), _values(kind, settings), settings["test_rollouts"])
        return jobs

    return grid


_TRAIN = ("train",)
_BOTH = ("train", "evaluate")
register("4.1", "Training curves of kl_avg, kl_exact, params_avg and joint under four conditions", _TRAIN)(_grid())
register("4.2", "Key frames of a walking cycle, kl_avg and kl_exact vs params_avg", _BOTH)(_grid("wind0"))
register("4.3", "Walker2d testing return vs wind speed", _BOTH)(_grid("wind"))
register("4.4", "Hopper: testing return vs wind; mass × friction heat maps", _BOTH)(_grid("wind", "shift"))
register("4.5", "Walker2d testing return over mass × friction", _BOTH)(_grid("shift"))
register("4.6", "Testing return vs observation- and action-noise scale", _BOTH)(_grid("obs", "act"))
register("4.7", "Policy entropy during training", _TRAIN)(_grid())


# ---------------------------------------------------------------- tables behind the verdicts
def compare(frame: pd.DataFrame, value: str, by: Sequence[str] = ("panel",), ours: str = OURS) -> pd.DataFrame:
    """Mean of ``value`` per (by..., algo), the best algorithm of each group and whether it is ``ours``.

    The algorithm columns are the frame's ``algo`` values; ``best`` and ``<ours>_best`` are added.
    """
    table = frame.groupby([*by, "algo"])[value].mean().unstack("algo")
    table.columns.name = None
    algos = list(table.columns)
    table["best"] = table[algos].idxmax(axis=1)
    table[f"{ours}_best"] = table["best"] == ours
    return table


def late_returns(curves: pd.DataFrame) -> pd.DataFrame:
    """Fig 4.1: mean training return over the last third of the iterations, per panel and algorithm."""
    n_it = int(curves["iteration"].max())
    return compare(curves[curves["iteration"] > n_it - max(1, n_it // 3)], "return")


def off_centre(heat: pd.DataFrame) -> pd.DataFrame:
    """Heat-map rows except the training dynamics (mass = friction = 1)."""
    return heat[~(np.isclose(heat["mass"], 1.0) & np.isclose(heat["friction"], 1.0))]


def noise_aucs(noise: pd.DataFrame) -> pd.DataFrame:
    """Fig 4.6: AUC (Eq 3.6) of the seed-mean return over σ, per noise type, panel and algorithm."""
    curve = noise.groupby(["noise", "panel", "algo", "value"])["return"].mean().reset_index()
    rows = []
    for (kind, panel, algo), g in curve.groupby(["noise", "panel", "algo"]):
        g = g.sort_values("value")
        rows.append(
            {
                "noise": kind,
                "panel": panel,
                "algo": algo,
                "auc": float(auc(g["return"].to_numpy(), g["value"].tolist())),
            }
        )
    return pd.DataFrame(rows)


def best_seeds(runs: pd.DataFrame, last: int = 3) -> pd.DataFrame:
    """Fig 4.2: per algorithm, the run with the best mean return over its ``last`` iterations (index: algo)."""
    runs = runs.copy()
    runs["final_return"] = [
        float(np.nanmean(r["curve_return"][-last:])) if np.isfinite(r["curve_return"]).any() else -np.inf
        for r in runs["result"]
    ]
    return runs.loc[runs.groupby("algo")["final_return"].idxmax()].set_index("algo")


# ---------------------------------------------------------------- verdicts
def judged(settings_or_algos: Mapping[str, Any] | Sequence[str]) -> list[str]:
    """The aggregates whose claims a figure judges (thesis names, in :data:`JUDGED` order): those it trains.

    >>> judged(["kl-avg", "params-avg", "kl-exact", "joint"])
    ['kl_avg', 'kl_exact']
    """
    algos = settings_or_algos["algos"] if isinstance(settings_or_algos, Mapping) else settings_or_algos
    names = {THESIS_NAMES.get(a, a) for a in algos}
    return [a for a in JUDGED if a in names]


def panel_lines(
    table: pd.DataFrame, easy: Sequence[str] = (), tol: float = 0.1, what: str = "mean return", ours: str = OURS
) -> tuple[list[str], list[bool]]:
    """Per panel of a higher-is-better ``table`` (from :func:`compare`): a sentence and whether the claim holds.

    The claim: ``ours`` is similar (within ``tol`` relative to the best baseline) in the ``easy`` panels and
    strictly better than every baseline in the others. The baselines are :data:`BASELINES` (params_avg,
    joint) present in the table, never the other aggregate of :data:`JUDGED`: kl_avg and kl_exact are each
    judged against params_avg and joint only.
    """
    check_choice(ours, JUDGED, "judged aggregate")
    if ours not in table.columns:
        raise ValueError(f"the table has no column {ours!r}; its columns are {list(table.columns)}")
    baselines = [b for b in BASELINES if b in table.columns]
    if not baselines:
        raise ValueError(f"the table has no baseline column ({', '.join(BASELINES)}); columns: {list(table.columns)}")
    lines, holds = [], []
    for panel, row in table.iterrows():
        best_name = max(baselines, key=lambda b: float(row[b]))
        base = float(row[best_name])
        mine = float(row[ours])
        if panel in easy:
            good = mine >= base - tol * max(abs(base), 1e-9)
            word, thesis = ("similar or better" if good else "worse"), "similar"
        else:
            good = mine > base
            word, thesis = ("better" if good else "not better"), "better"
        lines.append(
            f"panel {panel}: {ours} {what} {mine:.3g} vs best baseline ({best_name}) {base:.3g} -> {word}"
            f" (thesis: {thesis})"
        )
        holds.append(bool(good))
    return lines, holds


def caveat(settings: Mapping[str, Any]) -> str:
    """The honest fine print of a chapter-4 run: budget in env steps and iterations vs the thesis's, seeds."""
    cfg = runs(settings)["config"].iloc[0]
    text = budget_note(settings, extra=f"{n_iterations(cfg)} iteration(s) of {iteration_steps(cfg):,} steps")
    if int(settings["train_seeds"]) < 3:
        text += " With so few seeds there are no error bars: small differences are not evidence either way."
    return text


def claim_verdict(
    figure: str,
    claim: str,
    table: pd.DataFrame,
    settings: Mapping[str, Any],
    easy: Sequence[str] = (),
    what: str = "mean return",
    tol: float = 0.1,
    ours: str = OURS,
) -> report.Verdict:
    """One :class:`~thesis_repro.report.Verdict` for an ``ours``-vs-baselines claim judged panel by panel.

    ``claim`` may hold ``{ours}`` (filled with the judged aggregate's name).
    """
    lines, holds = panel_lines(table, easy, tol, what, ours=ours)
    status = report.status(all(holds), settings["scale"], partly=any(holds))
    evidence = "reproduced: " + "; ".join(lines) + ". " + caveat(settings)
    return report.Verdict(figure, claim.format(ours=_who(ours)), status, evidence)


def _who(ours: str) -> str:
    """How a claim names the judged aggregate: the thesis's kl_avg, or kl_exact marked as ours."""
    return ours if ours == OURS else f"{ours} (ours: the exact Eq 4.7 minimiser, not in the thesis)"


def _each(
    figure: str,
    claim: str,
    table: pd.DataFrame,
    settings: Mapping[str, Any],
    easy: Sequence[str] = (),
    what: str = "mean return",
) -> list[report.Verdict]:
    """One :func:`claim_verdict` per aggregate of :func:`judged` (kl_avg, then kl_exact) on the same table."""
    return [claim_verdict(figure, claim, table, settings, easy, what, ours=a) for a in judged(settings)]


def verdict_4_1(curves: pd.DataFrame, settings: Mapping[str, Any]) -> list[report.Verdict]:
    """Fig 4.1: kl_avg (and kl_exact) learns as well in the easy condition (a) and better in the harder ones."""
    claim = "{ours} learns like the baselines in the easy condition (a) and better in the harder ones"
    return _each("4.1", claim, late_returns(curves), settings, easy=("a",), what="late training return")


def verdict_4_2(returns: pd.Series, settings: Mapping[str, Any]) -> list[report.Verdict]:
    """Fig 4.2 (visual gait claim): the measurable proxy, testing return at ξ = 0 of the best seeds.

    The figure compares the aggregates with params_avg only (the thesis's two walking cycles).
    """
    out = []
    base = float(returns["params_avg"])
    for ours in judged(settings):
        mine = float(returns[ours])
        evidence = (
            f"reproduced testing return at ξ = 0 of the best seeds: {ours} {mine:.1f}, params_avg {base:.1f}; "
            f"naturalness itself is visual (see the key frames). {caveat(settings)}"
        )
        claim = f"{_who(ours)}'s gait is more natural than params_avg's (proxy: higher testing return at ξ = 0)"
        out.append(report.Verdict("4.2", claim, report.status(mine >= base, settings["scale"]), evidence))
    return out


def verdict_4_3(wind: pd.DataFrame, settings: Mapping[str, Any]) -> list[report.Verdict]:
    """Fig 4.3: kl_avg (and kl_exact) extrapolates better over unseen wind speeds when training is harder."""
    claim = "{ours} is competitive in the easy condition (a) and more robust to unseen winds in the harder ones"
    return _each("4.3", claim, compare(wind, "return"), settings, easy=("a",), what="mean testing return over winds")


def verdict_4_4(wind: pd.DataFrame, heat: pd.DataFrame, settings: Mapping[str, Any]) -> list[report.Verdict]:
    """Fig 4.4 (Hopper): kl_avg (and kl_exact) degrades less under unseen winds (a) and mass/friction (b)."""
    return [
        *_each(
            "4.4",
            "(a) On Hopper {ours} is the most robust to unseen wind speeds",
            compare(wind, "return"),
            settings,
            what="mean return over winds",
        ),
        *_each(
            "4.4",
            "(b) On Hopper {ours} is the most robust to mass × friction changes",
            compare(off_centre(heat), "return"),
            settings,
            what="mean off-centre return",
        ),
    ]


def verdict_4_5(heat: pd.DataFrame, settings: Mapping[str, Any]) -> list[report.Verdict]:
    """Fig 4.5: kl_avg (and kl_exact) stays robust over a wide range of mass × friction (off-centre mean)."""
    claim = "{ours} is the most robust to unseen mass × friction combinations in every condition"
    return _each("4.5", claim, compare(off_centre(heat), "return"), settings, what="mean off-centre return")


def verdict_4_6(aucs: pd.DataFrame, settings: Mapping[str, Any]) -> list[report.Verdict]:
    """Fig 4.6: kl_avg's (and kl_exact's) testing return degrades more slowly under obs/act noise (AUC)."""
    return [
        v
        for kind in ("obs", "act")
        for v in _each(
            "4.6",
            f"{{ours}} degrades more slowly than the baselines under {kind} noise (higher AUC, Eq 3.6)",
            compare(aucs[aucs["noise"] == kind], "auc"),
            settings,
            what=f"{kind}-noise AUC",
        )
    ]


def verdict_4_7(curves: pd.DataFrame, settings: Mapping[str, Any]) -> list[report.Verdict]:
    """Fig 4.7: kl_avg (and kl_exact) keeps the highest policy entropy (final iteration).

    The thesis reads the higher entropy as a benefit (a "soft entropy regularisation"). A policy whose
    log-std grows because it stopped learning also has a high entropy, so each verdict's evidence adds the
    aggregate's late training return (:func:`late_returns`) beside the best baseline's and says so when it
    is lower: the literal claim is judged, the context is printed.
    """
    final = curves[curves["iteration"] == curves["iteration"].max()]
    claim = "{ours} keeps a higher policy entropy than params_avg and joint"
    verdicts = _each("4.7", claim, compare(final, "entropy"), settings, what="final entropy")
    late = late_returns(curves).iloc[0]
    base = max(BASELINES, key=lambda b: late.get(b, -np.inf))
    out = []
    for v, ours in zip(verdicts, judged(settings), strict=True):
        mine, best = float(late[ours]), float(late[base])
        note = f" Context: late training return {ours} {mine:,.0f} vs {base} {best:,.0f}"
        if mine < best:
            note += f"; {ours}'s higher entropy comes with a policy that learns less, so it is not a sign of"
            note += " better learning here."
        else:
            note += "."
        out.append(dataclasses.replace(v, evidence=v.evidence + note))
    return out


# ---------------------------------------------------------------- Figure 4.2: rendering
#: Offscreen rendering of Fig 4.2. Gymnasium 1.4 renders Walker2d/Hopper with a FREE camera whose
#: ``trackbodyid`` has no effect, so a walker leaves the frame after a few metres; the models' own
#: ``track`` camera (mode ``trackcom``) follows the centre of mass, as the thesis's frames do.
RENDER: dict[str, Any] = {"render_mode": "rgb_array", "width": 480, "height": 320, "camera_name": "track"}


def render_cycle(
    run_result: Any, env: str, c_a: float, n_frames: int = 5, steps: int = 300, seed: int = 0
) -> tuple[list[np.ndarray], list[int]]:
    """Key frames of one gait cycle of the trained policy at ξ = 0, rendered offscreen (``MUJOCO_GL``).

    The cycle period is the dominant period of the thigh-joint angle (FFT) over ``steps`` steps; the
    frames are ``n_frames`` evenly spaced steps of the last full cycle (fallback: of the whole episode).
    The camera follows the walker (:data:`RENDER`).
    """
    policy = load_policy(run_result)
    e = make_env(env, ratios={"wind": 0.0}, c_a=c_a, max_episode_steps=steps, env_kwargs=RENDER)
    obs, _ = e.reset(seed=seed)
    frames, angles = [e.render()], [float(obs[2])]
    for _ in range(steps):
        obs, _, term, trunc, _ = e.step(policy(obs[None])[0])
        frames.append(e.render())
        angles.append(float(obs[2]))
        if term or trunc:
            break
    e.close()
    idx = cycle_frames(np.asarray(angles), n_frames)
    return [frames[i] for i in idx], idx


def cycle_frames(angles: np.ndarray, n_frames: int) -> list[int]:
    """Indices of ``n_frames`` evenly spaced steps over the last full period of ``angles`` (FFT period).

    >>> t = np.arange(101)
    >>> cycle_frames(np.sin(2 * np.pi * t / 20), 5)
    [80, 85, 90, 95, 100]
    """
    n = len(angles)
    period = n
    if n >= 16:
        a = np.asarray(angles, float) - np.mean(angles)
        spec = np.abs(np.fft.rfft(a))
        freqs = np.fft.rfftfreq(n)
        k = int(np.argmax(spec[1:]) + 1)
        period = int(round(1.0 / freqs[k])) if freqs[k] > 0 else n
    period = max(min(period, n - 1), n_frames)
    start = max(n - 1 - period, 0)
    return np.linspace(start, min(start + period, n - 1), n_frames).round().astype(int).tolist()
