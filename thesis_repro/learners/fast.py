"""Leaner, equivalent training updates for SB3's PPO and TRPO (on-policy): same algorithm, less overhead.

SAC and DDPG (off-policy) are :mod:`thesis_repro.learners.fast_offpolicy`; they share :class:`_FusedAdamStep`.

SB3's ``PPO.train()`` spends most of its time on framework overhead for the kit's tiny networks: per
minibatch it copies numpy slices to tensors, builds ``torch.distributions`` objects, runs autograd over
~40 small nodes and walks ``policy.parameters()`` three times. :class:`FastPPO` overrides ``train()`` (SB3's
own extension point) with :func:`ppo_epochs`, which computes the SAME loss and its gradient:

* the rollout is flattened once into :class:`RolloutTensors` (:func:`rollout_tensors`, in the order of
  SB3's ``RolloutBuffer.get``) and permuted once per epoch with the same ``np.random.permutation`` draw;
* for the kit's policies (SB3 ``MlpExtractor`` or the SCN extractor, Linear+Tanh/ReLU layers, flat Box
  observations, diagonal Gaussian without gSDE) the forward pass and the gradient of the clipped PPO
  loss are written out in closed form (:class:`_ManualActorCritic`; tie and clip conventions of torch's
  autograd for ``min``/``clamp``), so no graph is built; any other policy takes the generic path
  (``policy.evaluate_actions`` + autograd) on the same tensors;
* gradients are clipped with one ``_foreach_norm``, the optimiser is the policy's (fused Adam in the kit);
  statistics stay tensors until the end (one sync per call, plus one per minibatch only if ``target_kl``).

``tests/test_fast.py`` proves equivalence: from identical parameters, optimiser state, rollout buffer and
numpy seed, ``FastPPO.train()`` and ``PPO.train()`` give the same parameters to atol 1e-5 after several
epochs (MLP, SCN, normalised advantages, ``target_kl`` early stop, value clipping).

A ``FastPPO`` zip is an ordinary SB3 PPO zip: ``PPO.load`` reads it (the class is not stored in the file).

>>> import gymnasium as gym
>>> m = FastPPO("MlpPolicy", gym.make("InvertedPendulum-v5"), n_steps=64, batch_size=32, n_epochs=2, seed=0)
>>> _ = m.learn(64)
>>> m.fast_path, m.logger.name_to_value["train/n_updates"]
(True, 2)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from functools import partial
from types import SimpleNamespace
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from sb3_contrib import TRPO
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.distributions import DiagGaussianDistribution
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import FlattenExtractor, MlpExtractor
from stable_baselines3.common.utils import explained_variance, obs_as_tensor
from stable_baselines3.common.vec_env import VecEnv
from torch import nn

from thesis_repro.learners.policies import SCNExtractor

_LOG_SQRT_2PI = math.log(math.sqrt(2 * math.pi))


# ------------------------------------------------------------------------------------------- rollout data
@dataclass
class RolloutTensors:
    """A flat on-policy batch (row ``i`` = one env step), the tensors SB3's ``RolloutBuffer.get`` yields."""

    observations: th.Tensor  # (n, *obs_shape)
    actions: th.Tensor  # (n, *act_shape)
    old_values: th.Tensor  # (n,)
    old_log_prob: th.Tensor  # (n,)
    advantages: th.Tensor  # (n,)
    returns: th.Tensor  # (n,)

    def __len__(self) -> int:
        return int(self.advantages.shape[0])

    def index(self, idx: th.Tensor) -> RolloutTensors:
        """Rows ``idx`` (a LongTensor) of every field."""
        return RolloutTensors(*(getattr(self, f.name).index_select(0, idx) for f in fields(self)))

    def slice(self, start: int, stop: int) -> RolloutTensors:
        """Rows ``start:stop`` (views)."""
        return RolloutTensors(
            self.observations[start:stop],
            self.actions[start:stop],
            self.old_values[start:stop],
            self.old_log_prob[start:stop],
            self.advantages[start:stop],
            self.returns[start:stop],
        )


_BUFFER_FIELDS = ("observations", "actions", "values", "log_probs", "advantages", "returns")


