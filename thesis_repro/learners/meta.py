"""The sequential meta-learners: Reptile-DG (Alg 2) and first-order MAML-DG (Alg 1), one domain at a time.

Both are :class:`~thesis_repro.learners.multidomain.MultiDomainPPO` algorithms (its module docstring: domains,
the shared observation filter, ``domain_per_batch``). Per iteration:

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
from stable_baselines3.common.vec_env import VecEnv
from torch import nn

from thesis_repro.core.validation import check_choice, check_nonneg
from thesis_repro.envs.wrappers import _EpisodeDomain
from thesis_repro.learners.config import META_UPDATES
from thesis_repro.learners.fast import RolloutTensors, _ManualActorCritic, ppo_epochs, rollout_tensors
from thesis_repro.learners.multidomain import MultiDomainPPO
from thesis_repro.mdl import aggregate as agg


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
    (:mod:`thesis_repro.runs.study`) varies; ε = 1 keeps the whole adaptation (π ← π').
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
    200k-step InvertedPendulum run (measured, 3 seeds: ``python -m thesis_repro.runs.study maml-outer-update``)
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
