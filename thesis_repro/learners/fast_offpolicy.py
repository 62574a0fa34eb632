"""Leaner, equivalent training updates for SB3's SAC and DDPG (the TD3 family): same algorithm, less overhead.

The off-policy half of the kit's lean learners (the on-policy half, PPO and TRPO, is
:mod:`thesis_repro.learners.fast`; both use the fused Adam step of :mod:`thesis_repro.learners.kernels`).
Closed-form forward and backward passes of the kit's MLP actors and Q-networks (:class:`_Net`), replay sampling
without SB3's per-call overhead and lean exploration; ``tests/test_fast.py`` proves equivalence with SB3's
``SAC``/``DDPG`` and ``tests/test_speed_identity.py`` pins the numbers bit for bit.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
import torch.nn.functional as F
from gymnasium import spaces
from stable_baselines3 import DDPG, SAC
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.torch_layers import FlattenExtractor
from stable_baselines3.common.utils import obs_as_tensor
from torch import nn

from thesis_repro.learners.kernels import _LOG_SQRT_2PI, _FusedAdamStep

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


#: :meth:`FastSAC.train` stacks the actor's two forwards for batches of a multiple of this many rows: torch's normal
#: draw fills blocks of 16 numbers and its vectorised loops step through blocks of 16 floats (AVX2), so each half of
#: the stacked tensors sees the blocks, and the bits, of its own forward.
STACK_ROWS = 16


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

    def actor_forward_pair(self, obs: th.Tensor, next_obs: th.Tensor) -> tuple[dict[str, Any], dict[str, Any]]:
        """``actor_forward(obs)`` then ``actor_forward(next_obs)`` as one forward of the stacked rows: the noise of
        both in one draw (the same numbers, in the same order), each result the rows of its half."""
        both = self.actor_forward(th.cat([obs, next_obs]))
        b = len(obs)
        halves = ({}, {})
        for key, value in both.items():
            for i, rows in enumerate((slice(None, b), slice(b, None))):
                halves[i][key] = [h[rows] for h in value] if key == "hs" else value[rows]
        return halves

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
    #: One actor forward for a batch's observations and next observations stacked (the same draws, in the same
    #: order, and the same bits as two forwards: ``tests/test_sac_speed.py``), for batches of a multiple of
    #: :data:`STACK_ROWS` rows; ``False``: two forwards, as before.
    stack_actor: bool = True

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
                stacked = self.stack_actor and b % STACK_ROWS == 0 and obs.shape == next_obs.shape
                if stacked:  # the actor is not updated between the two: one forward of both, split by rows
                    f, nf = nets.actor_forward_pair(obs, next_obs)
                else:
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
                if not stacked:
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
