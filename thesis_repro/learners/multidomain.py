"""Multi-domain learners as SB3 on-policy algorithms: EPOpt, MAML-DG, Reptile-DG and Alg 3 (params/kl aggregation).

Each is a subclass of :class:`~thesis_repro.learners.fast.FastPPO` (SB3's ``PPO`` with the same, leaner
update) as SB3 builds its algorithms: the base owns stepping, buffers, ``learn()`` and save/load; an algorithm
overrides ``_setup_model`` / ``train()`` (the sequential meta-learners also ``collect_rollouts``). Every PPO
update is :func:`~thesis_repro.learners.fast.ppo_epochs` on :func:`~thesis_repro.learners.fast.rollout_tensors`
of the rollout (the whole buffer, one env's column or a masked subset); the aggregation math is
:mod:`thesis_repro.mdl.aggregate`.

**Domains.** The training VecEnv has one env per domain (``n_envs`` = N, ``n_steps`` = T, so one iteration
collects N·T steps as the thesis's batches); what differs between domains is what the env settings randomise
once per episode (chapter 4's wind ξ, chapter 3's dom Θ ~ N(Θ0, Σ)). One ``VecNormalize`` over all of them is
the shared observation filter. With ``domain_per_batch`` (thesis protocol) the sequential meta-learners instead
hold ONE domain Θ_i per env for the whole iteration (Alg 1/2; :class:`_MetaPPO`). Per iteration:

* ``joint`` (= PPO-MDL) is plain PPO on the merged batch, i.e. :class:`~thesis_repro.learners.fast.FastPPO`
  itself (no class here);
* :class:`EPOpt`: PPO on the trajectories whose return is in the worst ε fraction (Rajeswaran et al. 2016):
  complete episodes by full return (:func:`complete_episode_mask`, the thesis protocol's ``epopt_rank:
  episodes``) or batch fragments by partial return (:func:`epopt_mask`, ``epopt_rank: fragments``);
* :class:`SubPolicyAggregation` (Alg 3): one sub-policy per domain, each updated by PPO on its own column from
  θ_old; after every epoch (``aggregate_every_epoch``) the sub-policies are aggregated by ``aggregate``:
  ``params_avg`` (Eq 4.6), ``kl_avg`` (Eq 4.10/4.11) or ``kl_exact`` (the exact minimiser of Eq 4.7), value
  nets averaged. Each iteration logs the true Eq 4.7 objective of the aggregate and its KL to each sub-policy;
* :class:`ReptileDG` (Alg 2): π' ← π; for each domain in random order collect T steps with π' and update π'
  by PPO (lr α = ``inner_lr``); then Adam (lr β = ``learning_rate``) on π with the gradient π − π'
  (:func:`reptile_meta_step`);
* :class:`MAMLDG` (Alg 1, FIRST-ORDER): each domain forks π_i = π, adapts it on D_i with PPO (lr α), collects
  D'_i with π_i and takes the PPO-loss gradient AT π_i on D'_i (:func:`post_adaptation_gradient`); Adam (lr β)
  on π with the mean of these gradients (:func:`fomaml_meta_step`). Second-order terms are dropped.
  ``meta_update="step"`` takes that one full-batch step per iteration (Alg 1 read literally);
  ``meta_update="ppo"`` (the kit's default) optimises the same first-order objective Σ_i η(π + Δ_i), with the
  adaptation shifts Δ_i = π_i − π held fixed, for PPO's ``n_epochs`` x minibatches of ``batch_size`` per
  domain on D'_i — its first step is Alg 1's step on a minibatch (fidelity note on :class:`MAMLDG`).

The sequential learners step one domain's env at a time through a one-env view of the same env (its own
``VecMonitor``, a ``LeanVecNormalize`` sharing the filter's statistics) with the base class's ``collect_rollouts``.
The main policy is what is saved and evaluated, without adaptation.

>>> import gymnasium as gym
>>> from stable_baselines3.common.vec_env import DummyVecEnv
>>> venv = DummyVecEnv([lambda: gym.make("InvertedPendulum-v5")] * 2)
>>> m = SubPolicyAggregation("MlpPolicy", venv, n_steps=32, batch_size=32, n_epochs=2, seed=0)
>>> _ = m.learn(64)
>>> sorted(m.last_train_stats), len(m.last_train_stats["kl"])
(['eq47', 'eq47_params_avg', 'kl'], 2)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.utils import FloatSchedule
from stable_baselines3.common.vec_env import VecEnv, VecMonitor
from torch import nn

from thesis_repro.envs.vec import LeanVecEnv, LeanVecNormalize
from thesis_repro.envs.wrappers import _EpisodeDomain
from thesis_repro.learners.config import AGGREGATES, EPOPT_RANKS, META_UPDATES
from thesis_repro.learners.fast import FastPPO, RolloutTensors, _ManualActorCritic, ppo_epochs, rollout_tensors
from thesis_repro.mdl import aggregate as agg
from thesis_repro.mdl import exact
from thesis_repro.validation import check_choice, check_nonneg


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


def epopt_mask(episode_starts: np.ndarray, rewards: np.ndarray, epsilon: float) -> np.ndarray:
    """Steps (shape ``(T, n_envs)`` like the buffer) of the trajectories in the worst ε fraction by return.

    A trajectory is a segment of one env's column between episode starts (cut at the buffer's ends).

    >>> starts = np.array([[1, 1], [0, 0], [1, 0]]); rewards = np.array([[1.0, 5.0], [1.0, 5.0], [0.5, 5.0]])
    >>> epopt_mask(starts, rewards, 0.5).astype(int).tolist()  # returns 2, 0.5 | 15: keep the worst 2 of 3
    [[1, 0], [1, 0], [1, 0]]
    """
    starts, rewards = np.asarray(episode_starts), np.asarray(rewards, dtype=float)
    if starts.shape != rewards.shape or starts.ndim != 2:
        raise ValueError(f"episode_starts and rewards must both be (T, n_envs), got {starts.shape}, {rewards.shape}")
    ids, scores = [], []
    for e in range(starts.shape[1]):
        seg = trajectory_segments(starts[:, e])
        ids.append(seg)
        scores.extend(np.bincount(seg, weights=rewards[:, e]).tolist())
    keep = worst_fraction(np.array(scores), epsilon)
    mask = np.zeros(starts.shape, dtype=bool)
    offset = 0
    for e, seg in enumerate(ids):
        mask[:, e] = keep[offset + seg]
        offset += int(seg[-1]) + 1
    return mask


def complete_episode_mask(episode_starts: np.ndarray, episode_returns: np.ndarray, epsilon: float) -> np.ndarray:
    """Steps (``(T, n_envs)`` like the buffer) of the COMPLETE episodes in the worst ε fraction by full return.

    ``episode_returns`` is NaN except at the last step of every episode that ended in the buffer, where it holds
    that episode's full return (VecMonitor's, which counts its steps in earlier batches too). Only episodes that
    end in the buffer are ranked and kept (EPOpt-ε ranks whole trajectories, Rajeswaran et al. 2016): the
    fragment of an episode still running at the buffer's end is never kept. No episode ended: all False.

    >>> starts = np.array([[0, 1], [1, 0], [0, 0], [1, 1]])  # env 0: an episode from the last batch ends at t=0
    >>> ends = np.full((4, 2), np.nan); ends[0, 0], ends[2, 0], ends[2, 1] = -5.0, 9.0, 3.0
    >>> complete_episode_mask(starts, ends, 0.5).astype(int).tolist()  # 3 ranked (-5, 9, 3): keep -5 and 3
    [[1, 1], [0, 1], [0, 1], [0, 0]]
    """
    starts, returns = np.asarray(episode_starts), np.asarray(episode_returns, dtype=float)
    if starts.shape != returns.shape or starts.ndim != 2:
        raise ValueError(f"episode_starts and episode_returns must be (T, n_envs), got {starts.shape}, {returns.shape}")
    ends = np.isfinite(returns)
    if (ends[:-1] != starts[1:].astype(bool)).any():
        raise ValueError("an episode start must follow every episode end (and only an end)")
    episodes: list[tuple[int, np.ndarray]] = []  # (env, steps of one complete episode)
    scores: list[float] = []
    for e in range(starts.shape[1]):
        seg = trajectory_segments(starts[:, e])
        for t in np.flatnonzero(ends[:, e]):
            episodes.append((e, np.flatnonzero(seg == seg[t])))
            scores.append(float(returns[t, e]))
    mask = np.zeros(starts.shape, dtype=bool)
    if not scores:
        return mask
    for (e, steps), keep in zip(episodes, worst_fraction(np.array(scores), epsilon), strict=True):
        mask[steps, e] = keep
    return mask


def reptile_meta_step(module: nn.Module, adapted: dict[str, th.Tensor], optimizer: th.optim.Optimizer) -> None:
    """Alg 2 outer step: the meta-gradient of every parameter is π − π' (so the step moves π towards π').

    >>> m = nn.Linear(1, 1); target = {k: v + 1 for k, v in m.state_dict().items()}
    >>> reptile_meta_step(m, target, th.optim.SGD(m.parameters(), lr=1.0))
    >>> all(th.allclose(v, target[k]) for k, v in m.state_dict().items())
    True
    """
    optimizer.zero_grad()
    for name, p in module.named_parameters():
        p.grad = (p.detach() - adapted[name].detach()).clone()
    optimizer.step()


def reptile_interpolate(module: nn.Module, adapted: dict[str, th.Tensor], eps: float) -> None:
    """Nichol et al.'s Reptile outer step without an optimiser: π ← π + ε (π' − π) for every parameter.

    >>> m = nn.Linear(1, 1); target = {k: v + 1 for k, v in m.state_dict().items()}
    >>> before = {k: v.clone() for k, v in m.state_dict().items()}
    >>> reptile_interpolate(m, target, 0.25)
    >>> all(th.allclose(v, before[k] + 0.25) for k, v in m.state_dict().items())
    True
    """
    with th.no_grad():
        for name, p in module.named_parameters():
            p.add_(adapted[name].detach() - p, alpha=float(eps))


def fomaml_meta_step(module: nn.Module, grads: list[dict[str, th.Tensor]], optimizer: th.optim.Optimizer) -> None:
    """Alg 1 outer step (first order): π's gradient is the mean of the post-adaptation gradients."""
    if not grads:
        raise ValueError("fomaml_meta_step needs at least one domain's gradient")
    optimizer.zero_grad()
    for name, p in module.named_parameters():
        p.grad = th.stack([g[name] for g in grads]).mean(0).clone()
    optimizer.step()


