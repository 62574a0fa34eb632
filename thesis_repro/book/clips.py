"""Videos of trained policies: one episode rendered offscreen (:func:`enjoy`), and the chapter-3 page's clips.

:func:`enjoy` plays one episode of a shipped or cached chapter-3 policy, optionally perturbed, and writes it as
an .mp4 or .gif (``python -m thesis_repro enjoy ppo Hopper --seed 0 --test obs --sigma 0.4 --video out.mp4``).
:func:`make_clips` renders the chapter-3 landing page's clips of the basic learners (:data:`CLIPS`;
``make clips``), and :func:`book_clips` puts them on the staged book's page, rendering them in a subprocess so
that MuJoCo's GL stays out of the book's process.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from thesis_repro.book.agent import load_sb3, match_task, training_job
from thesis_repro.core import paths, scales
from thesis_repro.core.cache import RunCache
from thesis_repro.core.terminal import Progress
from thesis_repro.core.validation import check_choice, check_nonneg
from thesis_repro.envs import PERTURBATIONS, make_env, prepare_render
from thesis_repro.learners import load_policy


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
    model: str | Path | None = None,
    human: bool = False,
    progress: bool = False,
) -> dict[str, Any]:
    """One episode of the shipped or cached policy of (``algo``, ``task``, ``seed``, ``scale``) -- or of the SB3
    ``.zip`` ``model`` (then ``algo`` is its SB3 class or ``None``: detected) -- under ``test`` at ``sigma``,
    rendered offscreen (``MUJOCO_GL``, EGL by default) to ``video`` (.mp4 or .gif) if given, or in a window
    with ``human`` (needs a display; without one a one-line ``ValueError``).

    ``size``: frames of ``size`` x ``size`` pixels (default: the task's 480 x 480); ``every``: keep every n-th
    step's frame (the video plays in real time); ``lean``: no shadows, reflections or skybox (a third of the
    rendering time with a software renderer); ``progress``: a progress line with an ETA on stderr.

    Returns ``{"return", "length", "video", "source"}``. A run neither shipped nor cached is a ``ValueError``
    naming the ``train`` command that makes it.
    """
    check_choice(test, PERTURBATIONS, "test type")
    sigma = check_nonneg(sigma, "sigma")
    if isinstance(every, bool) or not isinstance(every, int | np.integer) or every < 1:
        raise ValueError(f"every must be an integer >= 1, got {every!r}")
    if size is not None and (isinstance(size, bool) or not isinstance(size, int | np.integer) or size < 16):
        raise ValueError(f"size must be an integer >= 16 (pixels) or None, got {size!r}")
    if video is not None and Path(video).suffix.lower() not in (".mp4", ".gif"):
        raise ValueError(f"video must end in .mp4 or .gif, got {str(video)!r}")
    if video is not None and human:
        raise ValueError("choose one of video (offscreen) and human (a window)")
    if human:
        prepare_render("human")  # no display: one line now, not MuJoCo's abort later
    if video is not None:
        _check_video_writer(Path(video))
    task = match_task(task)
    if model is not None:
        sb3 = load_sb3(model, algo)

        def policy(obs: np.ndarray) -> np.ndarray:
            return sb3.predict(obs, deterministic=True)[0]

        source = f"SB3 zip {Path(model).name}"
    else:
        job = training_job(algo, task, seed, scale)
        run = (cache or RunCache()).load(job)
        if run is None:
            raise ValueError(
                f"{algo} on {task} (seed {seed}, scale {scale}) is neither shipped nor cached; train it with "
                f"`python -m thesis_repro train {algo} {task} --seed {seed} --scale {scale}`"
            )
        policy, source = load_policy(run), run.source
    if human:
        render: dict[str, Any] | None = {"render_mode": "human"}
    elif video:
        render = {"render_mode": "rgb_array", **({"width": int(size), "height": int(size)} if size else {})}
    else:
        render = None
    env = make_env(task, test, sigma, seed=int(episode_seed), env_kwargs=render)
    frames: list[np.ndarray] = []
    total, steps = 0.0, 0
    limit = max_steps or 1000
    bar = None
    try:
        obs, _ = env.reset(seed=int(episode_seed))
        if video:
            _follow_camera(env)
        if video and lean:
            _lean_rendering(env)
        if progress:
            bar = Progress(f"enjoy {Path(model).name if model else algo} on {task}", limit, "steps")
        while steps < limit:
            if video and steps % every == 0:
                frames.append(env.render())
            action = np.asarray(policy(np.asarray(obs, dtype=np.float64)[None]))[0]
            obs, reward, terminated, truncated, _ = env.step(action)
            total += float(reward)
            steps += 1
            if bar is not None:
                bar.update(steps)
            if terminated or truncated:
                break
        if video:
            frames.append(env.render())
            _write_video(Path(video), frames, fps or max(1, int(round(1.0 / (env.unwrapped.dt * every)))))
    finally:
        env.close()
        if bar is not None:
            bar.total = max(steps, 1)  # an episode that ended early is done
            bar.update(steps)
            bar.close()
    return {"return": total, "length": steps, "video": None if video is None else str(video), "source": source}


def _follow_camera(env: Any) -> None:
    """Render from the model's ``track`` camera (it follows the body: Hopper, Walker2d, HalfCheetah) instead of
    gymnasium's default free camera, which stays where the episode started; a model without one keeps it."""
    renderer, model = getattr(env.unwrapped, "mujoco_renderer", None), getattr(env.unwrapped, "model", None)
    if renderer is None or model is None or getattr(renderer, "camera_id", None) != -1:
        return
    track = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "track")
    if track >= 0:
        renderer.camera_id = track


def _lean_rendering(env: Any) -> None:
    """Turn off the shadows, reflections and skybox of ``env``'s offscreen renderer (gymnasium's MuJoCo
    renderer; anything else is left as it is)."""
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
        import imageio  # noqa: F401 - local: the optional [video] extra, checked here

        if path.suffix.lower() == ".mp4":
            import imageio_ffmpeg  # noqa: F401 - the [video] extra's .mp4 writer
    except ImportError as err:
        raise RuntimeError(
            f"writing {path.suffix} videos needs {err.name}: pip install 'thesis_repro[video]' (make venv has it)"
        ) from None


def _write_video(path: Path, frames: list[np.ndarray], fps: int) -> None:
    import imageio.v2 as imageio  # local: the optional [video] extra

    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        imageio.mimsave(path, frames, duration=1000 / fps, loop=0)
    else:
        imageio.mimsave(path, frames, fps=fps, macro_block_size=1)


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
    return paths.build_dir(scale) / "clips"


def clips_key(scale: str, cache: RunCache | None = None) -> str:
    """What the clips of ``scale`` show: :data:`CLIPS`, the scale's :data:`CLIP_STEPS` and each learner's
    training run (its key and whether it is shipped, cached or missing). Clips with another key are stale."""
    cache = cache or RunCache()
    runs = []
    for algo in CLIPS["learners"]:
        job = training_job(algo, CLIPS["task"], CLIPS["seed"], scale)
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
        if cache.load(training_job(algo, task, seed, scale)) is None:
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
    jobs = [training_job(algo, CLIPS["task"], CLIPS["seed"], scale) for algo in CLIPS["learners"]]
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