def rollout_tensors(
    buffer: RolloutBuffer, env_index: int | None = None, mask: np.ndarray | None = None
) -> RolloutTensors:
    """Flatten a full ``RolloutBuffer`` env-major, exactly as ``RolloutBuffer.get`` does (row = env·T + t).

    ``env_index`` keeps one env's column (T rows, in time order); ``mask`` (bool, shape
    ``(buffer_size, n_envs)`` like the buffer, or ``(buffer_size,)`` with ``env_index``) keeps the
    marked steps. The buffer is not modified (it may or may not have been flattened by ``get`` already).

    >>> import gymnasium as gym
    >>> buf = RolloutBuffer(3, gym.spaces.Box(-1, 1, (2,)), gym.spaces.Box(-1, 1, (1,)), n_envs=2)
    >>> buf.observations[:] = np.arange(12).reshape(3, 2, 2); buf.full = True
    >>> rollout_tensors(buf).observations[:, 0].tolist()  # env 0 (t = 0, 1, 2), then env 1
    [0.0, 4.0, 8.0, 2.0, 6.0, 10.0]
    >>> rollout_tensors(buf, env_index=1, mask=np.array([True, False, True])).observations[:, 0].tolist()
    [2.0, 10.0]
    """
    if not buffer.full:
        raise ValueError("rollout_tensors needs a full rollout buffer (collect_rollouts first)")
    t_len, n_envs = buffer.buffer_size, buffer.n_envs
    if env_index is not None and not 0 <= int(env_index) < n_envs:
        raise ValueError(f"env_index must be in [0, {n_envs}), got {env_index!r}")
    out = []
    for name in _BUFFER_FIELDS:
        arr = getattr(buffer, name)
        if buffer.generator_ready:  # already flattened env-major by get(): (n_envs * T, ...)
            arr = arr.reshape(n_envs, t_len, *arr.shape[1:])
        else:  # (T, n_envs, ...)
            arr = arr.swapaxes(0, 1)
        if env_index is not None:
            arr = arr[int(env_index)]
            sel = None if mask is None else np.asarray(mask, dtype=bool).reshape(t_len)
        else:
            arr = arr.reshape(n_envs * t_len, *arr.shape[2:])
            sel = None if mask is None else np.asarray(mask, dtype=bool).reshape(t_len, n_envs).swapaxes(0, 1).ravel()
        if sel is not None:
            arr = arr[sel]
        t = th.tensor(np.ascontiguousarray(arr), device=buffer.device)
        out.append(t.reshape(len(t)) if name not in ("observations", "actions") else t)
    return RolloutTensors(*out)


# ------------------------------------------------------------------------------- closed-form PPO gradient
def _linear_layers(seq: nn.Sequential) -> tuple[list[nn.Linear], str] | None:
    mods = list(seq)
    if len(mods) % 2:
        return None
    linears, acts = mods[0::2], mods[1::2]
    if not all(type(m) is nn.Linear for m in linears):
        return None
    kinds = {type(a) for a in acts}
    if not kinds:
        return [], "tanh"
    if kinds == {nn.Tanh}:
        return linears, "tanh"
    if kinds == {nn.ReLU}:
        return linears, "relu"
    return None


def _tensors(layers: list[nn.Linear]) -> list[SimpleNamespace]:
    # wt: the transposed VIEW ``weight.t()`` (same strides as a fresh ``.t()``, so the same kernels), made once
    # per build instead of once per matmul; the optimiser updates ``weight`` in place, which the view sees
    return [SimpleNamespace(weight=lin.weight, bias=lin.bias, wt=lin.weight.t()) for lin in layers]