class _GradRecorder(th.optim.Optimizer):
    """An 'optimizer' that records the gradients it is asked to apply and leaves the parameters alone."""

    def __init__(self, named: list[tuple[str, nn.Parameter]]):
        super().__init__([p for _, p in named], {"lr": 0.0})
        self._named = named
        self.grads: dict[str, th.Tensor] = {}

    def step(self, closure=None):  # noqa: ANN001,ANN201 - optimizer API
        self.grads = {n: th.zeros_like(p) if p.grad is None else p.grad.detach().clone() for n, p in self._named}


def post_adaptation_gradient(
    policy: ActorCriticPolicy,
    data: RolloutTensors,
    *,
    recorder: _GradRecorder | None = None,
    manual: _ManualActorCritic | None = None,
    **ppo_kwargs: Any,
) -> dict[str, th.Tensor]:
    """Gradient of the PPO loss at ``policy``'s CURRENT parameters on ``data`` (one full batch, clipped at
    ``max_grad_norm`` as every PPO step); the parameters are not changed. ``ppo_kwargs``: of :func:`ppo_epochs`.

    ``recorder`` (a ``_GradRecorder`` of ``policy``) and ``manual`` (``_ManualActorCritic.build(policy)``) may be
    built once by a caller taking many gradients of one policy: the same numbers, without rebuilding them."""
    rec = recorder if recorder is not None else _GradRecorder(list(policy.named_parameters()))
    ppo_epochs(policy, rec, data, n_epochs=1, batch_size=len(data), manual=manual, **ppo_kwargs)
    return rec.grads


