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
hold ONE domain Θ_i per env for the whole iteration (Alg 1/2; :class:`~thesis_repro.learners.meta._MetaPPO`).
Per iteration:

* ``joint`` (= PPO-MDL) is plain PPO on the merged batch, i.e. :class:`~thesis_repro.learners.fast.FastPPO`
  itself (no class here);
* :class:`EPOpt`: PPO on the trajectories whose return is in the worst ε fraction (Rajeswaran et al. 2016):
  complete episodes by full return (:func:`complete_episode_mask`, the thesis protocol's ``epopt_rank:
  episodes``) or batch fragments by partial return (:func:`epopt_mask`, ``epopt_rank: fragments``);
* :class:`SubPolicyAggregation` (Alg 3): one sub-policy per domain, each updated by PPO on its own column from
  θ_old; after every epoch (``aggregate_every_epoch``) the sub-policies are aggregated by ``aggregate``:
  ``params_avg`` (Eq 4.6), ``kl_avg`` (Eq 4.10/4.11) or ``kl_exact`` (the exact minimiser of Eq 4.7), value
  nets averaged. Each iteration logs the true Eq 4.7 objective of the aggregate and its KL to each sub-policy;
* :class:`~thesis_repro.learners.meta.ReptileDG` (Alg 2) and :class:`~thesis_repro.learners.meta.MAMLDG`
  (Alg 1, first order), the sequential meta-learners, are :mod:`thesis_repro.learners.meta`.

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
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.utils import FloatSchedule
from stable_baselines3.common.vec_env import VecEnv, VecMonitor
from torch import nn

from thesis_repro.core.validation import check_choice, check_nonneg
from thesis_repro.envs.vec import LeanVecEnv, LeanVecNormalize
from thesis_repro.learners.config import AGGREGATES, EPOPT_RANKS
from thesis_repro.learners.fast import FastPPO, RolloutTensors, ppo_epochs, rollout_tensors
from thesis_repro.mdl import aggregate as agg
from thesis_repro.mdl import exact, readings


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

    ``aggregate``: ``params_avg`` (Eq 4.6), ``kl_avg`` (Eq 4.10/4.11: ``cg_iters``, ``cg_rtol``, ``damping``;
    ``line_search`` backtracks the correction on Eq 4.7, ``trust_region`` bounds the aggregate's KL to the
    epoch's θ_old by ``kl_bound`` or, if None, by the largest sub-policy's own,
    :func:`~thesis_repro.mdl.readings.kl_trust_region`), ``kl_diag`` (Eq 4.10 with diagonal
    Fishers, ``damping``: :func:`~thesis_repro.mdl.readings.kl_diag`) or ``kl_exact`` (``exact_iters`` Newton-CG
    steps on the true Eq 4.7: ``cg_iters``, ``cg_rtol``, ``damping``); ``aggregate_every_epoch``: aggregate
    after each of the ``n_epochs`` epochs (Alg 3) or once after all; ``fim_states``: rollout states used for
    Fisher products and the logged Eq 4.7. Besides Eq 4.7 (``eq47``, ``eq47_params_avg``, ``kl``), an iteration
    of a reading other than kl_avg, kl_exact and params_avg logs ``kl_params_avg`` (E_s KL(π_params_avg ‖
    π_aggregate): 0 when the reading reduces to params_avg) and its ``step_fraction``.
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
        trust_region: bool = False,
        kl_bound: float | None = None,
        exact_iters: int = 10,
        cg_rtol: float = 1e-3,
        **kwargs: Any,
    ):
        self.aggregate = check_choice(aggregate, AGGREGATES, "aggregate")
        self.aggregate_every_epoch = bool(aggregate_every_epoch)
        self.fim_states, self.cg_iters, self.exact_iters = int(fim_states), int(cg_iters), int(exact_iters)
        self.damping, self.cg_rtol = check_nonneg(damping, "damping"), check_nonneg(cg_rtol, "cg_rtol")
        self.line_search, self.trust_region = bool(line_search), bool(trust_region)
        self.kl_bound = None if kl_bound is None else check_nonneg(kl_bound, "kl_bound")
        if self.kl_bound is not None and not self.trust_region:
            raise ValueError("kl_bound is the bound of trust_region; set trust_region too")
        if self.trust_region and (self.line_search or self.aggregate != "kl_avg"):
            raise ValueError("trust_region is a step rule of aggregate 'kl_avg' without line_search")
        super().__init__(*args, **kwargs)

    def _setup_model(self) -> None:
        self.sub_lr = self.learning_rate if not callable(self.learning_rate) else self.learning_rate(1.0)
        super()._setup_model()

    def _states(self) -> th.Tensor:
        obs = self.rollout_buffer.observations.reshape(-1, *self.observation_space.shape)
        if self.fim_states < len(obs):
            obs = obs[self._rng.choice(len(obs), size=self.fim_states, replace=False)]
        return th.as_tensor(obs, dtype=th.float32, device=self.device)

    @property
    def _reading(self) -> bool:
        """A reading beyond the thesis's kl_avg, the kit's kl_exact and params_avg (logs its step diagnostics)."""
        once = not self.aggregate_every_epoch and self.aggregate != "params_avg"
        return self.aggregate == "kl_diag" or self.line_search or self.trust_region or once

    def _aggregate(
        self, view: agg.PolicyView, thetas: list[th.Tensor], states: th.Tensor, old: th.Tensor, info: dict, start
    ):
        """The aggregate of ``thetas``; ``old`` is the iteration's θ_old, ``start`` this epoch's (Alg 3's θ_old)."""
        if self.aggregate == "params_avg":
            return agg.params_avg(thetas)
        if self.aggregate == "kl_diag":
            return readings.kl_diag(view, thetas, states, damping=self.damping)
        if self.trust_region:
            return readings.kl_trust_region(
                view,
                thetas,
                states,
                start,
                cg_iters=self.cg_iters,
                damping=self.damping,
                cg_rtol=self.cg_rtol,
                kl_bound=self.kl_bound,
                info=info,
            )
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
        fractions: list[float] = []  # a reading's step fraction at each aggregation of the iteration
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
            start = view.get_flat() if self.trust_region else theta_old
            new = self._aggregate(view, thetas, states, theta_old, info, start)
            if self._reading and "step_fraction" in info:
                fractions.append(float(info["step_fraction"]))
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
        if self._reading:
            with th.no_grad():
                stats["kl_params_avg"] = float(agg.mean_kl(view, agg.params_avg(thetas), new, states))
            if fractions:
                stats["step_fraction_mean"] = float(np.mean(fractions))
        if self.aggregate == "kl_avg":  # of the last aggregation of the iteration
            stats.update(cg_residual=float(info["cg_residual"]), step_fraction=float(info["step_fraction"]))
            if self.trust_region:
                stats.update(kl_bound=float(info["kl_bound"]), kl_old=float(info["kl_old"]))
        elif self.aggregate == "kl_exact":
            stats.update(exact_iters=int(info["iters"]), cg_residual=float((info["cg_residuals"] or [math.nan])[-1]))
        self._record(stats)