class _ManualActorCritic:
    """Forward pass + closed-form gradient of the PPO loss for the kit's actor-critic policies."""

    def __init__(self, policy: ActorCriticPolicy, pi: list[nn.Linear], vf: list[nn.Linear], act: str, scn: bool):
        # layers as (weight, bias) holders of the parameter tensors themselves: no nn.Module attribute look-ups
        self.policy, self.pi, self.vf, self.act, self.scn = policy, _tensors(pi), _tensors(vf), act, scn
        self.action_net, self.value_net = _tensors([policy.action_net, policy.value_net])
        self.log_std: nn.Parameter = policy.log_std
        # parameters in policy.parameters() order, each with the slot of its gradient
        self.params = list(policy.parameters())

    def refresh(self) -> None:
        """Re-take the transposed weight views (in case a parameter's ``.data`` was replaced since the build)."""
        for layer in (*self.pi, *self.vf, self.action_net, self.value_net):
            layer.wt = layer.weight.t()

    @staticmethod
    def build(policy: nn.Module) -> _ManualActorCritic | None:
        """The manual path for ``policy``, or None if its structure is not one the kit uses."""
        if not isinstance(policy, ActorCriticPolicy) or type(policy.action_dist) is not DiagGaussianDistribution:
            return None
        if policy.use_sde or policy.squash_output or not isinstance(policy.observation_space, spaces.Box):
            return None
        if len(policy.observation_space.shape) != 1 or not isinstance(policy.action_space, spaces.Box):
            return None
        extractors = [policy.features_extractor, policy.pi_features_extractor, policy.vf_features_extractor]
        if not all(type(e) is FlattenExtractor for e in extractors if e is not None):
            return None
        mlp = policy.mlp_extractor
        if type(mlp) not in (MlpExtractor, SCNExtractor):
            return None
        pi, vf = _linear_layers(mlp.policy_net), _linear_layers(mlp.value_net)
        if pi is None or vf is None or (pi[0] and vf[0] and pi[1] != vf[1]):
            return None
        act = pi[1] if pi[0] else vf[1]
        manual = _ManualActorCritic(policy, pi[0], vf[0], act, type(mlp) is SCNExtractor)
        known = {id(p) for layer in (*pi[0], *vf[0], policy.action_net, policy.value_net) for p in layer.parameters()}
        known.add(id(policy.log_std))
        if {id(p) for p in manual.params} != known or len(manual.params) != len(known):
            return None
        return manual

    def _act(self, z: th.Tensor) -> th.Tensor:
        return th.tanh(z) if self.act == "tanh" else th.relu(z)

    @property
    def _act_fn(self) -> Any:
        return th.tanh if self.act == "tanh" else th.relu

    def _act_grad(self, g: th.Tensor, h: th.Tensor) -> th.Tensor:
        # tanh' = 1 - tanh^2 (autograd's tanh_backward); relu' = 1[h > 0] (threshold_backward). th.rsub(t, 1) is
        # what ``1 - t`` runs (Tensor.__rsub__), minus its Python wrapper; likewise t.reciprocal() * c for c / t
        return g * th.rsub(h * h, 1) if self.act == "tanh" else g * (h > 0)

    def _mlp(self, x: th.Tensor, layers: list[nn.Linear]) -> list[th.Tensor]:
        hs = [x]
        act = self._act_fn
        for lin in layers:
            hs.append(act(th.addmm(lin.bias, hs[-1], lin.wt)))
        return hs

    def _mlp_backward(self, g: th.Tensor, hs: list[th.Tensor], layers: list[nn.Linear], grads: dict) -> None:
        for i in range(len(layers) - 1, -1, -1):
            gz = self._act_grad(g, hs[i + 1])
            grads[id(layers[i].weight)] = gz.t().mm(hs[i])
            grads[id(layers[i].bias)] = gz.sum(0)
            if i:
                g = gz.mm(layers[i].weight)

    def forward(self, obs: th.Tensor, actions: th.Tensor) -> tuple[dict[str, Any], th.Tensor, th.Tensor]:
        """Cache of the forward pass, the log-prob of ``actions`` and the values (all without a graph)."""
        x = obs.float()
        hp = self._mlp(x, self.pi)
        latent_pi = th.cat([x, hp[-1]], dim=1) if self.scn else hp[-1]
        hv = self._mlp(x, self.vf)
        mean = th.addmm(self.action_net.bias, latent_pi, self.action_net.wt)
        values = th.addmm(self.value_net.bias, hv[-1], self.value_net.wt).flatten()
        log_std = self.log_std
        inv_var = th.exp(-2 * log_std)
        diff = actions - mean
        sq = diff * diff * inv_var
        log_prob = -0.5 * sq.sum(1) - (log_std.sum() + _LOG_SQRT_2PI * log_std.numel())
        cache = {"x": x, "hp": hp, "hv": hv, "latent_pi": latent_pi, "diff": diff, "sq": sq, "inv_var": inv_var}
        return cache, log_prob, values

    def sample(self, obs: th.Tensor, frozen: dict | None = None) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """``policy(obs)`` (SB3's ``ActorCriticPolicy.forward``, stochastic): the same torch draw and formulas,
        so the same actions, values (B, 1) and log-probs.

        ``frozen``: a dict the caller keeps for as long as the parameters do not change (one rollout); the
        std-only terms (``std``, ``2 std²``, ``log std``, each of the batch's shape) are computed into it once
        per batch shape, by the same ops on the same values, instead of at every call."""
        x = obs.float()
        hp = self._mlp(x, self.pi)
        latent_pi = th.cat([x, hp[-1]], dim=1) if self.scn else hp[-1]
        values = th.addmm(self.value_net.bias, self._mlp(x, self.vf)[-1], self.value_net.wt)
        mean = th.addmm(self.action_net.bias, latent_pi, self.action_net.wt)
        terms = None if frozen is None else frozen.get(mean.shape)
        if terms is None:
            std = th.ones_like(mean) * self.log_std.exp()
            terms = (std, 2 * std**2, std.log())
            if frozen is not None:
                frozen[mean.shape] = terms
        std, two_var, log_std = terms
        actions = mean + th.empty(mean.shape, dtype=mean.dtype, device=mean.device).normal_() * std
        log_prob = (-((actions - mean) ** 2) / two_var - log_std - _LOG_SQRT_2PI).sum(dim=1)
        return actions, values, log_prob

    def entropy(self) -> th.Tensor:
        """Per-sample entropy of the diagonal Gaussian (the same for every sample)."""
        return (0.5 + 0.5 * math.log(2 * math.pi) + self.log_std).sum()

    def backward(
        self,
        cache: dict[str, Any],
        g_log_prob: th.Tensor,
        g_values: th.Tensor,
        g_log_std_extra: float,
        attach: bool = True,
    ) -> list[th.Tensor]:
        """The gradient of every parameter (in ``params`` order) from dLoss/dlog_prob (B,), dLoss/dvalues (B,)
        and a constant dLoss/dlog_std term (entropy); also set as ``p.grad`` unless ``attach`` is False."""
        grads: dict[int, th.Tensor] = {}
        # actor: d log_prob / d mean = diff / var; d log_prob / d log_std = diff^2 / var - 1
        g_mean = g_log_prob[:, None] * cache["diff"] * cache["inv_var"]
        grads[id(self.log_std)] = (g_log_prob[:, None] * (cache["sq"] - 1)).sum(0) + g_log_std_extra
        grads[id(self.action_net.weight)] = g_mean.t().mm(cache["latent_pi"])
        grads[id(self.action_net.bias)] = g_mean.sum(0)
        if self.pi:
            g_lat = g_mean.mm(self.action_net.weight)
            if self.scn:
                g_lat = g_lat[:, cache["x"].shape[1] :]
            self._mlp_backward(g_lat, cache["hp"], self.pi, grads)
        # critic
        g_v = g_values[:, None]
        grads[id(self.value_net.weight)] = g_v.t().mm(cache["hv"][-1])
        grads[id(self.value_net.bias)] = g_v.sum(0)
        if self.vf:
            self._mlp_backward(g_v.mm(self.value_net.weight), cache["hv"], self.vf, grads)
        out = [grads[id(p)] for p in self.params]
        if attach:
            for p, g in zip(self.params, out, strict=True):
                p.grad = g
        return out