def episode_domains(env: Any) -> list[_EpisodeDomain]:
    """The wrappers of a gym env (outermost first) that draw a domain per episode (``dom`` shift, ``wind``)."""
    found = []
    while env is not None:
        if isinstance(env, _EpisodeDomain):
            found.append(env)
        env = getattr(env, "env", None)
    return found


class _StepsOnly(BaseCallback):
    """Forwards a callback's per-step calls only (a domain's collection is part of one iteration)."""

    def __init__(self, inner: BaseCallback):
        super().__init__()
        self.inner = inner

    def update_locals(self, locals_: dict[str, Any]) -> None:
        self.inner.update_locals(locals_)

    def _on_step(self) -> bool:
        return self.inner.on_step()


# ------------------------------------------------------------------------------------------ algorithms
class MultiDomainPPO(FastPPO):
    """Base of the multi-domain learners: env ``i`` of the VecEnv is domain ``i``; optional sub-policies.

    ``sub_lr`` (None: no sub-policies) is the learning rate of one sub-policy per domain (same class and
    architecture as the policy, own Adam state, saved with the model).
    """

    sub_lr: float | None = None

    def _setup_model(self) -> None:
        super()._setup_model()
        self.iterations_done = getattr(self, "iterations_done", 0)
        self.last_train_stats: dict[str, Any] = {}
        self._rng = getattr(self, "_rng", None) or np.random.default_rng(self.seed)
        self.sub_policies: nn.ModuleList | None = None
        if self.sub_lr is not None:
            subs = []
            for _ in range(self.n_envs):
                sub = self.policy_class(  # type: ignore[assignment]
                    self.observation_space, self.action_space, FloatSchedule(self.sub_lr), **self.policy_kwargs
                )
                sub.load_state_dict(self.policy.state_dict())
                subs.append(sub.to(self.device))
            self.sub_policies = nn.ModuleList(subs)
        self._domain_envs: list[VecEnv] | None = None
        self._domain_buffers: list[RolloutBuffer] = []
        self._domain_obs: list[np.ndarray] = []
        self._domain_starts: list[np.ndarray] = []

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        names, other = super()._get_torch_save_params()
        if self.sub_policies is not None:
            names = [*names, "sub_policies", *(f"sub_policies.{i}.optimizer" for i in range(len(self.sub_policies)))]
        return names, other

    def _excluded_save_params(self) -> list[str]:
        private = ["_domain_envs", "_domain_buffers", "_domain_obs", "_domain_starts", "_adapted", "_meta_grads"]
        return [*super()._excluded_save_params(), *private]

    def _ppo(self, policy: ActorCriticPolicy, optimizer: th.optim.Optimizer, data: RolloutTensors, n_epochs: int):
        """:func:`ppo_epochs` with this algorithm's PPO settings; returns its statistics."""
        return ppo_epochs(policy, optimizer, data, n_epochs=n_epochs, batch_size=self.batch_size, **self._ppo_kwargs())

    def _ppo_kwargs(self) -> dict[str, Any]:
        clip_vf = None if self.clip_range_vf is None else self.clip_range_vf(self._current_progress_remaining)
        return {
            "clip_range": self.clip_range(self._current_progress_remaining),  # type: ignore[operator]
            "clip_range_vf": clip_vf,
            "ent_coef": self.ent_coef,
            "vf_coef": self.vf_coef,
            "max_grad_norm": self.max_grad_norm,
            "normalize_advantage": self.normalize_advantage,
            "target_kl": self.target_kl,
        }

    def _record(self, stats: dict[str, Any]) -> None:
        self.iterations_done += 1
        self.last_train_stats = stats
        for key, value in stats.items():
            if isinstance(value, float | int):
                self.logger.record(f"train/{key}", value)

    # -- sequential collection (one domain at a time)
    def _domain_env(self, i: int) -> VecEnv:
        """One-env view of domain ``i`` (the same env object; own monitor; the shared filter statistics)."""
        if self._domain_envs is None:
            base = self.env.unwrapped  # type: ignore[union-attr]
            vn = self.get_vec_normalize_env()
            views: list[VecEnv] = []
            for env in base.envs:  # type: ignore[attr-defined]
                view: VecEnv = VecMonitor(LeanVecEnv([lambda e=env: e]))
                if vn is not None:  # LeanVecNormalize: VecNormalize's outputs and statistics, fewer copies
                    view = LeanVecNormalize(
                        view,
                        training=vn.training,
                        norm_obs=vn.norm_obs,
                        norm_reward=vn.norm_reward,
                        clip_obs=vn.clip_obs,
                        gamma=vn.gamma,
                        epsilon=vn.epsilon,
                    )
                    view.obs_rms = vn.obs_rms  # one shared running filter
                views.append(view)
            self._domain_envs = views
            self._domain_obs = [v.reset() for v in views]
            self._domain_starts = [np.ones(1, dtype=bool) for _ in views]
            self._domain_buffers = [
                RolloutBuffer(
                    self.n_steps,
                    self.observation_space,
                    self.action_space,
                    device=self.device,
                    gamma=self.gamma,
                    gae_lambda=self.gae_lambda,
                    n_envs=1,
                )
                for _ in views
            ]
        return self._domain_envs[i]

    def _collect_domain(self, i: int, policy: ActorCriticPolicy, callback: BaseCallback) -> bool:
        """Fill domain ``i``'s buffer with ``n_steps`` steps of ``policy`` (the base ``collect_rollouts``)."""
        env = self._domain_env(i)
        saved = self.policy, self._last_obs, self._last_episode_starts
        self.policy, self._last_obs, self._last_episode_starts = policy, self._domain_obs[i], self._domain_starts[i]
        try:
            ok = FastPPO.collect_rollouts(self, env, callback, self._domain_buffers[i], self.n_steps)
            self._domain_obs[i], self._domain_starts[i] = self._last_obs, self._last_episode_starts  # type: ignore
        finally:
            self.policy, self._last_obs, self._last_episode_starts = saved
        return ok


