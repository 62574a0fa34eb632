"""Your agent under the thesis's protocol: beside the shipped learners, and single runs in rl-baselines3-zoo's shape.

* :func:`compare_with_shipped`: a :func:`~thesis_repro.evaluation.score.score_model` result beside every learner
  the kit ships (or has cached) on the same task, scale, σ grid and testing seeds: a table of AUCs with 95 % CIs
  across training seeds, and a Fig 3.4-style figure (testing return vs σ per test type, CI bands).
* :func:`train_run`: one chapter-3 training run (learner, task, seed, scale) through the run cache, the same
  job the book trains or loads (``python -m thesis_repro train ppo Hopper --seed 0 --scale small``).
* :func:`enjoy`: one episode of a shipped or cached policy, optionally perturbed, rendered offscreen to a video
  (``python -m thesis_repro enjoy ppo Hopper --seed 0 --test obs --sigma 0.4 --video out.mp4``).
* :func:`load_sb3`: an SB3 ``.zip`` as a model (``python -m thesis_repro score model.zip --task Hopper``).

:data:`README_EXAMPLE` is the README's five lines (``tests/test_agent.py`` runs them as written).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro.cache import Job, Result, RunCache
from thesis_repro.envs import ENVS, TESTS, make_env, short_name
from thesis_repro.evaluation import tables
from thesis_repro.evaluation.score import Scores, book_grid, score_model
from thesis_repro.validation import check_choice, check_nonneg

#: Your agent beside the shipped learners in five lines (the README's "use it on your own agent").
README_EXAMPLE = """\
from stable_baselines3 import PPO
from thesis_repro.agent import compare_with_shipped, score_model
model = PPO("MlpPolicy", "InvertedPendulum-v5", seed=0).learn(2048)
scores = score_model(model, "InvertedPendulum", scale="small")  # the book's σ grid, rollouts and testing seeds
print(scores, compare_with_shipped(scores), sep="\\n\\n")  # AUCs with 95 % CIs beside every shipped learner
"""

#: The chapter-3 items whose learners the comparison and the single-run commands draw on (first match wins).
ITEMS: tuple[str, ...] = ("table-3.4", "table-3.5", "table-3.6", "table-3.7", "3.3")


def _item_settings(item: str, scale: str) -> dict[str, Any]:
    from thesis_repro.figures import ch3_tables

    return ch3_tables.settings(item, scale)


def _learners(task: str, scale: str) -> dict[str, dict[str, Any]]:
    """Learner -> the settings of the first chapter-3 item that runs it on ``task`` at ``scale``."""
    from thesis_repro.figures import ch3_tables

    out: dict[str, dict[str, Any]] = {}
    for item in ITEMS:
        s = _item_settings(item, scale)
        if task not in ch3_tables.item_envs(s):
            continue
        for a in ch3_tables.learners(s):
            out.setdefault(a, s)
    return out


def _benchmark(settings: dict[str, Any], algo: str, task: str, seeds: Sequence[int]) -> Any:
    from thesis_repro.figures import ch3, ch3_tables

    return ch3.benchmark(
        [algo],
        [task],
        list(seeds),
        ch3.learner_timesteps(settings, algo),
        settings["tests"],
        sigmas=settings["sigmas"],
        n_rollouts=int(settings["test_rollouts"]),
        max_episode_steps=int(settings["max_episode_steps"]),
        train_overrides=ch3_tables.overrides(settings, algo),
    )


#: The "Score your own agent" guide's stand-in agent per scale: SB3 PPO's training steps and the PPO settings
#: (seconds at ``smoke``; about a minute per seed at ``small``, where the learners beside it are shipped).
GUIDE_PPO: dict[str, dict[str, Any]] = {
    "smoke": {"timesteps": 256, "ppo": {"n_steps": 64, "batch_size": 32}},
    "small": {"timesteps": 20480, "ppo": {}},
    "full": {"timesteps": 20480, "ppo": {}},
}


def guide_settings(scale: str, task: str = "InvertedPendulum", timesteps: int | None = None) -> dict[str, Any]:
    """The settings of the guide page ``notebooks/guide-score-agent.py`` at ``scale``: the task's gymnasium id,
    the stand-in PPO's ``timesteps`` (``None``: :data:`GUIDE_PPO`'s) and ``ppo`` keyword arguments, and whether
    the learners beside it are computed when neither shipped nor cached (``compute_missing``: only at ``smoke``,
    seconds; at ``small`` they are the shipped runs), with a one-line ``note``.

    >>> g = guide_settings("smoke")
    >>> g["gym_id"], g["timesteps"], g["compute_missing"]
    ('InvertedPendulum-v5', 256, True)
    """
    from thesis_repro import scales

    scales.check_scale(scale)
    task = short_name(task)
    base = GUIDE_PPO[scale]
    steps = base["timesteps"] if timesteps is None else int(timesteps)
    if steps < 1:
        raise ValueError(f"timesteps must be an integer >= 1 or None, got {timesteps!r}")
    compute = scale == "smoke"
    beside = "trained now if not cached (smoke: seconds)" if compute else "the shipped (or cached) runs, none trained"
    return {
        "task": task,
        "gym_id": ENVS[task],
        "timesteps": steps,
        "ppo": dict(base["ppo"]),
        "compute_missing": compute,
        "note": f"scale {scale}: your agent = SB3 PPO, {steps:,} steps per seed on {task}; the learners beside it: "
        f"{beside}",
    }


# ---------------------------------------------------------------- comparison with the shipped learners
@dataclass
class Comparison:
    """Your agent beside the shipped learners: ``table`` (one row per test and learner: ``env, test, method,
    seed_mean, ci_lo, ci_hi, n_seeds``, the AUC across training seeds), the tidy ``returns`` behind it, what the
    intervals are (``ci_label``) and a Fig 3.4-style ``figure``; ``str()`` / :meth:`wide` give the table as text."""

    table: pd.DataFrame
    returns: pd.DataFrame
    ci_label: str
    scores: Scores
    title: str

    @cached_property
    def figure(self) -> Any:
        """The Fig 3.4-style figure (drawn on first access): testing return vs σ per test type, one line per
        learner (mean over training seeds), band the 95 % t-interval across seeds."""
        return _figure(self.returns, self.scores, self.title)

    def wide(self) -> pd.DataFrame:
        """AUC mean [95 % CI] (seeds) per learner (rows) and test (columns), as text."""
        t = self.table.assign(
            text=[tables.fmt_ci(r.seed_mean, r.ci_lo, r.ci_hi, r.n_seeds) for r in self.table.itertuples()]
        )
        return t.pivot(index="method", columns="test", values="text").reindex(
            index=list(dict.fromkeys(self.table["method"])), columns=list(dict.fromkeys(self.table["test"]))
        )

    def __str__(self) -> str:
        return f"testing AUC, {self.ci_label}\n{self.wide().to_string()}"


def shipped_results(
    task: str, scale: str = "small", cache: RunCache | None = None, *, compute_missing: bool = False
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The shipped (or locally cached) evaluations of every chapter-3 learner on ``task`` at ``scale``: tidy
    ``returns`` (``env, method, seed, test, sigma, rollout, return``) and per-rollout ``aucs`` (``env, method,
    seed, test, rollout, value``). Nothing is trained or evaluated (a learner without evaluations is left out)
    unless ``compute_missing``: then the missing runs are trained and evaluated through the run cache, the
    book's own jobs (seconds at ``smoke``; never at ``small``, whose runs are shipped)."""
    from thesis_repro.evaluation.metrics import auc

    task = short_name(task)
    cache = cache or RunCache()
    ret_parts, auc_parts = [], []
    for algo, s in _learners(task, scale).items():
        bench = _benchmark(s, algo, task, range(int(s["train_seeds"])))
        for test, jobs in bench.eval_jobs.items():
            sig = np.asarray(bench.tests[test]["sigmas"], dtype=float)
            for seed, job in zip(bench.seeds, jobs, strict=True):
                res = cache.run(job) if compute_missing else cache.load(job)
                if res is None:
                    continue
                r = np.asarray(res["returns"], dtype=float)  # (sigmas, rollouts)
                ident = {"env": task, "method": algo, "seed": seed, "test": test}
                si, ri = np.indices(r.shape).reshape(2, -1)
                ret_parts.append(pd.DataFrame({**ident, "sigma": sig[si], "rollout": ri, "return": r.reshape(-1)}))
                per = auc(r, sig, axis=0)
                auc_parts.append(pd.DataFrame({**ident, "rollout": np.arange(r.shape[1]), "value": per}))
    if not ret_parts:
        raise ValueError(
            f"no shipped or cached chapter-3 evaluations of {task} at scale {scale!r} (the kit ships scale 'small'; "
            f"score with scale='small', or run the book at {scale!r} first)"
        )
    return pd.concat(ret_parts, ignore_index=True), pd.concat(auc_parts, ignore_index=True)