class _FusedAdamStep:
    """``optimizer.step()`` of a fused CPU ``torch.optim.Adam``: the same two kernels (``_foreach_add_`` on the
    step counters, ``_fused_adam_``) with the same arguments, minus the per-call Python of ``Optimizer.step``
    (hooks, profiler, state look-ups). Any other optimiser, or a state not yet initialised, uses ``step()``."""

    def __init__(self, optimizer: th.optim.Optimizer):
        self.optimizer = optimizer
        groups = optimizer.param_groups
        self.ok = type(optimizer) is th.optim.Adam and all(
            g["fused"] and not (g["amsgrad"] or g["capturable"] or g["differentiable"] or g["decoupled_weight_decay"])
            for g in groups
        )
        self.ok = self.ok and all(p.dtype == th.float32 and p.device.type == "cpu" for g in groups for p in g["params"])
        self._lists: list[tuple[dict, list, list, list, list, list | int]] | None = None

    def _ready(self) -> bool:
        state = self.optimizer.state
        if self._lists is None:
            if not all(len(state[p]) for g in self.optimizer.param_groups for p in g["params"]):
                return False
            self._lists = [
                (g, g["params"], [state[p]["exp_avg"] for p in g["params"]],
                 [state[p]["exp_avg_sq"] for p in g["params"]], [state[p]["step"] for p in g["params"]],
                 _ones_like_steps([state[p]["step"] for p in g["params"]]))
                for g in self.optimizer.param_groups
            ]  # fmt: skip
        return True

    def holds(self, params: list[nn.Parameter]) -> bool:
        """True if the optimiser has one parameter group holding exactly ``params``, in that order (then
        :meth:`step_with` can take their gradients as a list)."""
        groups = self.optimizer.param_groups
        return (
            len(groups) == 1
            and len(groups[0]["params"]) == len(params)
            and all(a is b for a, b in zip(groups[0]["params"], params, strict=True))
        )

    def step_grads(self, grads: dict[int, th.Tensor]) -> bool:
        """:meth:`step_with` for any number of parameter groups: ``grads`` maps ``id(p)`` to the gradient of
        every parameter ``p`` of the optimiser (see :meth:`covers`). False (nothing done): as :meth:`step_with`."""
        if not self._fast():
            return False
        for lists in self._lists:  # type: ignore[union-attr]
            self._kernels(lists, [grads[id(p)] for p in lists[1]])
        return True

    def covers(self, params: list[nn.Parameter]) -> bool:
        """True if the optimiser's parameters are exactly ``params`` (any order, any grouping): then a
        gradient dict over ``params`` serves :meth:`step_grads`."""
        mine = [id(p) for g in self.optimizer.param_groups for p in g["params"]]
        return len(mine) == len(params) and set(mine) == {id(p) for p in params}

    def step_with(self, grads: list[th.Tensor]) -> bool:
        """``__call__``'s two kernels with ``grads`` (the gradients of :meth:`holds`' ``params``, in order) instead
        of the ``p.grad`` attributes, so the caller need not set them per step. False (nothing done): the
        caller sets ``p.grad`` and calls ``__call__`` (not a fused Adam, hooks, or state not initialised yet)."""
        if not self._fast():
            return False
        self._kernels(self._lists[0], grads)  # type: ignore[index]
        return True

    def __call__(self) -> None:
        if not self._fast():
            self.optimizer.step()
            return
        grads = [[p.grad for p in lists[1]] for lists in self._lists]  # type: ignore[union-attr]
        if any(gr is None for gs in grads for gr in gs):
            self.optimizer.step()  # parameters without gradient: let Adam skip them
            return
        for lists, gs in zip(self._lists, grads, strict=True):  # type: ignore[arg-type]
            self._kernels(lists, gs)

    def _fast(self) -> bool:
        opt = self.optimizer
        return self.ok and not opt._optimizer_step_pre_hooks and not opt._optimizer_step_post_hooks and self._ready()

    @staticmethod
    def _kernels(lists: tuple[dict, list, list, list, list, list | int], grads: list[th.Tensor]) -> None:
        """One parameter group's Adam step: the step counters, then the fused update (``Adam.step``'s kernels)."""
        g, params, exp_avgs, exp_avg_sqs, steps, one = lists
        beta1, beta2 = g["betas"]
        th._foreach_add_(steps, one)
        th._fused_adam_(
            params, grads, exp_avgs, exp_avg_sqs, [], steps, amsgrad=False, lr=g["lr"],
            beta1=beta1, beta2=beta2, weight_decay=g["weight_decay"], eps=g["eps"], maximize=g["maximize"],
            grad_scale=None, found_inf=None,
        )  # fmt: skip