class EPOpt(MultiDomainPPO):
    """PPO on the worst ``epsilon`` fraction of the iteration's trajectories, after a warm start on all of them.

    ``epopt_rank``: ``"episodes"`` (EPOpt-ε as Rajeswaran et al. 2016) ranks the COMPLETE episodes that end in
    the iteration's batch by their full return (VecMonitor's, which includes the episode's steps of earlier
    batches) and trains on the steps in this batch of the worst ε of them; an episode still running at the
    batch's end is neither ranked nor kept (it is ranked in the batch where it ends). An iteration in which no
    episode ended trains nothing. ``"fragments"``: the batch's fragments between episode starts and the batch's
    ends, ranked by partial return (:func:`epopt_mask`).

    Warm start: the first ``epopt_warm_start`` iterations (None: ``epopt_warmup``) train on the whole batch
    (ε = 1, i.e. PPO-MDL), as Rajeswaran et al. start with ε = 1.
    """

    def __init__(
        self,
        *args: Any,
        epsilon: float = 0.1,
        epopt_warmup: int = 0,
        epopt_rank: str = "fragments",
        epopt_warm_start: int | None = None,
        **kwargs: Any,
    ):
        if not 0.0 < epsilon <= 1.0:
            raise ValueError(f"epsilon must be in (0, 1], got {epsilon!r}")
        self.epsilon, self.epopt_warmup = float(epsilon), int(epopt_warmup)
        self.epopt_rank = check_choice(epopt_rank, EPOPT_RANKS, "epopt_rank")
        self.epopt_warm_start = None if epopt_warm_start is None else int(epopt_warm_start)
        super().__init__(*args, **kwargs)

    def collect_rollouts(self, env: VecEnv, callback: BaseCallback, buffer: RolloutBuffer, n_rollout_steps: int):
        if self.epopt_rank == "episodes":  # full return of each episode, at the step where it ends
            self._episode_ends = np.full((n_rollout_steps, self.n_envs), np.nan)
        return super().collect_rollouts(env, callback, buffer, n_rollout_steps)

    def _update_info_buffer(self, infos: list[dict[str, Any]], dones: np.ndarray | None = None) -> None:
        super()._update_info_buffer(infos, dones)
        if self.epopt_rank == "episodes":
            t = self.rollout_buffer.pos  # called before the step is added to the buffer
            for e, info in enumerate(infos):
                if "episode" in info:
                    self._episode_ends[t, e] = float(info["episode"]["r"])

    def train(self) -> None:
        """PPO on the selected steps of the rollout buffer."""
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        buf = self.rollout_buffer
        warm = self.epopt_warmup if self.epopt_warm_start is None else self.epopt_warm_start
        mask = None
        extra: dict[str, Any] = {}  # (none for fragments: their records have no extra field)
        if self.epopt_rank == "episodes":
            extra["ranked_episodes"] = int(np.isfinite(self._episode_ends).sum())
            if self.iterations_done >= warm:
                mask = complete_episode_mask(buf.episode_starts, self._episode_ends, self.epsilon)
        elif self.iterations_done >= warm:
            mask = epopt_mask(buf.episode_starts, buf.rewards, self.epsilon)
        if mask is not None and not mask.any():  # no episode ended in this batch: nothing to rank
            self._record({"kept_fraction": 0.0, **extra})
            return
        stats = self._ppo(self.policy, self.policy.optimizer, rollout_tensors(buf, mask=mask), self.n_epochs)
        self._n_updates += stats["epochs"]
        self._record({"kept_fraction": 1.0 if mask is None else float(mask.mean()), **extra})


