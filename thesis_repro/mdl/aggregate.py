"""Aggregation of sub-policies for multi-domain learning (thesis §4.2, Eq 4.6-4.11), in torch.

A policy is seen through a :class:`PolicyView`: the flat vector θ of the parameters that shape the
diagonal-Gaussian action distribution, and a function ``θ, states -> (mean, log_std)``. On top of it:

* :func:`params_avg` — Eq 4.6, the arithmetic mean of the sub-policies' parameters;
* :func:`fisher_vector_product` — ``I(θ) v`` of the expected Fisher information (Eq 4.9) without
  forming the matrix: for a diagonal Gaussian, ``I = E_s[J_μᵀ Σ⁻¹ J_μ + 2 J_ℓᵀ J_ℓ]`` (ℓ = log σ),
  computed with one forward-mode and one reverse-mode product (autograd, any policy: the reference);
* :class:`FisherProducts` — the same products for N policies θ_1..θ_N at once, in closed form through
  the MLP's layers when the view is a tanh/ReLU MLP Gaussian (SB3 ``MlpPolicy``, :class:`GaussianPolicy`):
  one batched forward cache per aggregation, then each product is a few batched matmuls (no autograd);
* :func:`kl_avg` — Eq 4.10/4.11 solved by conjugate gradient with those products;
  :func:`kl_avg_dense` is the dense reference solve for tiny networks.

The exact minimiser of Eq 4.7 (``kl_exact``, the kit's own) and the linear-Gaussian closed forms are
:mod:`thesis_repro.mdl.exact`.

>>> import torch
>>> pol = GaussianPolicy(3, 2, hidden=(4,), seed=0)
>>> view = PolicyView(pol)
>>> s = torch.randn(32, 3, generator=torch.Generator().manual_seed(0))
>>> t0 = view.get_flat()
>>> thetas = [t0 + 0.01 * torch.randn(t0.shape, generator=torch.Generator().manual_seed(i)) for i in range(3)]
>>> new = kl_avg(view, thetas, s, t0, cg_iters=50, damping=0.1)
>>> bool(torch.allclose(new, kl_avg_dense(view, thetas, s, damping=0.1), atol=1e-4))
True
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import NamedTuple

import torch
import torch.nn.functional as F
from gymnasium import spaces
from stable_baselines3.common.distributions import DiagGaussianDistribution
from stable_baselines3.common.torch_layers import FlattenExtractor
from torch import Tensor, nn
from torch.func import functional_call, jacrev, jvp, vjp

from thesis_repro.core.validation import check_nonneg

DistFn = Callable[[nn.Module, Tensor], tuple[Tensor, Tensor]]

#: SB3 ``ActorCriticPolicy`` parameter prefixes that shape the action distribution / the value.
SB3_ACTOR_PREFIXES: tuple[str, ...] = (
    "features_extractor.",
    "pi_features_extractor.",
    "mlp_extractor.policy_net.",
    "action_net.",
    "log_std",
)
SB3_CRITIC_PREFIXES: tuple[str, ...] = ("vf_features_extractor.", "mlp_extractor.value_net.", "value_net.")


class GaussianPolicy(nn.Module):
    """Small tanh-MLP diagonal-Gaussian policy (mean net + state-independent log-std), for tests and docs.

    >>> m, ls = GaussianPolicy(3, 2, hidden=(8,), seed=1)(torch.zeros(5, 3))
    >>> tuple(m.shape), tuple(ls.shape)
    ((5, 2), (5, 2))
    """

    def __init__(
        self, obs_dim: int, act_dim: int, hidden: Sequence[int] = (64, 64), seed: int = 0, log_std_init: float = 0.0
    ):
        super().__init__()
        if obs_dim < 1 or act_dim < 1 or any(h < 1 for h in hidden):
            raise ValueError(f"dimensions must be >= 1, got obs_dim={obs_dim}, act_dim={act_dim}, hidden={hidden}")
        gen = torch.Generator().manual_seed(seed)
        layers: list[nn.Module] = []
        last = obs_dim
        for h in hidden:
            layers += [nn.Linear(last, h), nn.Tanh()]
            last = h
        layers.append(nn.Linear(last, act_dim))
        self.mean_net = nn.Sequential(*layers)
        with torch.no_grad():
            for p in self.mean_net.parameters():
                p.copy_(torch.randn(p.shape, generator=gen) / math.sqrt(max(p.shape[-1], 1)))
        self.log_std = nn.Parameter(torch.full((act_dim,), float(log_std_init)))

    def forward(self, states: Tensor) -> tuple[Tensor, Tensor]:
        mean = self.mean_net(states)
        return mean, self.log_std.expand_as(mean)


def _sb3_dist(policy: nn.Module, states: Tensor) -> tuple[Tensor, Tensor]:
    features = policy.extract_features(states, policy.pi_features_extractor)  # type: ignore[operator]
    mean = policy.action_net(policy.mlp_extractor.forward_actor(features))  # type: ignore[operator]
    return mean, policy.log_std.expand_as(mean)  # type: ignore[union-attr]


class _Head(nn.Module):
    def __init__(self, module: nn.Module, fn: DistFn):
        super().__init__()
        self.p = module
        self._fn = fn

    def forward(self, states: Tensor) -> tuple[Tensor, Tensor]:
        return self._fn(self.p, states)


class MLPSpec(NamedTuple):
    """Layer structure of an MLP Gaussian head: mean = Linear_L(act(... act(Linear_1(s)))), log-std a parameter.

    ``linears``: (weight name, bias name or None) of each Linear, input to output; ``activations``: ``"tanh"``
    or ``"relu"`` after each Linear but the last (the mean is linear in the last hidden layer).
    """

    linears: tuple[tuple[str, str | None], ...]
    activations: tuple[str, ...]
    log_std: str


_ACTIVATIONS: dict[type, str] = {nn.Tanh: "tanh", nn.ReLU: "relu"}


def _sequential_spec(modules: Sequence[tuple[str, nn.Module]]) -> tuple[list, list] | None:
    """(linears, activations) of ``[(prefix, module), ...]`` alternating Linear / activation, else None."""
    linears: list[tuple[str, str | None]] = []
    acts: list[str] = []
    for prefix, mod in modules:
        if isinstance(mod, nn.Linear):
            if len(acts) != len(linears):  # two Linears in a row
                return None
            linears.append((f"{prefix}weight", f"{prefix}bias" if mod.bias is not None else None))
        elif type(mod) in _ACTIVATIONS:
            if len(acts) != len(linears) - 1:  # an activation not right after a Linear
                return None
            acts.append(_ACTIVATIONS[type(mod)])
        else:
            return None
    return linears, acts


def _finish_spec(linears: list, acts: list, names: Sequence[str], log_std: str) -> MLPSpec | None:
    if not linears or len(acts) != len(linears) - 1:
        return None
    covered = [n for pair in linears for n in pair if n is not None] + [log_std]
    if sorted(covered) != sorted(names):  # θ must be exactly these parameters
        return None
    return MLPSpec(tuple(linears), tuple(acts), log_std)


def _gaussian_policy_spec(module: nn.Module, names: Sequence[str]) -> MLPSpec | None:
    if not isinstance(module, GaussianPolicy):
        return None
    parsed = _sequential_spec([(f"mean_net.{k}.", m) for k, m in module.mean_net.named_children()])
    return None if parsed is None else _finish_spec(*parsed, names, "log_std")


def _sb3_spec(policy: nn.Module, names: Sequence[str]) -> MLPSpec | None:
    """The closed-form structure of an SB3 ``ActorCriticPolicy`` with a flat Box observation, an MLP actor
    and a state-independent diagonal Gaussian (no gSDE, no squashing); None for anything else."""
    try:
        ok = (
            isinstance(policy.action_dist, DiagGaussianDistribution)
            and not getattr(policy, "use_sde", False)
            and isinstance(policy.observation_space, spaces.Box)
            and len(policy.observation_space.shape) == 1
            and isinstance(policy.pi_features_extractor, FlattenExtractor)
            and isinstance(policy.mlp_extractor.policy_net, nn.Sequential)
            and isinstance(policy.action_net, nn.Linear)
        )
    except AttributeError:
        return None
    if not ok:
        return None
    net = [(f"mlp_extractor.policy_net.{k}.", m) for k, m in policy.mlp_extractor.policy_net.named_children()]
    parsed = _sequential_spec([*net, ("action_net.", policy.action_net)])
    return None if parsed is None else _finish_spec(*parsed, names, "log_std")


class PolicyView:
    """Flat-vector view θ of the distribution parameters of ``module`` and ``dist(θ, states)``.

    ``names`` selects the parameters forming θ (default: all); ``dist_fn(module, states)`` returns
    ``(mean, log_std)`` (default: ``module(states)``). Use :meth:`from_sb3` for an SB3 ``ActorCriticPolicy``.
    ``mlp`` is the :class:`MLPSpec` when θ is exactly an MLP Gaussian head (closed-form Fisher products,
    :class:`FisherProducts`), else None (autograd products).

    >>> view = PolicyView(GaussianPolicy(2, 1, hidden=(3,)))
    >>> view.numel
    14
    """

    def __init__(self, module: nn.Module, names: Sequence[str] | None = None, dist_fn: DistFn | None = None):
        params = dict(module.named_parameters())
        self.names: tuple[str, ...] = tuple(params) if names is None else tuple(names)
        unknown = [n for n in self.names if n not in params]
        if unknown:
            raise ValueError(f"unknown parameter names {unknown}; valid names are: {list(params)}")
        if not self.names:
            raise ValueError("a PolicyView needs at least one parameter")
        self.module = module
        self.shapes = [params[n].shape for n in self.names]
        self.sizes = [params[n].numel() for n in self.names]
        self.numel = sum(self.sizes)
        self._head = _Head(module, dist_fn or (lambda m, s: m(s)))
        self.mlp: MLPSpec | None = _gaussian_policy_spec(module, self.names) if dist_fn is None else None
        self._float_states = False  # SB3 casts observations to float32 before its features extractor

    @classmethod
    def from_sb3(cls, policy: nn.Module) -> PolicyView:
        """View over the actor parameters (features, policy MLP, action net, log-std) of an SB3 policy."""
        names = [n for n, _ in policy.named_parameters() if n.startswith(SB3_ACTOR_PREFIXES)]
        view = cls(policy, names, _sb3_dist)
        view.mlp = _sb3_spec(policy, view.names)
        view._float_states = True
        return view

    def params(self, theta: Tensor) -> dict[str, Tensor]:
        if theta.shape != (self.numel,):
            raise ValueError(f"theta must have shape ({self.numel},), got {tuple(theta.shape)}")
        return {n: t.view(s) for n, t, s in zip(self.names, torch.split(theta, self.sizes), self.shapes, strict=True)}

    def get_flat(self) -> Tensor:
        """Current θ of the module (detached copy)."""
        p = dict(self.module.named_parameters())
        return torch.cat([p[n].detach().reshape(-1) for n in self.names]).clone()

    def set_flat(self, theta: Tensor) -> None:
        """Write θ into the module in place."""
        p = dict(self.module.named_parameters())
        with torch.no_grad():
            for n, t in self.params(theta).items():
                p[n].copy_(t)

    def dist(self, theta: Tensor, states: Tensor) -> tuple[Tensor, Tensor]:
        """``(mean, log_std)``, each of shape (S, A), of π_θ at ``states`` (differentiable in ``theta``).

        An MLP view (``mlp``) runs the same ops as its modules (``F.linear``, tanh/ReLU) directly on the
        slices of θ, without ``functional_call``'s module swapping; other views use ``functional_call``.
        """
        if self.mlp is not None:
            p = self.params(theta)
            x = states.float() if self._float_states else states
            for k, (w, b) in enumerate(self.mlp.linears):
                x = F.linear(x, p[w], None if b is None else p[b])
                if k < len(self.mlp.activations):
                    x = torch.tanh(x) if self.mlp.activations[k] == "tanh" else torch.relu(x)
            return x, p[self.mlp.log_std].expand_as(x)
        full = {f"p.{n}": t for n, t in self.params(theta).items()}
        return functional_call(self._head, full, (states,), strict=False)


# ----------------------------------------------------------------------------------------------- Eq 4.6
def params_avg(thetas: Sequence[Tensor] | Sequence[Mapping[str, Tensor]]) -> Tensor | dict[str, Tensor]:
    """Eq 4.6: θ_new = (1/N) Σ θ_i, for flat tensors or state dicts (every floating entry is averaged).

    >>> params_avg([torch.tensor([0.0, 2.0]), torch.tensor([2.0, 4.0])])
    tensor([1., 3.])
    """
    if len(thetas) == 0:
        raise ValueError("params_avg needs at least one sub-policy")
    if isinstance(thetas[0], Mapping):
        keys = list(thetas[0])
        out = {}
        for k in keys:
            vals = [t[k] for t in thetas]  # type: ignore[index]
            out[k] = torch.stack(vals).mean(0) if vals[0].is_floating_point() else vals[0].clone()
        return out
    return torch.stack(list(thetas)).mean(0)  # type: ignore[arg-type]


# --------------------------------------------------------------------------------- KL, entropy, Fisher
def gaussian_kl(mean_p: Tensor, log_std_p: Tensor, mean_q: Tensor, log_std_q: Tensor) -> Tensor:
    """Per-state KL(N(μ_p, σ_p²) ‖ N(μ_q, σ_q²)) of diagonal Gaussians, summed over action dims."""
    var_p, var_q = torch.exp(2 * log_std_p), torch.exp(2 * log_std_q)
    return (log_std_q - log_std_p + (var_p + (mean_p - mean_q) ** 2) / (2 * var_q) - 0.5).sum(-1)


def _gaussian_kl(
    mean_p: Tensor, log_std_p: Tensor, var_p: Tensor, mean_q: Tensor, log_std_q: Tensor, two_var_q: Tensor
) -> Tensor:
    """:func:`gaussian_kl`'s expression given σ_p² = ``exp(2 log σ_p)`` and 2σ_q² = ``2 * exp(2 log σ_q)`` (the
    same ops; gaussian_kl itself keeps them inline, so the autograd graph of kl_exact's gradient is unchanged)."""
    return (log_std_q - log_std_p + (var_p + (mean_p - mean_q) ** 2) / two_var_q - 0.5).sum(-1)


