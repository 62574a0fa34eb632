"""``train_job``: one resumable, cached training run of ANY kit learner (chapters 3 and 4).

Usable as ``Job("train", train_config(...))``. The job

* builds ``n_envs`` copies of ``make_env(env, perturbation, sigma, c_a=..., wind=...)`` in one process
  (:class:`TrainingVecEnv` -> ``VecMonitor`` (raw returns) -> ``VecNormalize`` (obs filter) [-> ``ARPLVecEnv``]);
  for the multi-domain learners env ``i`` is domain ``i`` (:mod:`thesis_repro.learners.multidomain`);
* seeds SB3 (torch, numpy, the action space) with the config's ``seed`` and env ``i`` with
  :func:`env_seed` ``(seed, i)`` — the kit's ONE seeding rule, always ``< 2**32`` and so disjoint from the
  testing seeds (``>= 2**32``, :func:`thesis_repro.evaluation.test_seeds`), also after a resume;
* checkpoints model (+ replay buffer off-policy) + the run's live state (:mod:`thesis_repro.learners.resume`:
  simulators, wrappers, VecNormalize statistics, random generators, global RNGs) + bookkeeping into
  ``workdir/ckpt-<steps>`` at iteration boundaries at least ``checkpoint_every`` env steps apart, and resumes
  from the newest checkpoint when rerun after an interruption, EXACTLY: the resumed run is bit-identical to
  an uninterrupted one (``tests/test_resume.py``). A checkpoint that cannot be restored exactly (written by
  other code) is discarded and the run starts afresh;
* writes ``out/model.zip``, ``out/vecnormalize.pkl`` (if the obs filter is on), ``out/policy.pth`` +
  ``out/obs_norm.npz`` + ``out/learner.json`` (what :func:`thesis_repro.learners.load_policy` reads) and,
  every ``snapshot_every`` env steps at iteration boundaries, ``out/snapshots/step_<t>/`` (policy + obs filter).

Training return (Fig. 3.3's x-axis, Fig. 4.1's y-axis) := mean undiscounted return of the last 100 training
episodes, measured in the training environment (with its training perturbation), i.e. SB3's ``ep_rew_mean``.
"""

from __future__ import annotations

import json
import os
import pickle
import shutil
import time
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.noise import OrnsteinUhlenbeckActionNoise, VectorizedActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

from thesis_repro.envs import make_env
from thesis_repro.envs.vec import LeanVecEnv, LeanVecNormalize
from thesis_repro.learners.algos import DDPGSplit
from thesis_repro.learners.arpl import ARPLVecEnv
from thesis_repro.learners.config import iteration_steps
from thesis_repro.learners.fast import FastPPO, FastTRPO  # leaner, equivalent (tests/test_fast.py)
from thesis_repro.learners.fast_offpolicy import FastSAC
from thesis_repro.learners.meta import MAMLDG, ReptileDG
from thesis_repro.learners.multidomain import EPOpt, SubPolicyAggregation
from thesis_repro.learners.policies import SCNPolicy
from thesis_repro.learners.policy_file import save_policy
from thesis_repro.learners.resume import ResumeMismatch, capture, global_rng_state, restore, set_global_rng_state

RETURN_WINDOW = 100  # training episodes averaged into train_return and the curve
#: Makers of SB3 callbacks that watch every training run of this process, called with the run's total env steps
#: (``python -m thesis_repro train`` adds its progress line here); they only read the run, never change it.
OBSERVERS: list[Callable[[int], BaseCallback]] = []
#: Algorithm class of each ``class`` name of ``hyperparams.yaml``.
ALGORITHM_CLASSES: dict[str, type[BaseAlgorithm]] = {
    "PPO": FastPPO,
    "TRPO": FastTRPO,  # sb3_contrib's TRPO with the closed-form rollout forward
    "SAC": FastSAC,
    "DDPG": DDPGSplit,
    "EPOpt": EPOpt,
    "MAMLDG": MAMLDG,
    "ReptileDG": ReptileDG,
    "SubPolicyAggregation": SubPolicyAggregation,
}


def env_seed(seed: int, i: int) -> int:
    """Seed of env ``i`` of a training run with seed ``seed``: one draw of ``SeedSequence([seed, i])``.

    Always in ``[0, 2**32)`` (testing seeds are ``>= 2**32``), and independent across runs and envs (unlike
    SB3's default ``seed + i``, which gives run 0's env 1 the stream of run 1's env 0).

    >>> env_seed(0, 1) != env_seed(1, 0), all(0 <= env_seed(s, i) < 2**32 for s in (0, 2**40) for i in range(8))
    (True, True)
    """
    return int(np.random.SeedSequence([int(seed), int(i)]).generate_state(1, dtype=np.uint32)[0])