class SubPolicyAggregation(MultiDomainPPO):
    """Alg 3: per domain a sub-policy updated by PPO on its own column from θ_old, then aggregated.

    ``aggregate``: ``params_avg`` (Eq 4.6), ``kl_avg`` (Eq 4.10/4.11: ``cg_iters``, ``cg_rtol``, ``damping``,
    ``line_search``) or ``kl_exact`` (``exact_iters`` Newton-CG steps on the true Eq 4.7: ``cg_iters``,
    ``cg_rtol``, ``damping``); ``aggregate_every_epoch``: aggregate after each of the ``n_epochs`` epochs (Alg 3)
    or once after all; ``fim_states``: rollout states used for Fisher products and the logged Eq 4.7.
    The sub-policies learn with ``learning_rate``; value networks are averaged (Alg 3). The Fisher products
    are :class:`~thesis_repro.mdl.aggregate.FisherProducts` (closed form for the MLP policy, all N at once).

    **Reading of "domain" (fidelity note, issues 8/12).** Alg 3 samples N domains ξ_1..ξ_N per iteration
    and collects T steps in each; §4.3.2 says of the experiments that "the wind speed is sampled once per
    episode". The kit follows §4.3.2: domain i is env i of the VecEnv, whose ``Wind`` wrapper draws a new
    ξ ~ U(low, high) at every episode start, so sub-policy i learns from the T = 1024 steps of env i, which
    span one or more episodes, each with its own ξ — not from one ξ_i held for the whole iteration. The same
    envs feed ``joint`` (plain PPO on the merged batch), so the learners compared in chapter 4 see identical
    domain statistics. Holding one ξ_i per column for T steps (Alg 3 read literally) would need a per-iteration
    wind in the env layer and would also change what ``joint`` sees; it is not done.
    """

    def __init__(
        self,
        *args: Any,
        aggregate: str = "params_avg",
        aggregate_every_epoch: bool = True,
        fim_states: int = 1024,
        cg_iters: int = 10,
        damping: float = 0.1,
        line_search: bool = False,
        exact_iters: int = 10,
        cg_rtol: float = 1e-3,
        **kwargs: Any,
    ):
        self.aggregate = check_choice(aggregate, AGGREGATES, "aggregate")
        self.aggregate_every_epoch = bool(aggregate_every_epoch)
        self.fim_states, self.cg_iters, self.exact_iters = int(fim_states), int(cg_iters), int(exact_iters)
        self.damping, self.cg_rtol = check_nonneg(damping, "damping"), check_nonneg(cg_rtol, "cg_rtol")
        self.line_search = bool(line_search)
        super().__init__(*args, **kwargs)

    def _setup_model(self) -> None:
        self.sub_lr = self.learning_rate if not callable(self.learning_rate) else self.learning_rate(1.0)
        super()._setup_model()

    def _states(self) -> th.Tensor:
        obs = self.rollout_buffer.observations.reshape(-1, *self.observation_space.shape)
        if self.fim_states < len(obs):
            obs = obs[self._rng.choice(len(obs), size=self.fim_states, replace=False)]
        return th.as_tensor(obs, dtype=th.float32, device=self.device)

    def _aggregate(self, view: agg.PolicyView, thetas: list[th.Tensor], states: th.Tensor, old: th.Tensor, info: dict):
        if self.aggregate == "params_avg":
            return agg.params_avg(thetas)
        if self.aggregate == "kl_avg":
            return agg.kl_avg(
                view,
                thetas,
                states,
                old,
                cg_iters=self.cg_iters,
                damping=self.damping,
                info=info,
                line_search=self.line_search,
                cg_rtol=self.cg_rtol,
            )
        return exact.kl_exact(
            view,
            thetas,
            states,
            iters=self.exact_iters,
            cg_iters=self.cg_iters,
            cg_rtol=self.cg_rtol,
            damping=self.damping,
            info=info,
        )

    def train(self) -> None:
        """Alg 3's update on the rollout buffer (one column per domain)."""
        self.policy.set_training_mode(True)
        subs = self.sub_policies
        assert subs is not None
        self._update_learning_rate([s.optimizer for s in subs])
        data = [rollout_tensors(self.rollout_buffer, env_index=i) for i in range(self.n_envs)]
        states = self._states()
        view = agg.PolicyView.from_sb3(self.policy)
        critic = [n for n, _ in self.policy.named_parameters() if n.startswith(agg.SB3_CRITIC_PREFIXES)]
        theta_old = view.get_flat()
        rounds, epochs = (self.n_epochs, 1) if self.aggregate_every_epoch else (1, self.n_epochs)
        info: dict[str, Any] = {}
        thetas: list[th.Tensor] = []
        new = theta_old
        # built once per update (the modules' tensors are updated in place): each sub-policy's (own, main)
        # state_dict tensor pairs, which `sub.load_state_dict(self.policy.state_dict())` copies one by one
        current = self.policy.state_dict(keep_vars=True)
        own = [s.state_dict(keep_vars=True) for s in subs]
        pairs = [[(sd[k], v) for k, v in current.items()] for sd in own]
        sub_views = [agg.PolicyView.from_sb3(s) for s in subs]
        params = dict(self.policy.named_parameters())
        sub_params = [dict(s.named_parameters()) for s in subs]
        for _ in range(rounds):
            for sub, column, copies in zip(subs, data, pairs, strict=True):
                with th.no_grad():  # = sub.load_state_dict(self.policy.state_dict()): the same copies
                    for dst, src in copies:
                        dst.copy_(src)
                self._ppo(sub, sub.optimizer, column, epochs)
            thetas = [v.get_flat() for v in sub_views]
            new = self._aggregate(view, thetas, states, theta_old, info)
            view.set_flat(new)
            with th.no_grad():
                for name in critic:
                    params[name].copy_(th.stack([sp[name] for sp in sub_params]).mean(0))
        self._n_updates += self.n_epochs
        kls = agg.eq47_kls(view, new, thetas, states)
        stats: dict[str, Any] = {
            "eq47": float(kls.sum()),
            "kl": kls.tolist(),
            "eq47_params_avg": agg.eq47_objective(view, agg.params_avg(thetas), thetas, states),
        }
        if self.aggregate == "kl_avg":  # of the last aggregation of the iteration
            stats.update(cg_residual=float(info["cg_residual"]), step_fraction=float(info["step_fraction"]))
        elif self.aggregate == "kl_exact":
            stats.update(exact_iters=int(info["iters"]), cg_residual=float((info["cg_residuals"] or [math.nan])[-1]))
        self._record(stats)