def _ones_like_steps(steps: list[th.Tensor]) -> list[th.Tensor] | int:
    """What ``_foreach_add_(steps, ·)`` adds to Adam's step counters: ``Adam.step`` adds the Python scalar 1, which
    ATen wraps and converts to each counter's dtype on every call (a tensor allocation + copy per counter). A
    list of ready 0-dim ones of that dtype runs ``add_`` with the same converted value (``a + 1 * b`` with b = 1),
    minus the conversions; with float32 counters (fused Adam) the counts are integers below 2**24, exact either
    way. Anything but float32 CPU 0-dim counters: the scalar 1."""
    if not steps or not all(s.dtype == th.float32 and s.device.type == "cpu" and s.dim() == 0 for s in steps):
        return 1
    return [th.ones((), dtype=th.float32)] * len(steps)


_mse_mean = partial(th._C._nn.mse_loss, reduction=1)  # = F.mse_loss(a, b) for same-shape a, b (1: "mean")


def _clip_grads(params: list[nn.Parameter], max_norm: float) -> None:
    """``clip_grad_norm_(params, max_norm, foreach=True)`` on a known non-empty parameter list."""
    _clip_grad_list([p.grad for p in params if p.grad is not None], max_norm)


def _clip_grad_list(grads: list[th.Tensor], max_norm: float) -> None:
    """:func:`_clip_grads` on the gradient tensors themselves (scaled in place)."""
    if not grads:
        return
    total = th.linalg.vector_norm(th.stack(th._foreach_norm(grads, 2.0)), 2.0)
    th._foreach_mul_(grads, th.clamp((total + 1e-6).reciprocal() * max_norm, max=1.0))  # = max_norm / (total + 1e-6)


