"""SB3-based multi-domain learners: joint (PPO-MDL), PPO-EPOpt, PPO-MAML-DG, PPO-Reptile-DG, params_avg, kl_avg.

One SB3 ``PPO`` object per domain ("worker", its own 1-env ``VecNormalize``; all workers share ONE
running observation filter) collects ``steps_per_domain`` steps per iteration; the deployed policy
lives in a "main" ``PPO`` object. Per iteration (N = ``n_domains``, T = ``steps_per_domain``):

* ``joint``: all N batches collected with θ are merged into one batch (N·T) and PPO updates θ on it.
* ``ppo-epopt``: as joint, but PPO only sees the trajectories whose return is in the worst ε fraction
  (Rajeswaran et al. 2016); :func:`worst_fraction` is the selection.
* ``params_avg`` / ``kl_avg`` (Alg 3): every worker runs PPO on its own batch from θ_old; after each
  epoch (``aggregate_every_epoch``, as Alg 3 is written) the sub-policies are aggregated by Eq 4.6 or
  Eq 4.11 (CG with Fisher-vector products, FIM on the θ_old states) and the value nets averaged.
* ``ppo-reptile-dg`` (Alg 2): π' ← π; for each domain in turn, collect with π' and update π' with PPO
  (lr α = ``inner_lr``); then Adam (lr β = ``meta_lr``) on π with the gradient π − π' (:func:`reptile_meta_step`).
* ``ppo-maml-dg`` (Alg 1), FIRST-ORDER approximation: each domain forks π_i = π, adapts it on one batch
  D_i with PPO (lr α), collects D'_i with π_i and takes the PPO-loss gradient AT π_i on D'_i
  (:func:`post_adaptation_gradient`); π is updated by Adam (lr β) with the mean of these gradients
  (:func:`fomaml_meta_step`). Second-order terms through the adaptation are dropped (FOMAML); the SB3
  loss clips the gradient norm at ``max_grad_norm``.

The main policy is what is saved (``out/model.zip`` + ``out/vecnormalize.pkl``) and evaluated, without
adaptation. :func:`train_job` is the run-cache entry point.
"""

from __future__ import annotations

import math
import pickle
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.logger import configure
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize
from torch import nn

from thesis_repro.mdl import aggregate as agg
from thesis_repro.mdl.config import validate
from thesis_repro.mdl.envs import make_mdl_env

_FIELDS = ("observations", "actions", "rewards", "returns", "episode_starts", "values", "log_probs", "advantages")


# ---------------------------------------------------------------------------------- defining steps (pure)
def trajectory_segments(episode_starts: np.ndarray) -> np.ndarray:
    """Segment id of every step of one env's buffer column (a new segment at each episode start).

    >>> trajectory_segments(np.array([1, 0, 0, 1, 0])).tolist()
    [0, 0, 0, 1, 1]
    """
    starts = np.asarray(episode_starts, dtype=bool).copy()
    starts[0] = True
    return np.cumsum(starts) - 1


def worst_fraction(scores: np.ndarray, epsilon: float) -> np.ndarray:
    """EPOpt selection: boolean mask of the ``ceil(ε·n)`` lowest scores (at least one).

    >>> worst_fraction(np.array([5.0, 1.0, 3.0, 2.0]), 0.5).tolist()
    [False, True, False, True]
    """
    scores = np.asarray(scores, dtype=float)
    if scores.ndim != 1 or len(scores) == 0:
        raise ValueError("scores must be a non-empty 1-D array")
    if not 0.0 < epsilon <= 1.0:
        raise ValueError(f"epsilon must be in (0, 1], got {epsilon!r}")
    k = max(1, math.ceil(epsilon * len(scores) - 1e-9))
    mask = np.zeros(len(scores), dtype=bool)
    mask[np.argsort(scores, kind="stable")[:k]] = True
    return mask


def reptile_meta_step(module: nn.Module, adapted: dict[str, torch.Tensor], optimizer: torch.optim.Optimizer) -> None:
    """Alg 2 outer step: the meta-gradient of every parameter is π − π' (so the step moves π towards π').

    >>> m = nn.Linear(1, 1); target = {k: v + 1 for k, v in m.state_dict().items()}
    >>> reptile_meta_step(m, target, torch.optim.SGD(m.parameters(), lr=1.0))
    >>> all(torch.allclose(v, target[k]) for k, v in m.state_dict().items())
    True
    """
    optimizer.zero_grad()
    for name, p in module.named_parameters():
        p.grad = (p.detach() - adapted[name].detach()).clone()
    optimizer.step()