class _KLToTargets:
    """E_s KL(π_θi ‖ π_θ) of fixed targets θ_1..θ_N at any θ, without an autograd graph: :func:`gaussian_kl`'s
    ops on the same values, with the terms of one distribution computed once instead of once per pair (each
    target's (μ_i, log σ_i, σ_i²) once; θ's (μ, log σ, 2σ²) once per evaluation). The same numbers as
    ``gaussian_kl(*view.dist(θ_i, s), *view.dist(θ, s)).mean()`` per target (tests/test_kl_speed.py)."""

    def __init__(self, view: PolicyView, thetas: Sequence[Tensor], states: Tensor):
        self.view, self.states = view, states
        with torch.no_grad():
            dists = [view.dist(t.detach(), states) for t in thetas]
            self.targets = [(m, ls, torch.exp(2 * ls)) for m, ls in dists]

    def kls(self, theta: Tensor) -> list[Tensor]:
        """``[E_s KL(π_θi(·|s) ‖ π_θ(·|s)) for each target]`` (0-d tensors)."""
        with torch.no_grad():
            mean, log_std = self.view.dist(theta.detach(), self.states)
            two_var = 2 * torch.exp(2 * log_std)
            return [_gaussian_kl(m, ls, vp, mean, log_std, two_var).mean() for m, ls, vp in self.targets]