def ppo_epochs(
    policy: ActorCriticPolicy,
    optimizer: th.optim.Optimizer,
    data: RolloutTensors,
    *,
    n_epochs: int,
    batch_size: int,
    clip_range: float,
    clip_range_vf: float | None = None,
    ent_coef: float = 0.0,
    vf_coef: float = 0.5,
    max_grad_norm: float = 0.5,
    normalize_advantage: bool = True,
    target_kl: float | None = None,
    permutation: Any = None,
    manual: bool | _ManualActorCritic | None = None,
) -> dict[str, Any]:
    """SB3's PPO update (``PPO.train`` minus bookkeeping) on ``data``; returns its training statistics.

    Per epoch: one ``permutation(len(data))`` (default ``np.random.permutation``, SB3's draw), minibatches of
    ``batch_size`` in that order, the clipped surrogate + ``vf_coef``·value + ``ent_coef``·entropy loss,
    grad-norm clipping at ``max_grad_norm``, ``optimizer.step()``; stops when the approximate KL of a
    minibatch exceeds 1.5·``target_kl`` (before stepping it), as SB3. ``manual`` forces (True) or forbids
    (False) the closed-form path; None: closed form when the policy supports it; a prebuilt
    ``_ManualActorCritic.build(policy)`` is used as is (callers that take many small updates build it once).

    Returns the means SB3 logs (``policy_gradient_loss``, ``value_loss``, ``entropy_loss``, ``clip_fraction``
    over all minibatches; ``approx_kl`` over the last epoch; ``loss`` of the last minibatch),
    ``epochs`` (epochs started = SB3's ``_n_updates`` increment), ``continue_training`` and ``fast_path``.
    """
    n = len(data)
    if n == 0:
        raise ValueError("ppo_epochs needs a non-empty batch")
    perm_fn = np.random.permutation if permutation is None else permutation
    if isinstance(manual, _ManualActorCritic):
        if manual.policy is not policy:
            raise ValueError("the prebuilt closed-form path belongs to another policy")
        mac: _ManualActorCritic | None = manual
        mac.refresh()
    else:
        mac = _ManualActorCritic.build(policy) if manual is not False else None
    if manual and mac is None:
        raise ValueError(f"policy {type(policy).__name__} has no closed-form PPO path; use manual=None")
    params = mac.params if mac is not None else list(policy.parameters())
    adam_step = _FusedAdamStep(optimizer)
    # closed form + one fused-Adam group of exactly these parameters: the gradients go to the kernels as a list,
    # and p.grad is set once at the end (the last step's, as before) instead of 10 setter calls per minibatch
    direct = mac is not None and adam_step.ok and adam_step.holds(params)
    unattached: list[th.Tensor] | None = None
    policy.set_training_mode(True)
    pg_l, v_l, ent_l, clip_l, kl_l = [], [], [], [], []
    last: tuple[th.Tensor, th.Tensor, th.Tensor] | None = None  # (pg, value, entropy) losses of the last minibatch
    continue_training = True
    epochs = 0
    lo, hi = 1 - clip_range, 1 + clip_range
    with th.set_grad_enabled(mac is None):
        for _ in range(n_epochs):
            epochs += 1
            kl_l = []
            shuffled = data.index(th.as_tensor(perm_fn(n), dtype=th.long))
            for start in range(0, n, batch_size):
                mb = shuffled.slice(start, start + batch_size)
                b = len(mb)
                adv = mb.advantages
                if normalize_advantage and b > 1:
                    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
                if mac is not None:
                    cache, log_prob, values = mac.forward(mb.observations, mb.actions)
                    ent = -mac.entropy()
                else:
                    values, log_prob, entropy = policy.evaluate_actions(mb.observations, mb.actions)
                    values = values.flatten()
                    ent = th.mean(-log_prob) if entropy is None else -th.mean(entropy)
                log_ratio = log_prob - mb.old_log_prob
                ratio = th.exp(log_ratio)
                clipped = th.clamp(ratio, lo, hi)
                p1, p2 = adv * ratio, adv * clipped
                pg = -th.min(p1, p2).mean()
                if clip_range_vf is None:
                    vpred = values
                else:
                    vpred = mb.old_values + th.clamp(values - mb.old_values, -clip_range_vf, clip_range_vf)
                if mac is not None and mb.returns.shape == vpred.shape:  # F.mse_loss's kernel, minus its Python
                    vloss = _mse_mean(mb.returns, vpred)  # (broadcast_tensors of equal shapes = the same values)
                else:
                    vloss = th.nn.functional.mse_loss(mb.returns, vpred)
                if mac is not None:  # no graph: the tensors themselves (detach() would only copy the handle)
                    kl = th.mean((ratio - 1) - log_ratio)
                    clip_l.append(th.mean((th.abs(ratio - 1) > clip_range).float()))
                    pg_l.append(pg)
                    v_l.append(vloss)
                    ent_l.append(ent)
                else:
                    with th.no_grad():
                        kl = th.mean((ratio - 1) - log_ratio)
                        clip_l.append(th.mean((th.abs(ratio - 1) > clip_range).float()))
                    pg_l.append(pg.detach())
                    v_l.append(vloss.detach())
                    ent_l.append(ent.detach())
                kl_l.append(kl)
                last = (pg, vloss, ent)
                if target_kl is not None and np.float32(kl.item()) > 1.5 * target_kl:
                    continue_training = False
                    break
                if mac is not None:
                    # d loss / d ratio with autograd's conventions: clamp passes the gradient on [lo, hi]
                    # (there ratio == clipped, p1 == p2 and min's two halves add up to 1); outside, min
                    # sends it to the smaller term (half each on an exact tie) and clamp blocks p2's half.
                    w = th.where(ratio == clipped, 1.0, (p1 < p2) + 0.5 * (p1 == p2))
                    g_log_prob = adv * w * ratio * (-1.0 / b)
                    g_values = (vpred - mb.returns) * (2.0 * vf_coef / b)
                    if clip_range_vf is not None:
                        d = values - mb.old_values
                        g_values = g_values * ((d >= -clip_range_vf) & (d <= clip_range_vf))
                    grads = mac.backward(cache, g_log_prob, g_values, -float(ent_coef), attach=not direct)
                    _clip_grad_list(grads, max_grad_norm)
                    if direct and adam_step.step_with(grads):
                        unattached = grads
                        continue
                    if direct:  # first step of a fresh optimiser: Optimizer.step() initialises the state
                        for p, g in zip(params, grads, strict=True):
                            p.grad = g
                        unattached = None
                else:
                    loss = pg + ent_coef * ent + vf_coef * vloss
                    optimizer.zero_grad()
                    loss.backward()
                    with th.no_grad():
                        _clip_grads(params, max_grad_norm)
                adam_step()
            if not continue_training:
                break
    if unattached is not None:  # leave the last step's gradients in p.grad, as every step did before
        for p, g in zip(params, unattached, strict=True):
            p.grad = g
    with th.no_grad():
        mean = lambda xs: float(th.stack(xs).double().mean()) if xs else float("nan")  # noqa: E731
        loss = float(last[0] + ent_coef * last[2] + vf_coef * last[1]) if last is not None else float("nan")
    return {
        "policy_gradient_loss": mean(pg_l),
        "value_loss": mean(v_l),
        "entropy_loss": mean(ent_l),
        "clip_fraction": mean(clip_l),
        "approx_kl": mean(kl_l),
        "loss": loss,
        "epochs": epochs,
        "continue_training": continue_training,
        "fast_path": mac is not None,
    }