class _MetaPPO(MultiDomainPPO):
    """Base of the sequential meta-learners: sub-policies adapt with ``inner_lr`` for ``inner_epochs``.

    ``domain_per_batch`` (Alg 1/2's "sample a batch of domains Θ_i ~ p(Θ)"): at the start of domain i's
    collection in every iteration, its env draws ONE domain Θ_i (:meth:`~thesis_repro.envs.wrappers.
    _EpisodeDomain.hold_domain`, from the env wrappers' own seeded generators), restarts its episode in it and
    keeps Θ_i across its episode resets for all of domain i's batches of the iteration (MAML-DG: D_i and D'_i;
    D'_i continues D_i's episode stream). The restart is the reference MAML sampler's (each task's sampling
    starts from resets in that task); the episode it cuts is never recorded as a training episode. False: each
    env draws a new domain at every episode start, so one batch spans several domains.
    Without a per-episode domain wrapper (``dom`` perturbation or ``wind``) there is one domain and no restart.
    """

    def __init__(
        self, *args: Any, inner_lr: float = 1e-3, inner_epochs: int = 1, domain_per_batch: bool = False, **kwargs: Any
    ):
        self.inner_lr, self.inner_epochs = check_nonneg(inner_lr, "inner_lr"), int(inner_epochs)
        if self.inner_epochs < 1:
            raise ValueError(f"inner_epochs must be >= 1, got {inner_epochs!r}")
        self.domain_per_batch = bool(domain_per_batch)
        super().__init__(*args, **kwargs)

    def _new_domain(self, i: int) -> None:
        """With ``domain_per_batch``: draw and hold domain ``i``'s Θ_i for this iteration, restart its episode."""
        if not self.domain_per_batch:
            return
        view = self._domain_env(i)
        held = [w.hold_domain() for w in episode_domains(self.env.unwrapped.envs[i])]  # type: ignore[union-attr]
        if held:
            self._domain_obs[i] = view.reset()  # type: ignore[assignment]
            self._domain_starts[i] = np.ones(1, dtype=bool)

    def _setup_model(self) -> None:
        self.sub_lr = self.inner_lr
        super()._setup_model()
        if not isinstance(self.action_space, spaces.Box):
            raise ValueError("the multi-domain learners need a continuous (Box) action space")

    def _adapt(self, sub: ActorCriticPolicy, buffer: RolloutBuffer) -> None:
        self._ppo(sub, sub.optimizer, rollout_tensors(buffer), self.inner_epochs)