def compare_with_shipped(
    scores: Scores,
    task: str | None = None,
    *,
    cache: RunCache | None = None,
    title: str | None = None,
    compute_missing: bool = False,
) -> Comparison:
    """Your agent's :class:`~thesis_repro.evaluation.score.Scores` beside every learner shipped on ``task``
    (default: the scores' task) at the scores' scale, with 95 % CIs across training seeds, and a Fig 3.4-style
    figure. The scores must use that scale's book grid (``score_model(..., scale=...)`` without overrides), so
    that every number comes from the same σ grid, rollouts and testing seeds. ``compute_missing`` trains and
    evaluates the learners neither shipped nor cached first (:func:`shipped_results`; for ``smoke``).

    >>> cmp = compare_with_shipped(score_model(model, "Hopper", "small"))  # doctest: +SKIP
    >>> print(cmp); cmp.figure.savefig("hopper.png")  # doctest: +SKIP
    """
    if not isinstance(scores, Scores):
        raise ValueError(f"scores must be what score_model returns (a Scores), got {type(scores).__name__}")
    task = scores.task if task is None else short_name(task)
    if task != scores.task:
        raise ValueError(f"the scores are on task {scores.task!r}, not {task!r}")
    if scores.scale is None:
        raise ValueError("the scores have no scale (scale=None): score with scale='small' to compare with the book")
    grid = book_grid(scores.scale)
    if list(scores.sigmas) != grid["sigmas"] or scores.n_rollouts != grid["n_rollouts"] or scores.seed != 0:
        raise ValueError(
            f"the scores use σ {list(scores.sigmas)}, {scores.n_rollouts} rollouts, testing seed {scores.seed}; the "
            f"book at scale {scores.scale!r} uses σ {grid['sigmas']}, {grid['n_rollouts']} rollouts, seed 0: score "
            "with score_model(..., scale=...) and no grid overrides"
        )
    rets, aucs = shipped_results(task, scores.scale, cache, compute_missing=compute_missing)
    if scores.label in set(rets["method"]):
        raise ValueError(f"label {scores.label!r} is a shipped learner's name; score with another label=")
    keep = rets["test"].isin(scores.tests)
    rets = pd.concat([scores.returns_frame(), rets[keep]], ignore_index=True)
    aucs = pd.concat([scores.aucs(), aucs[aucs["test"].isin(scores.tests)]], ignore_index=True)
    table = tables.seed_ci(aucs)
    label = tables.ci_label(table["n_seeds"])
    title = title or f"{scores.label} beside the shipped learners on {task}"
    return Comparison(table=table, returns=rets, ci_label=label, scores=scores, title=title)