class TrainingVecEnv(LeanVecEnv):
    """The training VecEnv: :class:`~thesis_repro.envs.vec.LeanVecEnv` whose ``seed(s)`` seeds env ``i``
    with :func:`env_seed` ``(s, i)`` instead of SB3's ``s + i``."""

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        if seed is None:
            return super().seed(None)
        self._seeds = [env_seed(seed, i) for i in range(self.num_envs)]
        return self._seeds


def make_train_venv(cfg: dict[str, Any]) -> VecEnv:
    """The ``VecMonitor(TrainingVecEnv([...]))`` training env of a resolved config (before normalisation)."""
    fns = [
        partial(
            make_env,
            cfg["env"],
            cfg["perturbation"],
            cfg["sigma"],
            c_a=cfg["c_a"],
            wind=cfg["wind"],
            seed=env_seed(cfg["seed"], i),
            max_episode_steps=cfg["max_episode_steps"],
        )
        for i in range(cfg["n_envs"])
    ]
    return VecMonitor(TrainingVecEnv(fns))


def _wrap(cfg: dict[str, Any], inner: VecEnv, vecnorm_path: Path | None) -> VecEnv:
    venv: VecEnv = inner
    if cfg["normalize_obs"] or cfg["norm_reward"]:
        if vecnorm_path is not None:
            venv = LeanVecNormalize.load(str(vecnorm_path), inner)
        else:
            venv = LeanVecNormalize(  # = VecNormalize without per-step copies (tests/test_fast.py)
                inner,
                norm_obs=cfg["normalize_obs"],
                norm_reward=cfg["norm_reward"],
                clip_obs=cfg["clip_obs"],
                gamma=cfg["sb3"].get("gamma", 0.99),
            )
    if cfg.get("arpl") is not None:
        arpl = cfg["arpl"]  # delta absent: the rescaled form (ARPL_DELTAS)
        venv = ARPLVecEnv(venv, arpl["epsilon"], arpl["prob"], seed=cfg["seed"], delta=arpl.get("delta", "rescaled"))
    return venv


def build_model(cfg: dict[str, Any], venv: VecEnv) -> BaseAlgorithm:
    """A fresh model of the config's algorithm class (``train_config``) on ``venv``, logging nowhere."""
    cls = ALGORITHM_CLASSES[cfg["class"]]
    act = {"tanh": th.nn.Tanh, "relu": th.nn.ReLU}[cfg["activation"]]
    kwargs: dict[str, Any] = dict(cfg["sb3"])
    if cfg["class"] == "DDPG":
        kwargs.update(actor_lr=cfg["actor_lr"], critic_lr=cfg["critic_lr"], critic_l2=cfg["critic_l2"])
    if cfg.get("lr_schedule", "constant") == "linear":
        offset = iteration_steps(cfg) / int(cfg["timesteps"])
        horizon = int(cfg.get("stop_at") or cfg["timesteps"]) / int(cfg["timesteps"])
        for key in ("learning_rate", "clip_range"):
            initial = float(kwargs.get(key, 3e-4 if key == "learning_rate" else 0.2))
            kwargs[key] = Ppo1Linear(initial, offset, horizon)
    noise = cfg.get("action_noise")
    if noise is not None:
        if noise["type"] != "ou":
            raise ValueError(f"unknown action_noise type {noise['type']!r}; valid types are: 'ou'")
        dim = int(np.prod(venv.action_space.shape))
        base = OrnsteinUhlenbeckActionNoise(np.zeros(dim), float(noise["sigma"]) * np.ones(dim))
        kwargs["action_noise"] = base if venv.num_envs == 1 else VectorizedActionNoise(base, venv.num_envs)
    policy = SCNPolicy if cfg["policy"] == "scn" else "MlpPolicy"
    model = cls(
        policy,
        venv,
        seed=cfg["seed"],
        device="cpu",
        verbose=0,
        policy_kwargs={"net_arch": cfg["net_arch"], "activation_fn": act, **_optimizer(cfg)},
        **kwargs,
    )
    model.set_logger(Logger(None, []))  # SB3's default logger would create an SB3-<timestamp> temp folder
    return model