class ReptileDG(_MetaPPO):
    """Alg 2: π' ← π; per domain (random order) collect with π' and adapt π'; Adam on π with π − π'.

    ``meta_step_size`` (None: Alg 2 as written, one Adam step of lr β = ``learning_rate`` on the gradient
    π − π' per iteration) ε instead takes Nichol et al.'s (2018) outer step π ← π + ε_t (π' − π) with no
    optimiser, ε_t = ε x (current learning rate / initial one), so it anneals as the run's lr schedule does (the
    Reptile paper anneals ε linearly to 0). It is what the protocol study ``reptile-outer-step``
    (:mod:`thesis_repro.study`) varies; ε = 1 keeps the whole adaptation (π ← π').
    """

    def __init__(self, *args: Any, meta_step_size: float | None = None, **kwargs: Any):
        self.meta_step_size = None if meta_step_size is None else check_nonneg(meta_step_size, "meta_step_size")
        super().__init__(*args, **kwargs)

    def collect_rollouts(self, env: VecEnv, callback: BaseCallback, buffer: RolloutBuffer, n_rollout_steps: int):
        assert self.sub_policies is not None
        callback.on_rollout_start()
        steps = _StepsOnly(callback)
        steps.init_callback(self)
        adapted = {k: v.clone() for k, v in self.policy.state_dict().items()}
        for i in self._rng.permutation(self.n_envs).tolist():
            sub = self.sub_policies[i]
            sub.load_state_dict(adapted)
            self._new_domain(i)  # Θ_i (domain_per_batch)
            if not self._collect_domain(i, sub, steps):
                return False
            self._adapt(sub, self._domain_buffers[i])
            adapted = {k: v.clone() for k, v in sub.state_dict().items()}
        self._adapted = adapted
        callback.update_locals(locals())
        callback.on_rollout_end()
        return True

    def train(self) -> None:
        """The meta step π ← Adam(π, π − π') (lr ``learning_rate``), or π ← π + ε_t (π' − π)."""
        self._update_learning_rate(self.policy.optimizer)
        before = agg.PolicyView.from_sb3(self.policy).get_flat()
        if self.meta_step_size is None:
            reptile_meta_step(self.policy, self._adapted, self.policy.optimizer)
        else:
            eps = self.meta_step_size * self.lr_schedule(self._current_progress_remaining) / self.lr_schedule(1.0)
            reptile_interpolate(self.policy, self._adapted, eps)
        self._n_updates += 1
        self._record({"meta_step_norm": float((agg.PolicyView.from_sb3(self.policy).get_flat() - before).norm())})