def _figure(rets: pd.DataFrame, scores: Scores, title: str) -> Any:
    """Fig 3.4's top row for this task: testing return vs σ, one panel per test type, a line per learner (the
    mean over training seeds of each seed's mean over its rollouts) with its 95 % t-interval band across seeds;
    your agent in black, on top."""
    import matplotlib.pyplot as plt
    import seaborn as sns

    per_seed = tables.seed_means(rets, "return", ["env", "method", "test", "sigma"])
    order = list(dict.fromkeys(rets["method"]))
    others = order[1:]
    palette = dict(zip(others, sns.color_palette("husl", len(others)), strict=True))
    palette[scores.label] = (0.0, 0.0, 0.0)
    tests = scores.tests
    fig, axes = plt.subplots(1, len(tests), figsize=(3.2 * len(tests) + 2.0, 3.6), squeeze=False, sharey=True)
    for j, test in enumerate(tests):
        ax = axes[0, j]
        d = per_seed[per_seed["test"] == test]
        for method in [*others, scores.label]:
            m = d[d["method"] == method]
            mine = method == scores.label
            sns.lineplot(
                m,
                x="sigma",
                y="return",
                errorbar=tables.t_errorbar,
                color=palette[method],
                linewidth=2.4 if mine else 1.0,
                marker="o",
                markersize=4 if mine else 2.5,
                label=method if j == 0 else None,
                ax=ax,
                zorder=3 if mine else 2,
            )
        ax.set_title(f"{scores.task} — {test}", fontsize=9)
        ax.set(xlabel="σ (Σ for dom)", ylabel="testing return" if j == 0 else "")
        if ax.get_legend() is not None:
            ax.get_legend().remove()
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="center left", bbox_to_anchor=(0.87, 0.5), fontsize=7, frameon=False)
    n = per_seed.groupby(["method", "test", "sigma"])["seed"].nunique()
    band = f"band: {tables.ci_label(n)}" if n.max() > 1 else "no band: 1 training seed"
    fig.suptitle(f"{title} (scale {scores.scale})\nline: mean over training seeds; {band}", fontsize=9)
    fig.tight_layout(rect=(0, 0, 0.87, 1))
    return fig