class Ppo1Linear:
    """OpenAI baselines ppo1's ``schedule='linear'`` as an SB3 schedule: ``initial x max(1 - t/T, 0)`` with t the
    env steps done BEFORE the iteration (SB3 evaluates schedules after collecting it: ``progress_remaining`` =
    1 - (t + batch)/T, so ``offset`` = batch/T). The first iteration trains with ``initial``, the last with
    ``initial x batch/T``. ``horizon`` = (steps SB3 learns for) / T, below 1 for a run that stops early
    (``stop_at``): SB3's progress then runs over the shorter horizon and is mapped back onto T.

    >>> s = Ppo1Linear(3e-4, offset=0.25)  # 4 iterations
    >>> [round(s(p) / 3e-4, 2) for p in (0.75, 0.5, 0.25, 0.0)]
    [1.0, 0.75, 0.5, 0.25]
    >>> [round(Ppo1Linear(3e-4, 0.25, horizon=0.5)(p) / 3e-4, 2) for p in (0.5, 0.0)]  # the first 2 of 4
    [1.0, 0.75]
    """

    def __init__(self, initial: float, offset: float, horizon: float = 1.0):
        self.initial, self.offset, self.horizon = float(initial), float(offset), float(horizon)

    def __call__(self, progress_remaining: float) -> float:
        if self.horizon != 1.0:  # (only then: a full run's schedule keeps its exact float operations)
            progress_remaining = 1.0 - (1.0 - progress_remaining) * self.horizon
        return self.initial * min(max(progress_remaining + self.offset, 0.0), 1.0)

    def __repr__(self) -> str:
        return f"Ppo1Linear({self.initial:g}, offset={self.offset:g}, horizon={self.horizon:g})"


def _optimizer(cfg: dict[str, Any]) -> dict[str, Any]:
    kw = cfg.get("optimizer_kwargs")
    return {} if kw is None else {"optimizer_kwargs": dict(kw)}


def _curve_step(cfg: dict[str, Any]) -> int:
    """Default spacing of training-curve points: one per on-policy iteration, 1000 steps off-policy."""
    return iteration_steps(cfg) if cfg["class"] not in ("SAC", "DDPG") else 1000


def _checkpoints(workdir: Path) -> list[Path]:
    return sorted(workdir.glob("ckpt-*"), key=lambda p: int(p.name.split("-")[1]))


def checkpoint_steps(workdir: str | Path) -> int:
    """Env steps of the newest checkpoint in a training run's ``workdir`` (0: none yet): how far it got."""
    found = _checkpoints(Path(workdir))
    return int(found[-1].name.split("-")[1]) if found else 0


def save_artifacts(model: BaseAlgorithm, folder: Path, cfg: dict[str, Any], full: bool) -> None:
    """Write ``policy.pth`` (tensors only: :func:`~thesis_repro.learners.policy_file.save_policy`) + ``obs_norm.npz`` +
    ``learner.json`` (and if full the local resume state ``model.zip``/``vecnormalize.pkl``: pickles, never shipped)."""
    folder.mkdir(parents=True, exist_ok=True)
    spec = save_policy(model.policy, folder)
    vn = model.get_vec_normalize_env()
    if vn is not None and vn.norm_obs:
        np.savez(
            folder / "obs_norm.npz", mean=vn.obs_rms.mean, var=vn.obs_rms.var, clip_obs=vn.clip_obs, epsilon=vn.epsilon
        )
    meta = {
        "policy_class": spec["policy_class"],
        "algorithm": cfg["algorithm"],
        "class": cfg["class"],
        "env": cfg["env"],
        "num_timesteps": int(model.num_timesteps),
        "policy_kwargs": spec["policy_kwargs"],
    }
    (folder / "learner.json").write_text(json.dumps(meta, indent=1))
    if full:
        model.save(str(folder / "model.zip"))
        if vn is not None:
            vn.save(str(folder / "vecnormalize.pkl"))


def _entropy(model: BaseAlgorithm) -> float:
    """Entropy (nats) of a state-independent diagonal Gaussian policy (PPO/TRPO and the multi-domain learners)."""
    log_std = getattr(model.policy, "log_std", None)
    if not isinstance(log_std, th.Tensor):
        return float("nan")
    return float((log_std.detach() + 0.5 * np.log(2 * np.pi * np.e)).sum())