# ------------------------------------------------------------------------------------------------ FastPPO
class _LeanRollouts:
    """``collect_rollouts`` of SB3's on-policy algorithms with the policy forward in closed form."""

    def collect_rollouts(
        self, env: VecEnv, callback: BaseCallback, rollout_buffer: RolloutBuffer, n_rollout_steps: int
    ) -> bool:
        """SB3 2.9's ``OnPolicyAlgorithm.collect_rollouts`` with the policy forward in closed form
        (:meth:`_ManualActorCritic.sample`: same draw, same numbers) for the kit's policies."""
        mac = _ManualActorCritic.build(self.policy)
        if mac is None or not isinstance(self.action_space, spaces.Box):
            return super().collect_rollouts(env, callback, rollout_buffer, n_rollout_steps)
        assert self._last_obs is not None, "No previous observation was provided"
        self.policy.set_training_mode(False)
        n_steps = 0
        rollout_buffer.reset()
        callback.on_rollout_start()
        low, high = self.action_space.low, self.action_space.high
        frozen: dict = {}  # the std terms of mac.sample: the parameters do not change during the rollout
        while n_steps < n_rollout_steps:
            with th.no_grad():
                obs_tensor = obs_as_tensor(self._last_obs, self.device)  # type: ignore[arg-type]
                actions, values, log_probs = mac.sample(obs_tensor, frozen)
            actions = actions.cpu().numpy().reshape((-1, *self.action_space.shape))
            clipped_actions = np.clip(actions, low, high)
            new_obs, rewards, dones, infos = env.step(clipped_actions)
            self.num_timesteps += env.num_envs
            callback.update_locals(locals())
            if not callback.on_step():
                return False
            self._update_info_buffer(infos, dones)
            n_steps += 1
            for idx, done in enumerate(dones):  # timeouts: bootstrap with the value function (SB3 #633)
                if (
                    done
                    and infos[idx].get("terminal_observation") is not None
                    and infos[idx].get("TimeLimit.truncated", False)
                ):
                    terminal_obs = self.policy.obs_to_tensor(infos[idx]["terminal_observation"])[0]
                    with th.no_grad():
                        terminal_value = self.policy.predict_values(terminal_obs)[0]  # type: ignore[arg-type]
                    rewards[idx] += self.gamma * terminal_value
            rollout_buffer.add(self._last_obs, actions, rewards, self._last_episode_starts, values, log_probs)  # type: ignore[arg-type]
            self._last_obs = new_obs  # type: ignore[assignment]
            self._last_episode_starts = dones
        with th.no_grad():
            values = self.policy.predict_values(obs_as_tensor(new_obs, self.device))  # type: ignore[arg-type]
        rollout_buffer.compute_returns_and_advantage(last_values=values, dones=dones)
        callback.update_locals(locals())
        callback.on_rollout_end()
        return True