def fomaml_meta_step(module: nn.Module, grads: list[dict[str, torch.Tensor]], optimizer: torch.optim.Optimizer) -> None:
    """Alg 1 outer step (first order): π's gradient is the mean of the post-adaptation gradients."""
    if not grads:
        raise ValueError("fomaml_meta_step needs at least one domain's gradient")
    optimizer.zero_grad()
    for name, p in module.named_parameters():
        p.grad = torch.stack([g[name] for g in grads]).mean(0).clone()
    optimizer.step()


class _GradRecorder(torch.optim.Optimizer):
    """An 'optimizer' that records the gradients it is asked to apply and leaves the parameters alone."""

    def __init__(self, named: list[tuple[str, nn.Parameter]]):
        super().__init__([p for _, p in named], {"lr": 0.0})
        self._named = named
        self.grads: dict[str, torch.Tensor] = {}

    def step(self, closure=None):  # noqa: D102 - optimizer API
        self.grads = {n: torch.zeros_like(p) if p.grad is None else p.grad.detach().clone() for n, p in self._named}


def post_adaptation_gradient(worker: PPO) -> dict[str, torch.Tensor]:
    """Gradient of SB3's PPO loss at the worker's CURRENT (adapted) parameters on its current buffer.

    One full-batch pass (ratio = 1 for fresh data, i.e. the policy gradient + value + entropy terms);
    the parameters are not changed.
    """
    rec = _GradRecorder(list(worker.policy.named_parameters()))
    saved = worker.policy.optimizer, worker.batch_size, worker.n_epochs
    worker.policy.optimizer, worker.n_epochs = rec, 1
    worker.batch_size = worker.rollout_buffer.buffer_size * worker.rollout_buffer.n_envs
    try:
        worker.train()
    finally:
        worker.policy.optimizer, worker.batch_size, worker.n_epochs = saved
    return rec.grads


def merge_buffers(buffers: list[RolloutBuffer], masks: list[np.ndarray] | None = None) -> RolloutBuffer:
    """One flat buffer (n_envs = 1) of the (masked) steps of ``buffers``, advantages already computed."""
    first = buffers[0]
    cols = {f: [] for f in _FIELDS}
    for j, buf in enumerate(buffers):
        for e in range(buf.n_envs):
            m = slice(None) if masks is None else masks[j][:, e]
            for f in _FIELDS:
                cols[f].append(getattr(buf, f)[:, e][m])
    size = sum(len(c) for c in cols["rewards"])
    if size == 0:
        raise ValueError("merge_buffers: no steps selected")
    out = RolloutBuffer(size, first.observation_space, first.action_space, "cpu", first.gae_lambda, first.gamma, 1)
    for f in _FIELDS:
        setattr(out, f, np.concatenate(cols[f])[:, None])
    out.full = True
    out.pos = size
    return out


# ----------------------------------------------------------------------------------------- the trainer
def _monitor(venv: VecNormalize) -> Monitor:
    return venv.venv.envs[0]  # type: ignore[attr-defined]


def _entropy_of(policy: nn.Module) -> float:
    return float((policy.log_std.detach() + 0.5 * math.log(2 * math.pi * math.e)).sum())  # type: ignore[union-attr]


