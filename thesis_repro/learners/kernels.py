"""The fast learners' kernels: the closed-form actor-critic forward and PPO gradient, and the fused Adam step.

:class:`_ManualActorCritic` writes out, for the kit's policies (SB3 ``MlpExtractor`` or the SCN extractor,
Linear+Tanh/ReLU layers, flat Box observations, diagonal Gaussian without gSDE), the forward pass and the gradient
of the clipped PPO loss, so :func:`~thesis_repro.learners.fast.ppo_epochs` builds no autograd graph;
:class:`_FusedAdamStep` is a fused CPU Adam's ``step()`` without its per-call Python, shared with the off-policy
learners (:mod:`thesis_repro.learners.fast_offpolicy`). ``tests/test_fast.py`` proves both equal to autograd and
``Optimizer.step``.
"""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import torch as th
from gymnasium import spaces
from stable_baselines3.common.distributions import DiagGaussianDistribution
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import FlattenExtractor, MlpExtractor
from torch import nn

from thesis_repro.learners.policies import SCNExtractor

_LOG_SQRT_2PI = math.log(math.sqrt(2 * math.pi))


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


def _clip_grads(params: list[nn.Parameter], max_norm: float) -> None:
    """``clip_grad_norm_(params, max_norm, foreach=True)`` on a known non-empty parameter list."""
    _clip_grad_list([p.grad for p in params if p.grad is not None], max_norm)


def _clip_grad_list(grads: list[th.Tensor], max_norm: float) -> None:
    """:func:`_clip_grads` on the gradient tensors themselves (scaled in place)."""
    if not grads:
        return
    total = th.linalg.vector_norm(th.stack(th._foreach_norm(grads, 2.0)), 2.0)
    th._foreach_mul_(grads, th.clamp((total + 1e-6).reciprocal() * max_norm, max=1.0))  # = max_norm / (total + 1e-6)