class FastPPO(_LeanRollouts, PPO):
    """SB3 ``PPO`` whose ``train()`` runs :func:`ppo_epochs` (same update, see module docstring) and whose
    ``collect_rollouts`` samples in closed form (:class:`_LeanRollouts`).

    ``fast_path`` tells whether the last ``train()`` used the closed-form gradient (True for the kit's
    MLP and SCN policies).
    """

    fast_path: bool | None = None

    def train(self) -> None:
        """Update the policy on the current rollout buffer (drop-in for ``PPO.train``)."""
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        clip_range = self.clip_range(self._current_progress_remaining)  # type: ignore[operator]
        clip_range_vf = None
        if self.clip_range_vf is not None:
            clip_range_vf = self.clip_range_vf(self._current_progress_remaining)  # type: ignore[operator]
        if not isinstance(self.action_space, spaces.Box):
            self.fast_path = False
            return super().train()
        stats = ppo_epochs(
            self.policy,
            self.policy.optimizer,
            rollout_tensors(self.rollout_buffer),
            n_epochs=self.n_epochs,
            batch_size=self.batch_size,
            clip_range=clip_range,
            clip_range_vf=clip_range_vf,
            ent_coef=self.ent_coef,
            vf_coef=self.vf_coef,
            max_grad_norm=self.max_grad_norm,
            normalize_advantage=self.normalize_advantage,
            target_kl=self.target_kl,
        )
        self.fast_path = stats["fast_path"]
        self._n_updates += stats["epochs"]
        buf = self.rollout_buffer
        explained_var = explained_variance(buf.values.flatten(), buf.returns.flatten())
        for key in ("entropy_loss", "policy_gradient_loss", "value_loss", "approx_kl", "clip_fraction", "loss"):
            self.logger.record(f"train/{key}", stats[key])
        self.logger.record("train/explained_variance", explained_var)
        if hasattr(self.policy, "log_std"):
            self.logger.record("train/std", th.exp(self.policy.log_std).mean().item())
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/clip_range", clip_range)
        if self.clip_range_vf is not None:
            self.logger.record("train/clip_range_vf", clip_range_vf)


class FastTRPO(_LeanRollouts, TRPO):
    """sb3_contrib's ``TRPO`` (its own ``train()``) whose ``collect_rollouts`` samples in closed form
    (:class:`_LeanRollouts`: the same draws and numbers as SB3's, without building a distribution per step).
    A ``FastTRPO`` zip is an ordinary ``TRPO`` zip."""