def mean_kl(view: PolicyView, theta_p: Tensor, theta_q: Tensor, states: Tensor) -> Tensor:
    """E_s[KL(π_θp(·|s) ‖ π_θq(·|s))] over the rows of ``states``."""
    return gaussian_kl(*view.dist(theta_p, states), *view.dist(theta_q, states)).mean()


def eq47_kls(view: PolicyView, theta: Tensor, thetas: Sequence[Tensor], states: Tensor) -> Tensor:
    """Per-sub-policy terms of Eq 4.7: ``[E_s KL(π_θi(·|s) ‖ π_θ(·|s)) for θ_i in thetas]``, shape (N,).

    The thesis's direction: the sub-policy π_θi first, the aggregate π_θ second (Eq 4.7, 4.9).

    >>> view = PolicyView(GaussianPolicy(2, 1, hidden=(3,)))
    >>> t = view.get_flat()
    >>> eq47_kls(view, t, [t, t + 0.1], torch.zeros(4, 2)).shape
    torch.Size([2])
    """
    if len(thetas) == 0:
        raise ValueError("Eq 4.7 needs at least one sub-policy")
    with torch.no_grad():  # = stack([mean_kl(view, t, theta, states) ...]), with π_θ's forward pass once
        q = view.dist(theta.detach(), states)
        return torch.stack([gaussian_kl(*view.dist(t.detach(), states), *q).mean() for t in thetas])