# ---------------------------------------------------------------- single runs
def train_job(algo: str, task: str, seed: int = 0, scale: str = "small") -> Job:
    """The chapter-3 training job of ``algo`` on ``task`` with training seed ``seed`` at ``scale``: the one the
    book trains or loads (same config, same cache key). ``ValueError`` names the valid learners of the task."""
    from thesis_repro import scales

    scales.check_scale(scale)
    task = short_name(task)
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    learners = _learners(task, scale)
    check_choice(algo, list(learners), "learner")
    return _benchmark(learners[algo], algo, task, [int(seed)]).train_jobs[0]


def train_run(algo: str, task: str, seed: int = 0, scale: str = "small", cache: RunCache | None = None) -> Result:
    """Train (or load, when shipped or cached) one chapter-3 run through the run cache; returns its entry."""
    job = train_job(algo, task, seed, scale)
    return (cache or RunCache()).run(job)


def enjoy(
    algo: str,
    task: str,
    seed: int = 0,
    scale: str = "small",
    *,
    test: str = "none",
    sigma: float = 0.0,
    video: str | Path | None = None,
    episode_seed: int = 0,
    max_steps: int | None = None,
    fps: int | None = None,
    cache: RunCache | None = None,
    size: int | None = None,
    every: int = 1,
    lean: bool = False,
) -> dict[str, Any]:
    """One episode of the shipped or cached policy of (``algo``, ``task``, ``seed``, ``scale``) under ``test`` at
    ``sigma``, rendered offscreen (``MUJOCO_GL``, EGL by default) to ``video`` (.mp4 or .gif) if given.

    ``size``: frames of ``size`` x ``size`` pixels (default: the task's 480 x 480); ``every``: keep every n-th
    step's frame (the video plays in real time); ``lean``: no shadows, reflections or skybox (a third of the
    rendering time with a software renderer).

    Returns ``{"return", "length", "video", "source"}``. A run neither shipped nor cached is a ``ValueError``
    naming the ``train`` command that makes it.
    """
    from thesis_repro.envs import PERTURBATIONS
    from thesis_repro.learners import load_policy

    check_choice(test, PERTURBATIONS, "test type")
    sigma = check_nonneg(sigma, "sigma")
    if isinstance(every, bool) or not isinstance(every, int | np.integer) or every < 1:
        raise ValueError(f"every must be an integer >= 1, got {every!r}")
    if video is not None and Path(video).suffix.lower() not in (".mp4", ".gif"):
        raise ValueError(f"video must end in .mp4 or .gif, got {str(video)!r}")
    if video is not None:
        _check_video_writer(Path(video))
    job = train_job(algo, task, seed, scale)
    run = (cache or RunCache()).load(job)
    if run is None:
        raise ValueError(
            f"{algo} on {short_name(task)} (seed {seed}, scale {scale}) is neither shipped nor cached; train it with "
            f"`python -m thesis_repro train {algo} {short_name(task)} --seed {seed} --scale {scale}`"
        )
    policy = load_policy(run)
    render = {"render_mode": "rgb_array", **({"width": int(size), "height": int(size)} if size else {})}
    env = make_env(task, test, sigma, seed=int(episode_seed), env_kwargs=render if video else None)
    frames: list[np.ndarray] = []
    total, steps = 0.0, 0
    try:
        obs, _ = env.reset(seed=int(episode_seed))
        if video:
            _follow_camera(env)
        if video and lean:
            _lean_rendering(env)
        limit = max_steps or 1000
        while steps < limit:
            if video and steps % every == 0:
                frames.append(env.render())
            action = np.asarray(policy(np.asarray(obs, dtype=np.float64)[None]))[0]
            obs, reward, terminated, truncated, _ = env.step(action)
            total += float(reward)
            steps += 1
            if terminated or truncated:
                break
        if video:
            frames.append(env.render())
            _write_video(Path(video), frames, fps or max(1, int(round(1.0 / (env.unwrapped.dt * every)))))
    finally:
        env.close()
    return {"return": total, "length": steps, "video": None if video is None else str(video), "source": run.source}


