"""Leaner, equivalent training updates for SB3's PPO (and SAC/DDPG below): same algorithm, less overhead.

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
import torch.nn.functional as F
from gymnasium import spaces
from sb3_contrib import TRPO
from stable_baselines3 import DDPG, PPO, SAC
from stable_baselines3.common.buffers import ReplayBuffer, RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.distributions import DiagGaussianDistribution
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import FlattenExtractor, MlpExtractor
from stable_baselines3.common.utils import explained_variance, obs_as_tensor
from stable_baselines3.common.vec_env import VecEnv
from torch import nn

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
        from thesis_repro.learners.policies import SCNExtractor

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


# ------------------------------------------------------------------------------- SAC / DDPG (TD3 family)
_ACTS = {nn.ReLU: "relu", nn.Tanh: "tanh"}
_tanh_backward = th.ops.aten.tanh_backward
_threshold_backward = th.ops.aten.threshold_backward


class _Net:
    """A ``Sequential`` of Linear layers, each optionally followed by ReLU/Tanh, run and differentiated in
    closed form (SB3's ``create_mlp`` bodies: actor latents, TD3 actors, Q-networks)."""

    def __init__(self, layers: list[tuple[nn.Linear, str | None]]):
        # the parameter tensors themselves (updated in place by the optimiser), not the modules
        self.layers = [(lin.weight, lin.bias, act) for lin, act in layers]
        self.params = [p for w, b, _ in self.layers for p in (w, b)]
        # per layer (bias, the transposed VIEW weight.t(), activation): ATen's linear on a 2-D input with a bias IS
        # addmm(bias, input, weight.t()); the view (same memory, strides and offset as a fresh .t()) is taken once
        # per build (per train() call, and for the exploration cache), not per call, and sees the optimiser's
        # in-place updates. Of the detached weight: outside autograd (the closed forms run without a graph), so a
        # model holding it (the exploration cache) still deep-copies (storage shared with the weight's copy)
        self._fwd = [(b, w.detach().t(), act) for w, b, act in self.layers]

    @staticmethod
    def of(seq: nn.Module) -> _Net | None:
        """The closed-form view of ``seq``; None if it holds anything but biased Linear + ReLU/Tanh."""
        if type(seq) is not nn.Sequential:
            return None
        mods, layers, i = list(seq), [], 0
        while i < len(mods):
            lin = mods[i]
            if type(lin) is not nn.Linear or lin.bias is None:
                return None
            act = _ACTS.get(type(mods[i + 1])) if i + 1 < len(mods) else None
            layers.append((lin, act))
            i += 2 if act is not None else 1
        return _Net(layers) if layers else None

    def forward(self, x: th.Tensor) -> list[th.Tensor]:
        """``[x, h1, ..., out]``: the input and every layer's (activated) output (``nn.Linear``'s kernel)."""
        hs = [x]
        if x.dim() != 2:
            for w, b, act in self.layers:
                z = F.linear(hs[-1], w, b)
                hs.append(z if act is None else th.tanh(z) if act == "tanh" else th.relu(z))
            return hs
        addmm = th.addmm
        for b, wt, act in self._fwd:
            z = addmm(b, hs[-1], wt)
            # in place on the fresh addmm output: relu_/tanh_ run relu's/tanh's kernel (clamp_min(0), tanh) on it
            hs.append(z if act is None else z.relu_() if act == "relu" else z.tanh_())
        return hs

    def backward(self, g: th.Tensor, hs: list[th.Tensor], grads: dict | None, need_input: bool = False):
        """Store dLoss/dparams in ``grads`` (unless None) given dLoss/dout ``g``; return dLoss/dinput if asked.
        Activations use autograd's own backward kernels (``tanh_backward``, ``threshold_backward``)."""
        for i in range(len(self.layers) - 1, -1, -1):
            w, b, act = self.layers[i]
            if act == "tanh":
                g = _tanh_backward(g, hs[i + 1])
            elif act == "relu":
                g = _threshold_backward(g, hs[i + 1], 0)
            if grads is not None:
                grads[id(w)] = g.t().mm(hs[i])
                grads[id(b)] = g.sum(0)
            if i == 0:
                return g.mm(w) if need_input else None
            g = g.mm(w)
        return None


def _flat_box(model: Any) -> bool:
    space = model.observation_space
    mods = [model.policy, model.actor, model.critic]
    extractors = [getattr(m, "features_extractor", None) for m in mods]
    flat = all(e is None or type(e) is FlattenExtractor for e in extractors)
    return (
        flat and isinstance(space, spaces.Box) and len(space.shape) == 1 and isinstance(model.action_space, spaces.Box)
    )


def _q_nets(critic: nn.Module) -> list[_Net] | None:
    nets = [_Net.of(q) for q in critic.q_networks]
    if any(n is None for n in nets):
        return None
    if {id(p) for n in nets for p in n.params} != {id(p) for p in critic.parameters()}:
        return None
    return nets  # type: ignore[return-value]


def _q_forward(nets: list[_Net], obs: th.Tensor, actions: th.Tensor) -> tuple[th.Tensor, list[list[th.Tensor]]]:
    """Q-values (B, n_critics) of ``ContinuousCritic.forward`` and the per-net caches."""
    x = th.cat([obs, actions], dim=1)
    caches = [n.forward(x) for n in nets]
    return th.cat([c[-1] for c in caches], dim=1), caches


def _set_grads(params: list[nn.Parameter], grads: dict[int, th.Tensor]) -> None:
    for p in params:
        p.grad = grads[id(p)]


def _polyak(params: list[th.Tensor], targets: list[th.Tensor], tau: float, keep: list | None = None) -> None:
    """SB3's ``polyak_update`` in two foreach kernels: target <- (1 - tau) target + tau param.

    ``keep`` (from :func:`_polyak_factor`): the factor ``1 - tau`` as ready 0-dim tensors of the targets' dtype.
    ``mul_`` by the Python scalar wraps it and converts it to that dtype per target on every call; by the
    converted 0-dim tensor it runs the same kernel on the same two values, minus the conversions."""
    th._foreach_mul_(targets, 1 - tau if keep is None else keep)
    th._foreach_add_(targets, params, alpha=tau)


def _polyak_factor(targets: list[th.Tensor], tau: float) -> list[th.Tensor] | None:
    """``keep`` for :func:`_polyak`: ``[tensor(1 - tau)] * n`` (CPU, 0-dim, the targets' one dtype) or None."""
    if not targets or any(t.device.type != "cpu" or t.dtype != targets[0].dtype for t in targets):
        return None
    return [th.tensor(1 - tau, dtype=targets[0].dtype)] * len(targets)


def _replay_sample(model: Any, batch_size: int) -> tuple[th.Tensor, ...]:
    """``model.replay_buffer.sample(batch_size, env=model._vec_normalize_env)`` as (obs, actions, next_obs,
    dones, rewards, discounts): the same numpy draws and arithmetic, without the buffer's per-sample deep
    copies and tensor copies. Buffers other than SB3's plain ``ReplayBuffer`` use their own ``sample``."""
    buf, env = model.replay_buffer, model._vec_normalize_env
    if type(buf) is not ReplayBuffer or buf.optimize_memory_usage or isinstance(buf.observations, dict):
        d = buf.sample(batch_size, env=env)
        disc = d.discounts if d.discounts is not None else model.gamma
        return d.observations, d.actions, d.next_observations, d.dones, d.rewards, disc
    inds = np.random.randint(0, buf.buffer_size if buf.full else buf.pos, size=batch_size)
    envs = np.random.randint(0, high=buf.n_envs, size=(len(inds),))
    arrays = (buf.observations, buf.next_observations, buf.actions, buf.rewards, buf.dones, buf.timeouts)
    if all(a.flags.c_contiguous for a in arrays):
        # a[inds, envs] of a C-contiguous (buffer_size, n_envs, ...) array = rows inds * n_envs + envs of its
        # (buffer_size * n_envs, ...) view: the same elements, copied by one take instead of advanced indexing
        rows = inds * buf.n_envs + envs
        picked = [a.reshape(a.shape[0] * a.shape[1], *a.shape[2:]).take(rows, axis=0) for a in arrays]
    else:
        picked = [a[inds, envs] for a in arrays]
    obs, next_obs, actions, rewards, dones, timeouts = picked
    rewards = rewards.reshape(-1, 1)
    if env is not None:
        if env.norm_obs:
            obs = env._normalize_obs(obs, env.obs_rms).astype(np.float32)
            next_obs = env._normalize_obs(next_obs, env.obs_rms).astype(np.float32)
        rewards = env.normalize_reward(rewards).astype(np.float32)
    dones = (dones * (1 - timeouts)).reshape(-1, 1)
    arrays = (obs, actions, next_obs, dones, rewards)
    return (*(th.from_numpy(np.ascontiguousarray(a)) for a in arrays), model.gamma)


class _AdamSteps:
    """``optimizer.step()`` after ``p.grad = grads[id(p)]`` for each of ``params`` (all of the optimiser's), per
    call; with a fused Adam (:class:`_FusedAdamStep`) the gradients go to its kernels directly and the ``p.grad``
    of the last step are set once, by :meth:`finish` (what the per-step assignments would have left)."""

    def __init__(self, optimizer: th.optim.Optimizer, params: list[nn.Parameter]):
        self.params = params
        self.fused = _FusedAdamStep(optimizer)
        self.direct = self.fused.ok and self.fused.covers(params)
        self.pending: dict[int, th.Tensor] | None = None

    def __call__(self, grads: dict[int, th.Tensor]) -> None:
        if self.direct and self.fused.step_grads(grads):
            self.pending = grads
            return
        _set_grads(self.params, grads)  # e.g. a fresh optimiser: Optimizer.step() initialises its state
        self.pending = None
        self.fused()

    def finish(self) -> None:
        if self.pending is not None:
            _set_grads(self.params, self.pending)
            self.pending = None


def _mean(xs: list[th.Tensor]) -> float:
    return float(th.stack([x.reshape(()) for x in xs]).double().mean())


class _Numbers:
    """The Python-number operands of the closed-form SAC/DDPG updates as ready 0-dim tensors of one dtype.

    ``t * 0.5`` (any binary op or comparison of a tensor with a Python number) wraps 0.5 in a 0-dim tensor that
    ATen's TensorIterator converts to ``t``'s dtype (``static_cast``, round to nearest) before it runs the op's
    kernel on the two values. ``t * n(0.5)`` hands the kernel that converted 0-dim tensor itself: the same
    kernel, the same two values, minus the wrapping and the conversion (~1.3 µs per op). Use it only with
    tensors of exactly ``dtype`` (with another dtype the promotion, hence the arithmetic, would differ)."""

    def __init__(self, dtype: th.dtype):
        self.dtype = dtype
        self._made: dict[float, th.Tensor] = {}

    def __call__(self, value: float) -> th.Tensor:
        t = self._made.get(value)
        if t is None:
            t = self._made[value] = th.tensor(value, dtype=self.dtype)
        return t

    def of(self, value: Any, like: th.Tensor) -> Any:
        """``self(value)`` if ``value`` is a Python number and ``like`` has this dtype, else ``value`` as is."""
        if like.dtype != self.dtype or type(value) not in (int, float):
            return value
        return self(value)


class _SACNets:
    """Closed-form view of an SB3 ``SACPolicy`` (MLP latent, Linear mu / log_std heads, MLP Q-networks)."""

    def __init__(self, model: SAC, latent: _Net, critic: list[_Net], target: list[_Net]):
        self.latent, self.critic, self.target = latent, critic, target
        self.mu: nn.Linear = model.actor.mu
        self.log_std: nn.Linear = model.actor.log_std
        self.mu_wt, self.log_std_wt = self.mu.weight.detach().t(), self.log_std.weight.detach().t()  # as _Net's
        # the actor's arithmetic runs in its parameters' dtype (observations are cast by preprocess_obs = float())
        n = self.num = _Numbers(self.mu.weight.dtype)
        self.two, self.one, self.tiny, self.log_sqrt_2pi = n(2), n(1), n(1e-6), n(_LOG_SQRT_2PI)
        self.ls_min, self.ls_max = n(-20), n(2)
        self.actor_params = list(model.actor.parameters())
        self.critic_params = list(model.critic.parameters())
        self.target_params = list(model.critic_target.parameters())

    @staticmethod
    def build(model: SAC) -> _SACNets | None:
        actor = model.actor
        if model.use_sde or not _flat_box(model) or model.batch_norm_stats:
            return None
        if type(actor.mu) is not nn.Linear or type(actor.log_std) is not nn.Linear:
            return None
        latent = _Net.of(actor.latent_pi)
        critic, target = _q_nets(model.critic), _q_nets(model.critic_target)
        if latent is None or critic is None or target is None or latent.layers[-1][2] is None:
            return None
        heads = [*actor.mu.parameters(), *actor.log_std.parameters()]
        if {id(p) for p in (*latent.params, *heads)} != {id(p) for p in actor.parameters()}:
            return None
        return _SACNets(model, latent, critic, target)

    def act(self, obs: th.Tensor) -> th.Tensor:
        """``actor(obs, deterministic=False)``: the squashed sample, same torch draw and formulas."""
        latent = self.latent.forward(obs)[-1]
        mean = th.addmm(self.mu.bias, latent, self.mu_wt)
        std = th.clamp(th.addmm(self.log_std.bias, latent, self.log_std_wt), -20, 2).exp_()  # see actor_forward
        return th.tanh(mean + th.empty(mean.shape, dtype=mean.dtype, device=mean.device).normal_() * std)

    def actor_forward(self, obs: th.Tensor) -> dict[str, Any]:
        """SB3's ``actor.action_log_prob(obs)``: same torch RNG draw, same formulas, plus a cache."""
        hs = self.latent.forward(obs)
        latent = hs[-1]
        mean = th.addmm(self.mu.bias, latent, self.mu_wt)
        raw_ls = th.addmm(self.log_std.bias, latent, self.log_std_wt)
        # SB3's LOG_STD_MIN, LOG_STD_MAX; SB3 (Normal's broadcast) multiplies by ones_like(mean): 1.0 * x == x in
        # IEEE arithmetic, so the product is omitted; exp_ = exp's kernel, in place on clamp's fresh output
        std = th.clamp(raw_ls, -20, 2).exp_()
        eps = th.empty(mean.shape, dtype=mean.dtype, device=mean.device).normal_()  # Normal.rsample's draw
        u = mean + eps * std
        a = th.tanh(u)
        diff, var = u - mean, std**2
        # the numbers as _Numbers: -(diff**2) / (2 * var) - std.log() - _LOG_SQRT_2PI, 1 - a**2 + 1e-6
        log_prob = (-(diff**2) / (self.two * var) - std.log() - self.log_sqrt_2pi).sum(dim=1)
        squash = th.rsub(a**2, self.one) + self.tiny
        log_prob = log_prob - th.sum(th.log(squash), dim=1)
        return dict(hs=hs, raw_ls=raw_ls, std=std, var=var, eps=eps, a=a, diff=diff, squash=squash, log_prob=log_prob)

    def actor_grads(self, f: dict[str, Any], g_a: th.Tensor, g_lp: th.Tensor) -> dict[int, th.Tensor]:
        """dLoss/dactor-params from dLoss/daction (B, A) and dLoss/dlog_prob (B,) (reparameterised sample)."""
        a, diff, var, std = f["a"], f["diff"], f["var"], f["std"]
        gl = g_lp[:, None]
        g_a = g_a + gl * (self.two * a / f["squash"])  # from -sum log(1 - a^2 + eps)
        g_u = g_a * th.rsub(a * a, self.one)  # through tanh: (1 - a * a)
        dens_u = gl * (diff / var)  # the Gaussian density: d/du = -diff/var, d/dmean = +diff/var
        g_ud = g_u - dens_u  # one tensor for both uses (the same values)
        g_mean = g_ud + dens_u
        # d(-log std)/d std = -1/std: autograd's reciprocal() * 1, and x * 1 == x
        g_std = g_ud * f["eps"] + gl * (diff * diff / (var * std) - std.reciprocal())
        raw = f["raw_ls"]
        g_ls = g_std * std * ((raw >= self.ls_min) & (raw <= self.ls_max))  # clamp's gradient mask [-20, 2]
        latent = f["hs"][-1]
        grads = {
            id(self.mu.weight): g_mean.t().mm(latent),
            id(self.mu.bias): g_mean.sum(0),
            id(self.log_std.weight): g_ls.t().mm(latent),
            id(self.log_std.bias): g_ls.sum(0),
        }
        self.latent.backward(g_mean.mm(self.mu.weight) + g_ls.mm(self.log_std.weight), f["hs"], grads)
        return grads


class _LeanExploration:
    """``_sample_action`` of SB3 2.9's off-policy algorithms with ``predict`` in closed form: the same actor
    output, the same (un)scaling round trip and action noise, and the eval-mode switch only when needed.
    Warm-up (random actions), gSDE and anything unusual go through SB3's own code."""

    _actor_cache: tuple[int, Any] | None = None  # (id(policy), closed-form actor): rebuilt on demand, never saved

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_actor_cache"]  # type: ignore[misc]

    def __getstate__(self) -> dict[str, Any]:  # copy.deepcopy / pickle: without the cache (views of the weights)
        state = dict(self.__dict__)
        state.pop("_actor_cache", None)
        return state

    def _closed_form_actor(self) -> Any:
        raise NotImplementedError

    def _sample_action(self, learning_starts: int, action_noise: Any = None, n_envs: int = 1):
        policy = self.policy
        lean = (
            self.num_timesteps >= learning_starts
            and not self.use_sde
            and isinstance(self.action_space, spaces.Box)
            and isinstance(self._last_obs, np.ndarray)
            and policy.squash_output
        )
        if lean:
            if self._actor_cache is None or self._actor_cache[0] != id(policy):
                self._actor_cache = (id(policy), self._closed_form_actor())
            act = self._actor_cache[1]
        if not lean or act is None:
            return super()._sample_action(learning_starts, action_noise, n_envs)  # type: ignore[misc]
        if policy.training:
            policy.set_training_mode(False)  # as predict() does
        obs = np.array(self._last_obs).reshape((-1, *self.observation_space.shape))
        with th.no_grad():
            actions = act(obs_as_tensor(obs, self.device).float())
        unscaled = policy.unscale_action(actions.cpu().numpy().reshape((-1, *self.action_space.shape)))
        scaled = policy.scale_action(unscaled)
        if action_noise is not None:
            scaled = np.clip(scaled + action_noise(), -1, 1)
        return policy.unscale_action(scaled), scaled


class FastSAC(_LeanExploration, SAC):
    """SB3 ``SAC`` whose ``train()`` computes the same losses and gradients in closed form (no autograd graph,
    foreach Polyak update, no per-step ``.item()``); SB3's own ``train()`` for unusual policies.

    >>> import gymnasium as gym
    >>> m = FastSAC("MlpPolicy", gym.make("InvertedPendulum-v5"), learning_starts=10, seed=0)
    >>> _ = m.learn(20)
    >>> m.fast_path
    True
    """

    fast_path: bool | None = None

    def _closed_form_actor(self) -> Any:
        nets = _SACNets.build(self)
        return None if nets is None else nets.act

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        """Drop-in for ``SAC.train``: ``gradient_steps`` updates of critic, actor (and entropy coefficient)."""
        nets = _SACNets.build(self)
        self.fast_path = nets is not None
        if nets is None:
            return super().train(gradient_steps, batch_size)
        self.policy.set_training_mode(True)
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        if self.ent_coef_optimizer is not None:
            optimizers += [self.ent_coef_optimizer]
        self._update_learning_rate(optimizers)
        ent_coef_losses, ent_coefs, actor_losses, critic_losses = [], [], [], []
        n_obs = int(self.observation_space.shape[0])
        self._actor_cache = (id(self.policy), nets.act)  # exploration: the views of this build
        actor_params, critic_params, target_params = nets.actor_params, nets.critic_params, nets.target_params
        critic_nets, target_nets = nets.critic, nets.target
        actor_step = _AdamSteps(self.actor.optimizer, actor_params)
        critic_step = _AdamSteps(self.critic.optimizer, critic_params)
        keep = _polyak_factor(target_params, self.tau)
        auto_ent = self.ent_coef_optimizer is not None and self.log_ent_coef is not None
        rsub, th_min, num = th.rsub, th.min, nets.num
        with th.no_grad():
            for gradient_step in range(gradient_steps):
                obs, actions, next_obs, dones, rewards, discounts = _replay_sample(self, batch_size)
                obs, next_obs = obs.float(), next_obs.float()  # = preprocess_obs
                b = len(obs)
                f = nets.actor_forward(obs)
                log_prob = f["log_prob"].reshape(-1, 1)
                if auto_ent:
                    ent_coef = th.exp(self.log_ent_coef)
                    shifted = log_prob + self.target_entropy
                    ent_coef_losses.append(-(self.log_ent_coef * shifted).mean())
                    self.log_ent_coef.grad = (shifted.sum() * (-1.0 / shifted.numel())).reshape(1)
                    self.ent_coef_optimizer.step()
                else:
                    ent_coef = self.ent_coef_tensor
                ent_coefs.append(ent_coef)
                nf = nets.actor_forward(next_obs)
                next_q, _ = _q_forward(target_nets, next_obs, nf["a"])
                next_q, _ = th_min(next_q, dim=1, keepdim=True)
                next_q = next_q - ent_coef * nf["log_prob"].reshape(-1, 1)
                # rewards + (1 - dones) * gamma * next_q (the numbers as _Numbers where the dtypes allow)
                not_done = rsub(dones, num.of(1, dones))
                target_q = rewards + not_done * num.of(discounts, not_done) * next_q
                # critic: 0.5 * sum_k mean((q_k - y)^2)
                q, caches = _q_forward(critic_nets, obs, actions)
                td = q - target_q  # one tensor for the logged loss and the gradient (the same values)
                critic_losses.append(num.of(0.5, td) * (td**2).mean(0).sum())
                g_q = td * num.of(1.0 / b, td)
                grads: dict[int, th.Tensor] = {}
                for k, net in enumerate(critic_nets):
                    net.backward(g_q[:, k : k + 1], caches[k], grads)
                critic_step(grads)
                # actor: mean(alpha * log_prob - min_k q_k(s, a~pi)) with the updated critic
                q_pi, caches = _q_forward(critic_nets, obs, f["a"])
                min_q, idx = th_min(q_pi, dim=1, keepdim=True)
                actor_losses.append((ent_coef * log_prob - min_q).mean())
                g_a = th.zeros_like(f["a"])
                for k, net in enumerate(critic_nets):
                    g_k = (idx == k).to(q_pi.dtype) * num.of(-1.0 / b, q_pi)
                    g_a = g_a + net.backward(g_k, caches[k], None, need_input=True)[:, n_obs:]
                g_lp = (ent_coef * num.of(1.0 / b, ent_coef)).expand(b)
                actor_step(nets.actor_grads(f, g_a, g_lp))
                if gradient_step % self.target_update_interval == 0:
                    _polyak(critic_params, target_params, self.tau, keep)
        critic_step.finish()
        actor_step.finish()
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/ent_coef", _mean(ent_coefs))
        self.logger.record("train/actor_loss", _mean(actor_losses))
        self.logger.record("train/critic_loss", _mean(critic_losses))
        if ent_coef_losses:
            self.logger.record("train/ent_coef_loss", _mean(ent_coef_losses))


class FastDDPG(_LeanExploration, DDPG):
    """SB3 ``DDPG`` (= TD3 with one critic, no target smoothing, no policy delay) whose ``train()`` computes
    the same update in closed form; SB3's own ``train()`` for unusual policies. Any TD3 setting of the
    parent is honoured (``policy_delay``, ``target_policy_noise``, ``n_critics``)."""

    fast_path: bool | None = None

    def _closed_form_actor(self) -> Any:
        nets = self._fast_nets()
        return None if nets is None else (lambda obs: nets[0].forward(obs)[-1])

    def _fast_nets(self) -> tuple[_Net, _Net, list[_Net], list[_Net]] | None:
        if not _flat_box(self) or self.actor_batch_norm_stats or self.critic_batch_norm_stats:
            return None
        actor, actor_t = _Net.of(self.actor.mu), _Net.of(self.actor_target.mu)
        critic, critic_t = _q_nets(self.critic), _q_nets(self.critic_target)
        if actor is None or actor_t is None or critic is None or critic_t is None:
            return None
        if {id(p) for p in actor.params} != {id(p) for p in self.actor.parameters()}:
            return None
        return actor, actor_t, critic, critic_t

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        """Drop-in for ``TD3.train``."""
        nets = self._fast_nets()
        self.fast_path = nets is not None
        if nets is None:
            return super().train(gradient_steps, batch_size)
        actor, actor_t, critic, critic_t = nets
        actor_params, critic_params = list(self.actor.parameters()), list(self.critic.parameters())
        actor_targets, critic_targets = list(self.actor_target.parameters()), list(self.critic_target.parameters())
        self.policy.set_training_mode(True)
        self._update_learning_rate([self.actor.optimizer, self.critic.optimizer])
        actor_losses, critic_losses = [], []
        n_obs = int(self.observation_space.shape[0])
        self._actor_cache = (id(self.policy), lambda obs: actor.forward(obs)[-1])  # exploration: this build's views
        actor_step = _AdamSteps(self.actor.optimizer, actor_params)
        critic_step = _AdamSteps(self.critic.optimizer, critic_params)
        keep_critic, keep_actor = _polyak_factor(critic_targets, self.tau), _polyak_factor(actor_targets, self.tau)
        num = _Numbers(critic_params[0].dtype)
        with th.no_grad():
            for _ in range(gradient_steps):
                self._n_updates += 1
                obs, actions, next_obs, dones, rewards, discounts = _replay_sample(self, batch_size)
                obs, next_obs = obs.float(), next_obs.float()  # = preprocess_obs
                b = len(obs)
                noise = actions.clone().normal_(0, self.target_policy_noise)  # SB3's draw, even if 0
                noise = noise.clamp(-self.target_noise_clip, self.target_noise_clip)
                next_actions = (actor_t.forward(next_obs)[-1] + noise).clamp(-1, 1)
                next_q, _ = _q_forward(critic_t, next_obs, next_actions)
                next_q, _ = th.min(next_q, dim=1, keepdim=True)
                # rewards + (1 - dones) * gamma * next_q (the numbers as _Numbers where the dtypes allow)
                not_done = th.rsub(dones, num.of(1, dones))
                target_q = rewards + not_done * num.of(discounts, not_done) * next_q
                q, caches = _q_forward(critic, obs, actions)
                td = q - target_q  # one tensor for the logged loss and the gradient (the same values)
                critic_losses.append((td**2).mean(0).sum())  # sum_k mean((q_k - y)^2)
                g_q = td * num.of(2.0 / b, td)
                grads: dict[int, th.Tensor] = {}
                for k, net in enumerate(critic):
                    net.backward(g_q[:, k : k + 1], caches[k], grads)
                critic_step(grads)
                if self._n_updates % self.policy_delay == 0:
                    hs = actor.forward(obs)
                    q1_cache = critic[0].forward(th.cat([obs, hs[-1]], dim=1))
                    actor_losses.append(-q1_cache[-1].mean())
                    g_in = critic[0].backward(th.full_like(q1_cache[-1], -1.0 / b), q1_cache, None, need_input=True)
                    grads = {}
                    actor.backward(g_in[:, n_obs:], hs, grads)
                    actor_step(grads)
                    _polyak(critic_params, critic_targets, self.tau, keep_critic)
                    _polyak(actor_params, actor_targets, self.tau, keep_actor)
        critic_step.finish()
        actor_step.finish()
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        if actor_losses:
            self.logger.record("train/actor_loss", _mean(actor_losses))
        self.logger.record("train/critic_loss", _mean(critic_losses))