class MultiDomainTrainer:
    """Runs one learner of :data:`thesis_repro.mdl.config.ALGORITHMS` iteration by iteration.

    >>> from thesis_repro.mdl.config import mdl_config
    >>> cfg = mdl_config("kl_avg", "Hopper", 0, 256, n_domains=2, steps_per_domain=64, max_episode_steps=20)
    >>> tr = MultiDomainTrainer(cfg)  # doctest: +SKIP
    >>> row = tr.iterate(); sorted(row)[:3]  # doctest: +SKIP
    ['cg_residual', 'ep_length', 'ep_return']
    """

    def __init__(self, config: dict[str, Any]):
        validate(config)
        self.cfg = cfg = dict(config)
        self.algo: str = cfg["algorithm"]
        self.n: int = int(cfg["n_domains"])
        self.t: int = int(cfg["steps_per_domain"])
        seed = int(cfg["seed"])
        torch.manual_seed(seed)
        self.rng = np.random.default_rng([seed, 4])
        wind = None if cfg["wind"] is None else tuple(cfg["wind"])
        self.venvs: list[VecNormalize] = []
        for i in range(self.n):

            def make(i: int = i) -> Monitor:
                env = make_mdl_env(
                    cfg["env"],
                    cfg["perturbation"],
                    cfg["sigma"],
                    c_a=cfg["c_a"],
                    wind=wind,
                    max_episode_steps=cfg["max_episode_steps"],
                    seed=seed * 1000 + i,
                )
                return Monitor(env)

            venv = VecNormalize(
                DummyVecEnv([make]),
                norm_obs=bool(cfg["normalize_obs"]),
                norm_reward=False,
                clip_obs=float(cfg["clip_obs"]),
                gamma=float(cfg["gamma"]),
            )
            if self.venvs:
                venv.obs_rms = self.venvs[0].obs_rms  # one shared running-mean filter
            self.venvs.append(venv)
        meta = self.algo in ("ppo-maml-dg", "ppo-reptile-dg")
        worker_lr = float(cfg["inner_lr"]) if meta else float(cfg["learning_rate"])
        kw = dict(
            batch_size=int(cfg["batch_size"]),
            gamma=float(cfg["gamma"]),
            gae_lambda=float(cfg["gae_lambda"]),
            clip_range=float(cfg["clip_range"]),
            ent_coef=float(cfg["ent_coef"]),
            vf_coef=float(cfg["vf_coef"]),
            max_grad_norm=float(cfg["max_grad_norm"]),
            device="cpu",
            verbose=0,
            policy_kwargs={
                "net_arch": {"pi": list(cfg["net_arch"]), "vf": list(cfg["net_arch"])},
                "activation_fn": nn.Tanh,
            },
        )
        self.main = PPO(
            "MlpPolicy",
            self.venvs[0],
            n_steps=self.n * self.t,
            n_epochs=int(cfg["n_epochs"]),
            learning_rate=float(cfg["learning_rate"]),
            seed=seed,
            **kw,
        )
        self.main.set_logger(configure(None, []))
        self.workers: list[PPO] = []
        self.callbacks = []
        for i, venv in enumerate(self.venvs):
            w = PPO(
                "MlpPolicy",
                venv,
                n_steps=self.t,
                n_epochs=int(cfg["n_epochs"]),
                learning_rate=worker_lr,
                seed=seed * 1000 + i,
                **kw,
            )
            _, cb = w._setup_learn(total_timesteps=10**12, callback=None, reset_num_timesteps=True)
            w.set_logger(configure(None, []))
            self.workers.append(w)
            self.callbacks.append(cb)
        self.view = agg.PolicyView.from_sb3(self.main.policy)
        self.wviews = [agg.PolicyView.from_sb3(w.policy) for w in self.workers]
        self.critic = [n for n, _ in self.main.policy.named_parameters() if n.startswith(agg.SB3_CRITIC_PREFIXES)]
        self.meta_opt = torch.optim.Adam(self.main.policy.parameters(), lr=float(cfg.get("meta_lr", 1e-3)))
        self.iteration = 0
        self.timesteps = 0
        self.rows: list[dict[str, Any]] = []
        self._seen = [0] * self.n

    # -- helpers
    def _collect(self, i: int, state: dict[str, torch.Tensor] | None) -> RolloutBuffer:
        w = self.workers[i]
        if state is not None:
            w.policy.load_state_dict(state)
        w.collect_rollouts(w.env, self.callbacks[i], w.rollout_buffer, self.t)
        self.timesteps += self.t
        return w.rollout_buffer

    def _new_episodes(self) -> tuple[list[float], list[int]]:
        rets: list[float] = []
        lens: list[int] = []
        for i, venv in enumerate(self.venvs):
            mon = _monitor(venv)
            rets += mon.get_episode_rewards()[self._seen[i] :]
            lens += mon.get_episode_lengths()[self._seen[i] :]
            self._seen[i] = len(mon.get_episode_rewards())
        return rets, lens

    def _states(self, buffers: list[RolloutBuffer]) -> torch.Tensor:
        obs = np.concatenate([b.observations.reshape(-1, b.observations.shape[-1]) for b in buffers])
        k = int(self.cfg.get("fim_states", len(obs)))
        if k < len(obs):
            obs = obs[self.rng.choice(len(obs), size=k, replace=False)]
        return torch.as_tensor(obs, dtype=torch.float32)

    # -- one iteration of each learner
    def _joint(self, row: dict[str, Any]) -> None:
        state = self.main.policy.state_dict()
        bufs = [self._collect(i, state) for i in range(self.n)]
        masks = None
        if self.algo == "ppo-epopt" and self.iteration >= int(self.cfg["epopt_warmup"]):
            seg_scores, where = [], []
            for j, b in enumerate(bufs):
                ids = trajectory_segments(b.episode_starts[:, 0])
                for s in np.unique(ids):
                    seg_scores.append(float(b.rewards[ids == s, 0].sum()))
                    where.append((j, ids == s))
            keep = worst_fraction(np.array(seg_scores), float(self.cfg["epsilon"]))
            masks = [np.zeros_like(b.rewards, dtype=bool) for b in bufs]
            for (j, m), k in zip(where, keep, strict=True):
                if k:
                    masks[j][m, 0] = True
            row["kept_fraction"] = float(sum(m.sum() for m in masks) / (self.n * self.t))
        self.main.rollout_buffer = merge_buffers(bufs, masks)
        self.main.train()

    def _aggregate(self, row: dict[str, Any]) -> None:
        old = {k: v.clone() for k, v in self.main.policy.state_dict().items()}
        bufs = [self._collect(i, old) for i in range(self.n)]
        states = self._states(bufs)
        theta_old = self.view.get_flat()
        every = bool(self.cfg["aggregate_every_epoch"])
        rounds, epochs = (int(self.cfg["n_epochs"]), 1) if every else (1, int(self.cfg["n_epochs"]))
        info: dict[str, Any] = {}
        thetas: list[torch.Tensor] = []
        new = theta_old
        for r in range(rounds):
            thetas, critics = [], []
            current = self.main.policy.state_dict()
            for i, w in enumerate(self.workers):
                if r > 0:
                    w.policy.load_state_dict(current)
                w.n_epochs = epochs
                w.train()
                thetas.append(self.wviews[i].get_flat())
                params = dict(w.policy.named_parameters())
                critics.append({n: params[n].detach().clone() for n in self.critic})
            if self.algo == "kl_avg":
                new = agg.kl_avg(
                    self.view,
                    thetas,
                    states,
                    theta_old,
                    cg_iters=int(self.cfg["cg_iters"]),
                    damping=float(self.cfg["damping"]),
                    info=info,
                    line_search=bool(self.cfg["line_search"]),
                )
            else:
                new = agg.params_avg(thetas)
            self.view.set_flat(new)
            avg = agg.params_avg(critics)
            main_params = dict(self.main.policy.named_parameters())
            with torch.no_grad():
                for n in self.critic:
                    main_params[n].copy_(avg[n])
        with torch.no_grad():
            row["kl"] = [float(agg.mean_kl(self.view, t, new, states)) for t in thetas]
        row["cg_residual"] = float(info.get("cg_residual", float("nan")))
        row["step_fraction"] = float(info.get("step_fraction", float("nan")))

    def _reptile(self, row: dict[str, Any]) -> None:
        current = {k: v.clone() for k, v in self.main.policy.state_dict().items()}
        for i in self.rng.permutation(self.n):
            self._collect(int(i), current)
            w = self.workers[int(i)]
            w.n_epochs = int(self.cfg["inner_epochs"])
            w.train()
            current = {k: v.clone() for k, v in w.policy.state_dict().items()}
        reptile_meta_step(self.main.policy, current, self.meta_opt)

    def _maml(self, row: dict[str, Any]) -> None:
        start = {k: v.clone() for k, v in self.main.policy.state_dict().items()}
        grads = []
        for i, w in enumerate(self.workers):
            self._collect(i, start)  # D_i with pi
            w.n_epochs = int(self.cfg["inner_epochs"])
            w.train()  # pi_i = adapted
            self._collect(i, None)  # D'_i with pi_i
            grads.append(post_adaptation_gradient(w))
        fomaml_meta_step(self.main.policy, grads, self.meta_opt)

    def iterate(self) -> dict[str, Any]:
        """One training iteration; returns its log row (timesteps, returns, lengths, entropy, kl, ...)."""
        t0 = time.perf_counter()
        row: dict[str, Any] = {
            "kl": [float("nan")] * self.n,
            "cg_residual": float("nan"),
            "step_fraction": float("nan"),
            "kept_fraction": 1.0,
        }
        if self.algo in ("joint", "ppo-epopt"):
            self._joint(row)
        elif self.algo in ("params_avg", "kl_avg"):
            self._aggregate(row)
        elif self.algo == "ppo-reptile-dg":
            self._reptile(row)
        else:
            self._maml(row)
        rets, lens = self._new_episodes()
        self.iteration += 1
        row.update(
            iteration=self.iteration,
            timesteps=self.timesteps,
            entropy=_entropy_of(self.main.policy),
            ep_return=float(np.mean(rets)) if rets else float("nan"),
            ep_length=float(np.mean(lens)) if lens else float("nan"),
            seconds=time.perf_counter() - t0,
        )
        self.rows.append(row)
        return row

    # -- checkpoint / artefacts
    def state(self) -> dict[str, Any]:
        return {
            "iteration": self.iteration,
            "timesteps": self.timesteps,
            "rows": self.rows,
            "seen": self._seen,
            "main": self.main.policy.state_dict(),
            "main_opt": self.main.policy.optimizer.state_dict(),
            "meta_opt": self.meta_opt.state_dict(),
            "workers": [(w.policy.state_dict(), w.policy.optimizer.state_dict()) for w in self.workers],
            "obs_rms": pickle.dumps(self.venvs[0].obs_rms),
            "rng": self.rng.bit_generator.state,
        }

    def load_state(self, st: dict[str, Any]) -> None:
        self.iteration, self.timesteps, self.rows = st["iteration"], st["timesteps"], st["rows"]
        self.main.policy.load_state_dict(st["main"])
        self.main.policy.optimizer.load_state_dict(st["main_opt"])
        self.meta_opt.load_state_dict(st["meta_opt"])
        for w, (p, o) in zip(self.workers, st["workers"], strict=True):
            w.policy.load_state_dict(p)
            w.policy.optimizer.load_state_dict(o)
        rms = pickle.loads(st["obs_rms"])
        for v in self.venvs:
            v.obs_rms = rms
        self.rng.bit_generator.state = st["rng"]
        # episodes of the interrupted run are gone; count from the fresh monitors
        self._seen = [0] * self.n

    def save(self, out: Path) -> None:
        """Artefacts in the learners' format (``policy.pth``, ``obs_norm.npz``, ``learner.json``, ``model.zip``,
        ``vecnormalize.pkl``), so ``thesis_repro.learners.load_policy`` loads these runs too."""
        from thesis_repro.learners.train import save_artifacts

        out.mkdir(parents=True, exist_ok=True)
        save_artifacts(self.main, out, {"algorithm": self.algo, "class": "PPO", "env": self.cfg["env"]}, full=True)

    def close(self) -> None:
        for v in self.venvs:
            v.close()