def _follow_camera(env: Any) -> None:
    """Render from the model's ``track`` camera (it follows the body: Hopper, Walker2d, HalfCheetah) instead of
    gymnasium's default free camera, which stays where the episode started; a model without one keeps it."""
    import mujoco

    renderer, model = getattr(env.unwrapped, "mujoco_renderer", None), getattr(env.unwrapped, "model", None)
    if renderer is None or model is None or getattr(renderer, "camera_id", None) != -1:
        return
    track = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "track")
    if track >= 0:
        renderer.camera_id = track


def _lean_rendering(env: Any) -> None:
    """Turn off the shadows, reflections and skybox of ``env``'s offscreen renderer (gymnasium's MuJoCo
    renderer; anything else is left as it is)."""
    import mujoco

    renderer = getattr(env.unwrapped, "mujoco_renderer", None)
    get = getattr(renderer, "_get_viewer", None)
    scene = getattr(get("rgb_array"), "scn", None) if get is not None else None
    if scene is None:
        return
    for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION, mujoco.mjtRndFlag.mjRND_SKYBOX):
        scene.flags[flag] = 0


def _check_video_writer(path: Path) -> None:
    """``RuntimeError`` (one line) if the packages that write ``path`` are missing: imageio, and imageio-ffmpeg for
    an .mp4 (the ``[video]`` extra)."""
    try:
        import imageio  # noqa: F401

        if path.suffix.lower() == ".mp4":
            import imageio_ffmpeg  # noqa: F401
    except ImportError as err:
        raise RuntimeError(
            f"writing {path.suffix} videos needs {err.name}: pip install 'thesis_repro[video]' (make venv has it)"
        ) from None