def eq47_objective(view: PolicyView, theta: Tensor, thetas: Sequence[Tensor], states: Tensor) -> float:
    """Eq 4.7's objective F(θ) = Σ_i E_s KL(π_θi(·|s) ‖ π_θ(·|s)) (nats; the sum of :func:`eq47_kls`).

    >>> view = PolicyView(GaussianPolicy(2, 1, hidden=(3,)))
    >>> t = view.get_flat()
    >>> eq47_objective(view, t, [t, t], torch.zeros(4, 2))
    0.0
    """
    return float(eq47_kls(view, theta, thetas, states).sum())


def entropy(view: PolicyView, theta: Tensor, states: Tensor) -> Tensor:
    """E_s[H(π_θ(·|s))] of the diagonal Gaussian (nats)."""
    _, log_std = view.dist(theta, states)
    return (log_std + 0.5 * math.log(2 * math.pi * math.e)).sum(-1).mean()


def fisher_vector_product(view: PolicyView, theta: Tensor, states: Tensor, v: Tensor) -> Tensor:
    """``I(θ) v`` with I(θ) = ∂²/∂θ'² E_s KL(π_θ ‖ π_θ')|θ'=θ = E_s[J_μᵀΣ⁻¹J_μ + 2 J_ℓᵀJ_ℓ] (matrix-free)."""
    theta = theta.detach()

    def f(t: Tensor) -> tuple[Tensor, Tensor]:
        return view.dist(t, states)

    (mean, log_std), (dmu, dls) = jvp(f, (theta,), (v.detach(),))
    _, pull = vjp(f, theta)
    n = states.shape[0]
    (out,) = pull((dmu * torch.exp(-2 * log_std.detach()) / n, 2.0 * dls / n))
    return out