class MAMLDG(_MetaPPO):
    """Alg 1 (first order): per domain adapt π_i from π on D_i, gradient at π_i on D'_i; Adam on π with their mean.

    **Outer update (fidelity note).** Alg 1 writes one step π ← π + β∇_π Σ_i η(π_i) per iteration. Read
    literally (``meta_update="step"``) that is ONE Adam step per 2·N·T = 8,192 env steps: 24 steps in `small`'s
    200k-step InvertedPendulum run (measured, 3 seeds: ``python -m thesis_repro.study maml-outer-update``)
    and 488 in the thesis's 4M, against PPO-MDL's ~10 epochs x 64 minibatches per 4,096 steps.
    The thesis's Table 3.7 has PPO-MAML-DG level with or above PPO-MDL, which such a learner cannot reach, so
    the kit's default (``meta_update="ppo"``) optimises the same first-order outer objective as PPO optimises
    its own: ``n_epochs`` epochs; per step one minibatch of ``batch_size`` from each D'_i, the PPO loss
    gradient at π + Δ_i with the adaptation shift Δ_i = π_i − π fixed (first order: ∂(π + Δ_i)/∂π = I), their
    mean applied to π by Adam (lr β). π_i moves with π, so the PPO ratio and clipping keep the outer steps
    near D'_i's policy, as in PPO. With one epoch and one minibatch per domain it IS the literal step (test).
    """

    def __init__(self, *args: Any, meta_update: str = "ppo", **kwargs: Any):
        self.meta_update = check_choice(meta_update, META_UPDATES, "meta_update")
        super().__init__(*args, **kwargs)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_shifts", "_post_data"]

    def collect_rollouts(self, env: VecEnv, callback: BaseCallback, buffer: RolloutBuffer, n_rollout_steps: int):
        assert self.sub_policies is not None
        callback.on_rollout_start()
        steps = _StepsOnly(callback)
        steps.init_callback(self)
        start = {k: v.clone() for k, v in self.policy.state_dict().items()}
        grads, shifts, post = [], [], []
        for i, sub in enumerate(self.sub_policies):
            sub.load_state_dict(start)
            self._new_domain(i)  # Θ_i for D_i and D'_i (domain_per_batch)
            if not self._collect_domain(i, sub, steps):  # D_i with π
                return False
            self._adapt(sub, self._domain_buffers[i])  # π_i
            if not self._collect_domain(i, sub, steps):  # D'_i with π_i
                return False
            data = rollout_tensors(self._domain_buffers[i])
            shifts.append({n: p.detach() - start[n] for n, p in sub.named_parameters()})  # Δ_i
            post.append(data)
            if self.meta_update == "step":
                grads.append(post_adaptation_gradient(sub, data, **self._ppo_kwargs()))
        self._meta_grads, self._shifts, self._post_data = grads, shifts, post
        callback.update_locals(locals())
        callback.on_rollout_end()
        return True

    def train(self) -> None:
        """The outer update on π (Adam, lr ``learning_rate``): one step, or PPO's epochs (``meta_update``)."""
        self._update_learning_rate(self.policy.optimizer)
        if self.meta_update == "step":
            fomaml_meta_step(self.policy, self._meta_grads, self.policy.optimizer)
            norm = math.sqrt(sum(float(g.square().sum()) for g in _mean_grads(self._meta_grads).values()))
            self._n_updates += 1
            self._record({"meta_grad_norm": norm, "meta_steps": 1})
            return
        n_steps = self._outer_ppo()
        self._n_updates += self.n_epochs
        self._record({"meta_steps": n_steps})

    def _outer_ppo(self) -> int:
        """``n_epochs`` x minibatch Adam steps on π with the mean gradient at π + Δ_i on D'_i; returns the count."""
        assert self.sub_policies is not None
        main = dict(self.policy.named_parameters())
        kwargs = self._ppo_kwargs()
        n = min(len(d) for d in self._post_data)
        # built once per update (the same numbers as building them per gradient: tests/test_protocol_learners.py)
        cached = [(_GradRecorder(list(s.named_parameters())), _ManualActorCritic.build(s)) for s in self.sub_policies]
        count = 0
        for _ in range(self.n_epochs):
            perms = [th.as_tensor(np.random.permutation(len(d)), dtype=th.long) for d in self._post_data]
            for lo in range(0, n, self.batch_size):
                grads = []
                for sub, (rec, mac), shift, data, perm in zip(
                    self.sub_policies, cached, self._shifts, self._post_data, perms, strict=True
                ):
                    with th.no_grad():
                        for name, p in sub.named_parameters():
                            p.copy_(main[name] + shift[name])
                    batch = data.index(perm[lo : lo + self.batch_size])
                    grads.append(post_adaptation_gradient(sub, batch, recorder=rec, manual=mac, **kwargs))
                fomaml_meta_step(self.policy, grads, self.policy.optimizer)
                count += 1
        return count


def _mean_grads(grads: list[dict[str, th.Tensor]]) -> dict[str, th.Tensor]:
    return {k: th.stack([g[k] for g in grads]).mean(0) for k in grads[0]}


#: Class name (the ``class`` of a ``hyperparams.yaml`` entry) -> algorithm class.
CLASSES: dict[str, type[MultiDomainPPO]] = {
    "EPOpt": EPOpt,
    "MAMLDG": MAMLDG,
    "ReptileDG": ReptileDG,
    "SubPolicyAggregation": SubPolicyAggregation,
}