def _write_video(path: Path, frames: list[np.ndarray], fps: int) -> None:
    import imageio.v2 as imageio

    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        imageio.mimsave(path, frames, duration=1000 / fps, loop=0)
    else:
        imageio.mimsave(path, frames, fps=fps, macro_block_size=1)


# ---------------------------------------------------------------- the chapter-3 landing page's clips
#: The chapter-3 landing page's clips: one episode of each basic learner (Table 3.4's) on one task under one
#: perturbation, from its shipped (or cached) policy of training seed ``seed``; ``size`` x ``size`` pixels.
CLIPS: dict[str, Any] = {
    "task": "Hopper",
    "learners": ("ppo", "trpo", "sac", "ddpg"),
    "test": "act",
    "sigma": 0.4,
    "seed": 0,
    "size": 160,
}
#: Per scale: (at most this many steps of the episode, a frame every this many steps): ~3 s at Hopper's 125 Hz.
CLIP_STEPS: dict[str, tuple[int, int]] = {"smoke": (40, 2), "small": (400, 6), "full": (400, 6)}
#: The clips' listing beside them: what was rendered from which runs, and each episode's return.
CLIPS_INDEX = "clips.json"


def clips_dir(scale: str) -> Path:
    """``build/<scale>/clips``: the clips of ``scale`` (``<learner>.gif``) and their :data:`CLIPS_INDEX`."""
    from thesis_repro import paths

    return paths.build(scale) / "clips"


def clips_key(scale: str, cache: RunCache | None = None) -> str:
    """What the clips of ``scale`` show: :data:`CLIPS`, the scale's :data:`CLIP_STEPS` and each learner's
    training run (its key and whether it is shipped, cached or missing). Clips with another key are stale."""
    cache = cache or RunCache()
    runs = []
    for algo in CLIPS["learners"]:
        job = train_job(algo, CLIPS["task"], CLIPS["seed"], scale)
        runs.append([algo, job.key, cache.state(job)])
    payload = {"clips": CLIPS, "steps": CLIP_STEPS[scale], "runs": runs}
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=list).encode()).hexdigest()[:16]


def current_clips(scale: str, cache: RunCache | None = None) -> dict[str, Any] | None:
    """The clips index of ``scale`` if its clips are there and up to date (same :func:`clips_key`), else None."""
    index = clips_dir(scale) / CLIPS_INDEX
    try:
        doc = json.loads(index.read_text())
    except (OSError, ValueError):
        return None
    files = [index.parent / c["file"] for c in doc.get("clips", []) if c.get("file")]
    if doc.get("key") != clips_key(scale, cache) or not all(f.is_file() for f in files):
        return None
    return doc


def make_clips(scale: str = "small", force: bool = False, cache: RunCache | None = None) -> dict[str, Any]:
    """Render the chapter-3 clips of ``scale`` (:data:`CLIPS`) into :func:`clips_dir` with :func:`enjoy`, unless
    they are up to date (``force``: always), and write their index; returns it. A learner whose run is neither
    shipped nor cached gets no clip, and its entry names the ``train`` command that makes it
    (``python -m thesis_repro clips --scale small``; ``make clips``)."""
    from thesis_repro import scales

    scales.check_scale(scale)
    cache = cache or RunCache()
    if not force and (doc := current_clips(scale, cache)) is not None:
        return doc
    out = clips_dir(scale)
    _check_video_writer(out / "x.gif")
    steps, every = CLIP_STEPS[scale]
    task, seed = CLIPS["task"], CLIPS["seed"]
    rows: list[dict[str, Any]] = []
    for algo in CLIPS["learners"]:
        if cache.load(train_job(algo, task, seed, scale)) is None:
            cmd = f"python -m thesis_repro train {algo} {task} --seed {seed} --scale {scale}"
            rows.append({"algo": algo, "missing": cmd})
            continue
        res = enjoy(
            algo,
            task,
            seed,
            scale,
            test=CLIPS["test"],
            sigma=CLIPS["sigma"],
            video=out / f"{algo}.gif",
            max_steps=steps,
            size=CLIPS["size"],
            every=every,
            lean=True,
            cache=cache,
        )
        rows.append({"algo": algo, "file": f"{algo}.gif", **{k: res[k] for k in ("return", "length", "source")}})
    doc = {
        "key": clips_key(scale, cache),
        "scale": scale,
        **CLIPS,
        "max_steps": steps,
        "every": every,
        "mujoco_gl": os.environ.get("MUJOCO_GL", ""),
        "clips": rows,
    }
    out.mkdir(parents=True, exist_ok=True)
    (out / CLIPS_INDEX).write_text(json.dumps(doc, indent=1, default=list))
    return doc