def fisher_matrix(view: PolicyView, theta: Tensor, states: Tensor) -> Tensor:
    """Dense expected FIM (P×P); only for tiny networks (reference for tests)."""
    theta = theta.detach()
    jac_mu, jac_ls = jacrev(lambda t: view.dist(t, states))(theta)  # (S, A, P) each
    _, log_std = view.dist(theta, states)
    w = torch.exp(-2 * log_std.detach())
    n = states.shape[0]
    return (torch.einsum("sap,sa,saq->pq", jac_mu, w, jac_mu) + 2.0 * torch.einsum("sap,saq->pq", jac_ls, jac_ls)) / n


class FisherProducts:
    """``I(θ_i) v`` (Eq 4.9) for N fixed policies θ_1..θ_N on one set of states, batched over the N.

    With an MLP view (``view.mlp``) the products are computed in closed form: the layer activations of every
    θ_i on ``states`` are cached once, then ``I v = (1/S) Σ_s J_μᵀ Σ⁻¹ J_μ v + 2 v_ℓ`` is one forward-mode
    pass (dz_l = x_{l-1} dW_lᵀ + db_l + dx_{l-1} W_lᵀ, dx_l = act'(z_l) ⊙ dz_l) and one reverse pass
    through the N networks as batched matmuls, with no autograd graph. Otherwise each product is
    :func:`fisher_vector_product` (autograd). Both give the same numbers to float rounding
    (``tests/test_aggregate.py``). ``fpv(v)`` takes one (P,) vector for all N or an (N, P) stack and returns
    (N, P); :meth:`mean` is (1/N) Σ_i I(θ_i) v.

    >>> view = PolicyView(GaussianPolicy(3, 2, hidden=(4,), seed=0))
    >>> s = torch.randn(16, 3, generator=torch.Generator().manual_seed(0))
    >>> t = view.get_flat(); v = torch.ones_like(t)
    >>> fp = FisherProducts(view, [t, t + 0.1], s)
    >>> fp.closed_form, tuple(fp(v).shape)
    (True, (2, 28))
    >>> bool(torch.allclose(fp(v)[0], fisher_vector_product(view, t, s, v), atol=1e-5))
    True
    """

    def __init__(self, view: PolicyView, thetas: Sequence[Tensor], states: Tensor):
        if len(thetas) == 0:
            raise ValueError("FisherProducts needs at least one policy")
        self.view, self.states = view, states
        self.thetas = [t.detach() for t in thetas]
        self.n = len(self.thetas)
        self.closed_form = view.mlp is not None
        if self.closed_form:
            self._cache()

    def _split(self, flat: Tensor) -> dict[str, Tensor]:
        """Per-parameter views of an (N, P) stack -> (N, *shape), or of a (P,) vector -> (*shape)."""
        lead = flat.shape[:-1]
        parts = torch.split(flat, self.view.sizes, dim=-1)
        return {n: p.reshape(*lead, *s) for n, p, s in zip(self.view.names, parts, self.view.shapes, strict=True)}

    def _cache(self) -> None:
        spec = self.view.mlp
        assert spec is not None
        p = self._split(torch.stack(self.thetas))
        self._w = [p[w] for w, _ in spec.linears]
        self._b = [None if b is None else p[b] for _, b in spec.linears]
        x = self.states.to(self.thetas[0].dtype)
        self._x: list[Tensor] = [x]  # input of each Linear: (S, d0) shared, then (N, S, d)
        self._d: list[Tensor] = []  # act'(z) of each hidden layer, (N, S, d)
        with torch.no_grad():
            for k, act in enumerate(spec.activations):
                z = x @ self._w[k].transpose(-1, -2)
                if self._b[k] is not None:
                    z = z + self._b[k].unsqueeze(-2)
                if act == "tanh":
                    x = torch.tanh(z)
                    self._d.append(1.0 - x * x)
                else:
                    x = torch.relu(z)
                    self._d.append((z > 0).to(z.dtype))
                self._x.append(x)
            # Σ⁻¹ / S per domain and action dim, shape (N, 1, A)
            self._prec = (torch.exp(-2.0 * p[spec.log_std]) / self.states.shape[0]).unsqueeze(-2)

    def __call__(self, v: Tensor) -> Tensor:
        v = v.detach()
        if v.shape not in ((self.view.numel,), (self.n, self.view.numel)):
            raise ValueError(
                f"v must have shape ({self.view.numel},) or ({self.n}, {self.view.numel}), got {tuple(v.shape)}"
            )
        if not self.closed_form:
            vs = v.expand(self.n, -1)
            return torch.stack(
                [fisher_vector_product(self.view, t, self.states, u) for t, u in zip(self.thetas, vs, strict=True)]
            )
        spec = self.view.mlp
        assert spec is not None
        dv = self._split(v)
        n_layers = len(spec.linears)
        with torch.no_grad():
            dx = None
            for k, (wn, bn) in enumerate(spec.linears):  # forward mode: dμ = J_μ v
                dz = self._x[k] @ dv[wn].transpose(-1, -2)
                if bn is not None:
                    dz = dz + dv[bn].unsqueeze(-2)
                if dx is not None:
                    dz = dz + dx @ self._w[k].transpose(-1, -2)
                if k < n_layers - 1:
                    dx = self._d[k] * dz
            g = dz * self._prec  # (N, S, A): Σ⁻¹ J_μ v / S
            out: dict[str, Tensor] = {}
            for k in range(n_layers - 1, -1, -1):  # reverse mode: J_μᵀ g
                wn, bn = spec.linears[k]
                out[wn] = g.transpose(-1, -2) @ self._x[k]
                if bn is not None:
                    out[bn] = g.sum(-2)
                if k > 0:
                    g = (g @ self._w[k]) * self._d[k - 1]
            out[spec.log_std] = 2.0 * dv[spec.log_std]
        lead = (self.n,)
        return torch.cat(
            [
                out[name].expand(*lead, *shape).reshape(self.n, -1)
                for name, shape in zip(self.view.names, self.view.shapes, strict=True)
            ],
            dim=1,
        )

    def mean(self, v: Tensor) -> Tensor:
        """(1/N) Σ_i I(θ_i) v, shape (P,)."""
        return self(v).mean(0)

    def diagonal(self) -> Tensor:
        """The diagonals of I(θ_1)..I(θ_N), shape (N, P).

        With an MLP view, in closed form: per parameter, (1/S) Σ_s Σ_a σ_a⁻² (∂μ_a(s)/∂θ_p)² (2 for each log σ
        entry), by one reverse pass of all A action outputs at once through the cached activations; otherwise
        the diagonal of :func:`fisher_matrix` (tiny networks only).
        """
        if not self.closed_form:
            return torch.stack([torch.diagonal(fisher_matrix(self.view, t, self.states)) for t in self.thetas])
        spec = self.view.mlp
        assert spec is not None
        n_states, n_act = self.states.shape[0], self._w[-1].shape[-2]
        weight = self._prec.unsqueeze(-1)  # (N, 1, A, 1): σ_a⁻² / S
        out: dict[str, Tensor] = {}
        with torch.no_grad():
            eye = torch.eye(n_act, dtype=self._prec.dtype)
            g = eye.expand(self.n, n_states, n_act, n_act)  # ∂μ_a/∂z_L, (N, S, A, d_L)
            for k in range(len(spec.linears) - 1, -1, -1):
                wn, bn = spec.linears[k]
                h = (weight * g * g).sum(-2)  # (N, S, d_k): Σ_a σ_a⁻² (∂μ_a/∂z_k)² / S
                out[wn] = h.transpose(-1, -2) @ (self._x[k] * self._x[k])
                if bn is not None:
                    out[bn] = h.sum(-2)
                if k > 0:
                    g = (g @ self._w[k].unsqueeze(1)) * self._d[k - 1].unsqueeze(-2)
            out[spec.log_std] = torch.full(self.view.params(self.thetas[0])[spec.log_std].shape, 2.0)
        return torch.cat(
            [
                out[name].expand(self.n, *shape).reshape(self.n, -1)
                for name, shape in zip(self.view.names, self.view.shapes, strict=True)
            ],
            dim=1,
        )