def curves(rows: list[dict[str, Any]]) -> dict[str, np.ndarray]:
    """Training-curve arrays from the log rows (``kl`` is iterations × domains)."""
    keys = (
        "iteration",
        "timesteps",
        "ep_return",
        "ep_length",
        "entropy",
        "cg_residual",
        "step_fraction",
        "kept_fraction",
        "seconds",
    )
    out = {k: np.array([r.get(k, np.nan) for r in rows], dtype=float) for k in keys}
    out["kl"] = np.array([r["kl"] for r in rows], dtype=float)
    return out


def train_job(config: dict[str, Any], workdir: Path) -> dict[str, Any]:
    """Run-cache job: train to ``config["timesteps"]``, checkpointing in ``workdir``; artefacts in ``workdir/out``.

    Returns the training curves (:func:`curves`) plus ``final_entropy`` and ``total_seconds``.
    """
    workdir = Path(workdir)
    ckpt = workdir / "checkpoint.pt"
    torch.set_num_threads(1)
    trainer = MultiDomainTrainer(config)
    try:
        if ckpt.exists():
            trainer.load_state(torch.load(ckpt, weights_only=False))
        every = int(config["checkpoint_every"])
        while trainer.timesteps < int(config["timesteps"]):
            trainer.iterate()
            if trainer.iteration % every == 0:
                tmp = workdir / "checkpoint.tmp"
                torch.save(trainer.state(), tmp)
                tmp.replace(ckpt)
        trainer.save(workdir / "out")
    finally:
        trainer.close()
    res: dict[str, Any] = dict(curves(trainer.rows))
    res["final_entropy"] = float(trainer.rows[-1]["entropy"])
    res["total_seconds"] = float(np.nansum(res["seconds"]))
    return res


def load_policy(result: Any):
    """Deterministic batched policy ``obs[n, d] -> actions[n, a]`` of a finished :func:`train_job` result.

    Delegates to ``thesis_repro.learners.load_policy`` (same artefact format); runs saved before that
    format (only ``model.zip`` + ``vecnormalize.pkl``) are loaded through SB3 directly.
    """
    out = Path(result.out if hasattr(result, "out") else result)
    if (out / "policy.pth").exists():
        from thesis_repro.learners.policy import load_policy as _load

        return _load(out)
    from thesis_repro.evaluation.score import sb3_policy

    model = PPO.load(out / "model.zip", device="cpu")
    with open(out / "vecnormalize.pkl", "rb") as fh:
        vn = pickle.load(fh)
    vn.training = False
    return sb3_policy(model, vn)
