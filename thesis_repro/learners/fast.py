"""Leaner, equivalent training updates for SB3's PPO and TRPO (on-policy): same algorithm, less overhead.

SAC and DDPG (off-policy) are :mod:`thesis_repro.learners.fast_offpolicy`; they share the fused Adam step of
:mod:`thesis_repro.learners.kernels`.

SB3's ``PPO.train()`` spends most of its time on framework overhead for the kit's tiny networks: per
minibatch it copies numpy slices to tensors, builds ``torch.distributions`` objects, runs autograd over
~40 small nodes and walks ``policy.parameters()`` three times. :class:`FastPPO` overrides ``train()`` (SB3's
own extension point) with :func:`ppo_epochs`, which computes the SAME loss and its gradient:

* the rollout is flattened once into :class:`RolloutTensors` (:func:`rollout_tensors`, in the order of
  SB3's ``RolloutBuffer.get``) and permuted once per epoch with the same ``np.random.permutation`` draw;
* for the kit's policies (SB3 ``MlpExtractor`` or the SCN extractor, Linear+Tanh/ReLU layers, flat Box
  observations, diagonal Gaussian without gSDE) the forward pass and the gradient of the clipped PPO
  loss are written out in closed form (:class:`~thesis_repro.learners.kernels._ManualActorCritic`; tie and clip
  conventions of torch's autograd for ``min``/``clamp``), so no graph is built; any other policy takes the generic path
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

from dataclasses import dataclass, fields
from functools import partial
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from sb3_contrib import TRPO
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.utils import explained_variance, obs_as_tensor
from stable_baselines3.common.vec_env import VecEnv

from thesis_repro.learners.kernels import _clip_grad_list, _clip_grads, _FusedAdamStep, _ManualActorCritic


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


_mse_mean = partial(th._C._nn.mse_loss, reduction=1)  # = F.mse_loss(a, b) for same-shape a, b (1: "mean")


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