def clips_section(doc: dict[str, Any] | None, scale: str, error: str | None = None) -> str:
    """The chapter-3 landing page's clips section (Markdown; the clips in ``clips/``): a table of the learners'
    clips with each episode's return, or one line saying why there are none.

    >>> print(clips_section(None, "small", "no EGL"))  # doctest: +NORMALIZE_WHITESPACE
    <BLANKLINE>
    ## The basic learners under a perturbation
    <BLANKLINE>
    No clips in this build: rendering them failed on this machine (no EGL); `make clips SCALE=small` renders them
    where MuJoCo's offscreen rendering works.
    <BLANKLINE>
    """
    head = "\n## The basic learners under a perturbation\n\n"
    if doc is None:
        why = error or "not rendered"
        return (
            f"{head}No clips in this build: rendering them failed on this machine ({why}); "
            f"`make clips SCALE={scale}` renders them where MuJoCo's offscreen rendering works.\n"
        )
    test_name = {"obs": "observation noise", "act": "action noise", "env": "environment noise", "dom": "domain shift"}
    what = test_name.get(doc["test"], doc["test"])
    intro = (
        f"One episode of each basic learner of Table 3.4 on {doc['task']} under {what} (σ = {doc['sigma']}), "
        f"its policy of training seed {doc['seed']} at scale `{scale}`: at most {doc['max_steps']} steps, a frame "
        f"every {doc['every']} steps, in real time. Rendered offscreen by `make clips SCALE={scale}` "
        f"(MUJOCO_GL={doc.get('mujoco_gl') or 'egl'}); `python -m thesis_repro enjoy ppo {doc['task']} "
        f"--test {doc['test']} --sigma {doc['sigma']} --video ppo.mp4` renders one at full size.\n\n"
    )
    names, cells, notes = [], [], []
    for c in doc["clips"]:
        names.append(c["algo"])
        if c.get("file"):
            cells.append(f"![{c['algo']} on {doc['task']}, {doc['test']} σ {doc['sigma']}](clips/{c['file']})")
            end = "over the first" if c["length"] >= doc["max_steps"] else "episode ended after"
            notes.append(f"return {c['return']:.0f}, {end} {c['length']} steps ({c['source']} run)")
        else:
            cells.append("no clip")
            notes.append(f"not trained at scale {scale}: `{c['missing']}`")
    rows = [
        "| " + " | ".join(names) + " |",
        "|" + "|".join(":-:" for _ in names) + "|",
        "| " + " | ".join(cells) + " |",
        "| " + " | ".join(notes) + " |",
    ]
    return head + intro + "\n".join(rows) + "\n"