class _Bookkeeper(BaseCallback):
    """Records finished episodes and, per on-policy iteration, the policy entropy and the learner's own
    statistics (``model.last_train_stats``); checkpoints and snapshots at iteration boundaries."""

    def __init__(self, cfg: dict[str, Any], workdir: Path, state: dict[str, Any], live: dict[str, Any] | None = None):
        super().__init__()
        self.cfg, self.workdir, self.state = cfg, workdir, state
        self.live = live  # a checkpoint's live state, written back once learn() has set itself up
        self.t0 = time.time()

    def _on_training_start(self) -> None:
        # after SB3's _setup_learn (which resets action noise and may reset envs): the checkpoint's state wins
        if self.live is not None:
            _restore_live(self.model, self.live)
            self.live = None

    def _on_step(self) -> bool:
        for info in self.locals.get("infos", []):
            if "episode" in info:
                ep = info["episode"]
                self.state["episodes"].append([int(self.num_timesteps), float(ep["r"]), int(ep["l"])])
        return True

    def _on_rollout_start(self) -> None:
        t = int(self.model.num_timesteps)
        self.log_iteration()
        every = self.cfg["snapshot_every"]
        last = self.state["last_snapshot"]
        if every > 0 and (last is None or t - last >= every):
            self.snapshot()
        at = self.cfg.get("snapshot_at")  # a snapshot at the first rollout start at or after each listed step
        if at and any((-1 if last is None else last) < step <= t for step in at):
            self.snapshot()
        if self.cfg["checkpoint_every"] > 0 and t - self.state["last_checkpoint"] >= self.cfg["checkpoint_every"]:
            self.checkpoint()

    def log_iteration(self) -> None:
        """One row of per-iteration statistics after each on-policy update (none before the first)."""
        t = int(self.model.num_timesteps)
        rows = self.state["iterations"]
        if not isinstance(self.model, OnPolicyAlgorithm) or t == 0 or (rows and rows[-1]["timesteps"] == t):
            return
        stats = dict(getattr(self.model, "last_train_stats", None) or {})
        rows.append({"timesteps": t, "entropy": _entropy(self.model), **stats})

    def snapshot(self) -> None:
        t = int(self.model.num_timesteps)
        save_artifacts(self.model, self.workdir / "out" / "snapshots" / f"step_{t:09d}", self.cfg, full=False)
        self.state["last_snapshot"] = t

    def checkpoint(self) -> None:
        t = int(self.model.num_timesteps)
        self.state["last_checkpoint"] = t
        self.state["wall_time"] = self.state["wall_time_before"] + time.time() - self.t0
        tmp = self.workdir / ".ckpt-tmp"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        self.model.save(str(tmp / "model.zip"))
        vn = self.model.get_vec_normalize_env()
        if vn is not None:
            vn.save(str(tmp / "vecnormalize.pkl"))
        if isinstance(self.model, OffPolicyAlgorithm):
            self.model.save_replay_buffer(str(tmp / "replay_buffer.pkl"))
        with open(tmp / "live.pkl", "wb") as fh:
            pickle.dump(_capture_live(self.model), fh, protocol=pickle.HIGHEST_PROTOCOL)
        (tmp / "state.json").write_text(json.dumps(self.state))
        old = _checkpoints(self.workdir)
        os.replace(tmp, self.workdir / f"ckpt-{t:012d}")
        for p in old:
            if p.name != f"ckpt-{t:012d}":
                shutil.rmtree(p, ignore_errors=True)


def _live_roots(model: BaseAlgorithm) -> dict[str, Any]:
    """What ``model.save`` does not hold, as separately walked roots (SB3's ``load`` rebuilds the model's own
    spaces apart from the env's, so each root is captured on its own, whatever the two runs share)."""
    own = {
        k: v
        for k, v in vars(model).items()
        if isinstance(v, np.ndarray | np.random.Generator | int | float | bool | np.generic) and not k.startswith("__")
    }
    roots: dict[str, Any] = {
        "env": model.env,
        "action_space": model.action_space,
        "observation_space": model.observation_space,
        "action_noise": getattr(model, "action_noise", None),
        "model": own,
    }
    if getattr(model, "_domain_envs", None) is not None:  # the sequential learners' per-domain views
        roots["domains"] = (model._domain_envs, model._domain_obs, model._domain_starts)  # type: ignore[attr-defined]
    return roots


def _capture_live(model: BaseAlgorithm) -> dict[str, Any]:
    roots = {name: capture(obj) for name, obj in _live_roots(model).items()}
    return {"roots": roots, "rng": global_rng_state()}