# ----------------------------------------------------------------------------------------- Eq 4.10/4.11
#: Fractions of the Eq 4.11 correction that :func:`kl_avg`'s line search tries, largest first; 0 is params_avg.
LINE_SEARCH_FRACTIONS: tuple[float, ...] = (*(2.0**-k for k in range(11)), 0.0)


def conjugate_gradient(
    avp: Callable[[Tensor], Tensor], b: Tensor, iters: int = 10, rtol: float = 1e-6
) -> tuple[Tensor, float]:
    """Solve A x = b for symmetric positive (semi-)definite A given ``avp(v) = A v``; returns (x, ‖r‖).

    Stops after ``iters`` products or once ‖r‖ ≤ ``rtol``·‖b‖ (a RELATIVE tolerance: the same ``rtol``
    means the same accuracy whatever the scale of ``b``).

    >>> a = torch.tensor([[4.0, 1.0], [1.0, 3.0]])
    >>> x, res = conjugate_gradient(lambda v: a @ v, torch.tensor([1.0, 2.0]), iters=5)
    >>> [round(v, 4) for v in x.tolist()]
    [0.0909, 0.6364]
    """
    if iters < 1:
        raise ValueError(f"cg iters must be >= 1, got {iters}")
    rtol = check_nonneg(rtol, "cg_rtol")
    x = torch.zeros_like(b)
    r = b.clone()
    p = r.clone()
    rr = r @ r
    stop = (rtol * b.norm()) ** 2
    for _ in range(iters):
        if rr <= stop:
            break
        ap = avp(p)
        denom = p @ ap
        if denom <= 0:
            break
        alpha = rr / denom
        x = x + alpha * p
        r = r - alpha * ap
        rr_new = r @ r
        p = r + (rr_new / rr) * p
        rr = rr_new
    return x, float(rr.sqrt())