def book_clips(root: Path, scale: str) -> str:
    """Put the clips of ``scale`` on the staged book's chapter-3 landing page (``root/chapter-3.md``): render them
    when missing or stale (``python -m thesis_repro clips`` in a subprocess, so that MuJoCo's GL stays out of
    the book's process: ``MUJOCO_GL`` as set, EGL by default, then OSMesa), copy them to ``root/clips`` and
    append :func:`clips_section`; one line instead when rendering fails (a scale whose basic learners are not
    trained gets their ``train`` commands, without a subprocess). Returns the section."""
    md = Path(root) / "chapter-3.md"
    if not md.exists():
        return ""
    doc, error = current_clips(scale), None
    cache = RunCache()
    jobs = [train_job(algo, CLIPS["task"], CLIPS["seed"], scale) for algo in CLIPS["learners"]]
    if doc is None and all(cache.state(job) in ("missing", "partial") for job in jobs):
        doc = make_clips(scale, cache=cache)  # no policy to render: no renderer, no subprocess
    if doc is None:
        tried = [os.environ.get("MUJOCO_GL", "egl")]
        if tried[0] == "egl":
            tried.append("osmesa")
        for gl in tried:
            done = subprocess.run(
                [sys.executable, "-m", "thesis_repro", "clips", "--scale", scale],
                capture_output=True,
                text=True,
                env={**os.environ, "MUJOCO_GL": gl},
            )
            if done.returncode == 0:
                doc = current_clips(scale)
                break
            lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
            error = error or f"MUJOCO_GL={gl}: {lines[-1] if lines else f'exit code {done.returncode}'}"
        if doc is None and len(tried) > 1:
            error = f"{error}; MUJOCO_GL=osmesa failed too"
    if doc is not None:
        dest = Path(root) / "clips"
        dest.mkdir(exist_ok=True)
        for c in doc["clips"]:
            if c.get("file"):
                shutil.copy(clips_dir(scale) / c["file"], dest / c["file"])
    section = clips_section(doc, scale, error)
    md.write_text(md.read_text().rstrip("\n") + "\n" + section)
    return section


# ---------------------------------------------------------------- SB3 zips
#: SB3 algorithm classes tried, in order, on a zip without ``--algo``.
SB3_ALGOS: tuple[str, ...] = ("ppo", "sac", "td3", "ddpg", "a2c", "trpo", "tqc")


def _sb3_class(name: str) -> Any:
    import sb3_contrib
    import stable_baselines3

    check_choice(name, SB3_ALGOS, "SB3 algorithm")
    return getattr(stable_baselines3, name.upper(), None) or getattr(sb3_contrib, name.upper())


def load_sb3(path: str | Path, algo: str | None = None) -> Any:
    """An SB3 model from a ``.zip`` saved with ``model.save`` (``algo``: its class, e.g. ``"ppo"``; default: the
    first of :data:`SB3_ALGOS` that loads it). A missing or unreadable file is a one-line ``ValueError``."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"no such model file: {str(path)!r} (an SB3 .zip saved with model.save)")
    if not zipfile.is_zipfile(p):
        raise ValueError(f"{str(path)!r} is not an SB3 model .zip (saved with model.save)")
    names = [algo] if algo is not None else list(SB3_ALGOS)
    errors = []
    for name in names:
        cls = _sb3_class(name)
        try:
            return cls.load(str(p), device="cpu")
        except Exception as err:  # noqa: BLE001 - the wrong class fails in many ways; try the next
            errors.append(f"{name}: {type(err).__name__}")
    raise ValueError(f"cannot load {str(path)!r} as an SB3 model ({'; '.join(errors)})")


def tasks() -> list[str]:
    """The five tasks (for the command line's choices)."""
    return list(ENVS)


__all__ = [
    "CLIPS",
    "CLIP_STEPS",
    "ITEMS",
    "README_EXAMPLE",
    "SB3_ALGOS",
    "TESTS",
    "Comparison",
    "book_clips",
    "clips_section",
    "compare_with_shipped",
    "enjoy",
    "guide_settings",
    "load_sb3",
    "make_clips",
    "score_model",
    "shipped_results",
    "tasks",
    "train_job",
    "train_run",
]