def _restore_live(model: BaseAlgorithm, live: dict[str, Any]) -> None:
    saved = live["roots"]
    if "domains" in saved and getattr(model, "_domain_envs", None) is None:
        model._domain_env(0)  # type: ignore[attr-defined]  # build them; their state is restored next
    roots = _live_roots(model)
    if set(roots) != set(saved):
        raise ResumeMismatch(f"checkpoint roots {sorted(saved)} != rebuilt {sorted(roots)}")
    for name, obj in roots.items():
        restore(obj, saved[name])
    for key, value in roots["model"].items():
        setattr(model, key, value)
    set_global_rng_state(live["rng"])


def _resume(cfg: dict[str, Any], workdir: Path, cls: type[BaseAlgorithm], ckpt: Path):
    """``(venv, model, state, live)`` of checkpoint ``ckpt``, restored exactly; ``ResumeMismatch`` if it cannot be."""
    live_path = ckpt / "live.pkl"
    if not live_path.exists():
        raise ResumeMismatch(f"{ckpt.name} has no live state (written by an older kit)")
    state = json.loads((ckpt / "state.json").read_text())
    with open(live_path, "rb") as fh:
        live = pickle.load(fh)
    venv = _wrap(cfg, make_train_venv(cfg), None)
    try:
        model = cls.load(str(ckpt / "model.zip"), env=venv, device="cpu", force_reset=False)
        model.set_logger(Logger(None, []))
        if isinstance(venv, ARPLVecEnv):
            venv.policy = model.policy
        if isinstance(model, OffPolicyAlgorithm):
            model.load_replay_buffer(str(ckpt / "replay_buffer.pkl"))
        _restore_live(model, live)  # now, to find a mismatch before training; again in _on_training_start
    except Exception:
        venv.close()
        raise
    return venv, model, state, live


def _grid(every: int, end: int) -> np.ndarray:
    grid = np.arange(every, end + every, every, dtype=np.int64)
    if len(grid):
        grid[-1] = min(grid[-1], end)
    return grid


def _window_means(episodes: np.ndarray, grid: np.ndarray, column: int) -> np.ndarray:
    """Mean of ``episodes[:, column]`` over the last :data:`RETURN_WINDOW` episodes finished by each grid point."""
    out = np.full(len(grid), np.nan)
    if len(episodes):
        n_done = np.searchsorted(episodes[:, 0], grid, side="right")
        for i, n in enumerate(n_done):
            if n:
                out[i] = episodes[max(0, n - RETURN_WINDOW) : n, column].mean()
    return out


def _iteration_curves(rows: list[dict[str, Any]], grid: np.ndarray) -> dict[str, np.ndarray]:
    """``curve_<stat>`` arrays on ``grid``: the last per-iteration row at or before each point (NaN before any)."""
    if not rows:
        return {}
    ts = np.array([r["timesteps"] for r in rows])
    idx = np.searchsorted(ts, grid, side="right") - 1
    out: dict[str, np.ndarray] = {}
    for key in dict.fromkeys(k for r in rows for k in r if k != "timesteps"):
        values = [np.asarray(r.get(key, np.nan), dtype=float) for r in rows]
        shape = max((v.shape for v in values), key=len)
        values = [v if v.shape == shape else np.full(shape, np.nan) for v in values]
        table = np.stack(values)
        arr = np.full((len(grid), *shape), np.nan)
        arr[idx >= 0] = table[idx[idx >= 0]]
        out[f"curve_{key}"] = arr
    return out