def kl_avg(
    view: PolicyView,
    thetas: Sequence[Tensor],
    states: Tensor,
    theta_old: Tensor | None = None,
    cg_iters: int = 10,
    damping: float = 0.1,
    info: dict | None = None,
    line_search: bool = False,
    cg_rtol: float = 1e-6,
) -> Tensor:
    """Eq 4.11: θ_new = θ_old + ḡ + [Ī + λ·1]⁻¹ (1/N) Σ I(θ_i)(g_i − ḡ), Ī = (1/N) Σ I(θ_i), by CG with FVPs.

    g_i = θ_i − θ_old; the FIMs are estimated on ``states`` (the θ_old rollouts). Dividing both sides of
    Eq 4.11 by N changes nothing at λ = 0; it makes the damping λ ≥ 0 act on the MEAN Fisher, like TRPO's
    ``cg_damping`` (0.1, Appendix A). θ_old cancels (θ_old + ḡ = mean θ_i); λ shrinks the correction
    towards zero, i.e. towards :func:`params_avg` (λ → ∞ gives Eq 4.6). With λ = 0 and enough iterations
    this is Eq 4.10, the argmin of Σ_i (θ_i − θ)ᵀ I(θ_i) (θ_i − θ) (Eq 4.8).

    ``line_search`` (off by default; not in the thesis) backtracks the correction (fractions
    :data:`LINE_SEARCH_FRACTIONS`: 1, ½, ..., 2⁻¹⁰, then 0) until the TRUE objective of Eq 4.7,
    Σ_i E_s KL(π_θi ‖ π_θ), is no larger than at the parameter mean: never worse than params_avg.
    CG stops after ``cg_iters`` products or at relative residual ``cg_rtol`` (see :func:`conjugate_gradient`).
    ``info`` (if given) receives ``cg_residual`` (‖r‖) and ``step_fraction``.
    """
    damping = check_nonneg(damping, "damping")
    if len(thetas) == 0:
        raise ValueError("kl_avg needs at least one sub-policy")
    thetas = [t.detach() for t in thetas]
    mean = torch.stack(thetas).mean(0)
    base = mean if theta_old is None else theta_old.detach()
    gs = [t - base for t in thetas]
    gbar = mean - base
    fisher = FisherProducts(view, thetas, states)
    b = fisher(torch.stack([g - gbar for g in gs])).mean(0)

    def avp(v: Tensor) -> Tensor:
        return fisher.mean(v) + damping * v

    corr, res = conjugate_gradient(avp, b, cg_iters, rtol=cg_rtol)  # type: ignore[arg-type]
    frac = 1.0
    if line_search:
        with torch.no_grad():  # the objective the learner logs (eq47_objective), so the guarantee holds there too
            ref = eq47_objective(view, mean, thetas, states)
            for frac in LINE_SEARCH_FRACTIONS:
                if frac == 0.0 or eq47_objective(view, mean + frac * corr, thetas, states) <= ref:
                    break
    if info is not None:
        info["cg_residual"] = res
        info["step_fraction"] = frac
    if line_search:  # from the mean itself, so that a rejected correction (0) is params_avg to the last bit
        return mean + frac * corr
    return base + gbar + frac * corr


def kl_avg_dense(view: PolicyView, thetas: Sequence[Tensor], states: Tensor, damping: float = 0.0) -> Tensor:
    """Dense reference of Eq 4.10 (with the same damping convention as :func:`kl_avg`): forms every FIM."""
    damping = check_nonneg(damping, "damping")
    dtype = thetas[0].dtype
    fims = [fisher_matrix(view, t.detach(), states).double() for t in thetas]
    thetas = [t.detach().double() for t in thetas]
    mean = torch.stack(thetas).mean(0)
    n = len(thetas)
    a = sum(fims) / n + damping * torch.eye(mean.numel(), dtype=torch.float64)
    b = sum(f @ (t - mean) for f, t in zip(fims, thetas, strict=True)) / n
    return (mean + torch.linalg.solve(a, b)).to(dtype)