def train_job(config: dict[str, Any], workdir: Path, *, callback: BaseCallback | None = None) -> dict[str, Any]:
    """Train (or resume) the run described by ``config`` (from :func:`train_config`); see module docstring.

    ``callback`` is an extra SB3 callback (tests use it to simulate an interruption); the cache never
    passes it. Returns ``train_return`` (None if no episode finished), every finished episode
    (``episode_timesteps``, ``episode_returns``, ``episode_lengths``), the training curve on a grid of
    ``curve_every`` env steps (default: one point per iteration): ``curve_timesteps``, ``curve_return`` and
    ``curve_length`` (means over the last 100 episodes), and for on-policy learners one ``curve_<stat>`` per
    per-iteration statistic (``curve_entropy``; the multi-domain learners' own, e.g. ``curve_eq47``,
    ``curve_kl`` (points × domains), ``curve_kept_fraction``); ``timesteps_done``, ``resumed_from``,
    ``snapshots`` (steps), ``wall_time`` (seconds over all sessions), ``steps_per_s`` (this session, per wall
    second), ``cpu_time`` and ``steps_per_cpu_s`` (this session's CPU seconds, and steps per CPU-second).
    """
    th.set_num_threads(1)
    cfg = config
    workdir = Path(workdir)
    (workdir / "out").mkdir(parents=True, exist_ok=True)
    cls = ALGORITHM_CLASSES[cfg["class"]]
    ckpts = _checkpoints(workdir)
    resumed = None
    if ckpts:
        try:
            resumed = _resume(cfg, workdir, cls, ckpts[-1])
        except (ResumeMismatch, OSError, EOFError, pickle.UnpicklingError, ValueError, KeyError) as err:
            print(f"[train] cannot resume {workdir.name} exactly ({err}); starting afresh", flush=True)
            for p in ckpts:
                shutil.rmtree(p, ignore_errors=True)
            shutil.rmtree(workdir / "out" / "snapshots", ignore_errors=True)
            ckpts = []
    live = None
    if resumed is not None:
        venv, model, state, live = resumed
        resumed_from = int(model.num_timesteps)
        snaps = workdir / "out" / "snapshots"
        for p in snaps.glob("step_*") if snaps.exists() else []:
            if int(p.name.split("_")[1]) > resumed_from:  # written after the checkpoint by the lost session
                shutil.rmtree(p)
        if state["last_snapshot"] is not None and state["last_snapshot"] > resumed_from:
            state["last_snapshot"] = None
        state["wall_time_before"] = state["wall_time"]
    else:
        venv = _wrap(cfg, make_train_venv(cfg), None)
        model = build_model(cfg, venv)
        resumed_from = 0
        state = {
            "episodes": [],
            "iterations": [],
            "last_snapshot": None,
            "last_checkpoint": 0,
            "wall_time": 0.0,
            "wall_time_before": 0.0,
        }
        if isinstance(venv, ARPLVecEnv):
            venv.policy = model.policy
    book = _Bookkeeper(cfg, workdir, state, live)
    remaining = int(cfg.get("stop_at") or cfg["timesteps"]) - int(model.num_timesteps)
    t0, c0 = time.time(), time.process_time()
    if remaining > 0:
        watchers = [make(int(cfg["timesteps"])) for make in OBSERVERS]
        cbs = [book] + ([callback] if callback is not None else []) + watchers
        model.learn(total_timesteps=remaining, callback=CallbackList(cbs), reset_num_timesteps=not ckpts)
    else:
        book.init_callback(model)
    elapsed, cpu = time.time() - t0, time.process_time() - c0
    done = int(model.num_timesteps)
    book.log_iteration()
    if cfg["snapshot_every"] > 0 and state["last_snapshot"] != done:
        book.snapshot()
    save_artifacts(model, workdir / "out", cfg, full=True)
    venv.close()

    episodes = np.asarray(state["episodes"], dtype=np.float64).reshape(-1, 3)
    grid = _grid(cfg["curve_every"] or _curve_step(cfg), done)
    last = episodes[-RETURN_WINDOW:, 1]
    snaps = workdir / "out" / "snapshots"
    return {
        "train_return": float(last.mean()) if len(last) else None,
        "train_return_episodes": int(len(last)),
        "n_episodes": int(len(episodes)),
        "timesteps_done": done,
        "resumed_from": resumed_from,
        "curve_timesteps": grid,
        "curve_return": _window_means(episodes, grid, 1),
        "curve_length": _window_means(episodes, grid, 2),
        **_iteration_curves(state["iterations"], grid),
        "episode_timesteps": episodes[:, 0].astype(np.int64),
        "episode_returns": episodes[:, 1],
        "episode_lengths": episodes[:, 2].astype(np.int64),
        "snapshots": sorted(int(p.name.split("_")[1]) for p in snaps.glob("step_*")) if snaps.exists() else [],
        "wall_time": float(state["wall_time_before"] + elapsed),
        "steps_per_s": float((done - resumed_from) / elapsed) if elapsed > 0 and done > resumed_from else None,
        "cpu_time": float(cpu),  # this session's CPU seconds: the pace per CPU-second, as make bench measures it
        "steps_per_cpu_s": float((done - resumed_from) / cpu) if cpu > 0 and done > resumed_from else None,
    }
