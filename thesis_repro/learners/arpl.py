"""Adversarially Robust Policy Learning (Mandlekar et al., 2017), observation attacks only (thesis §3.2.1).

During training, each observation the policy sees is, with probability ``prob``, replaced by
``s + delta`` where ``delta = epsilon * g / ||g||`` and ``g = grad_s ||pi(s)||`` is the gradient of the
norm of the policy's mean action: the direction that most increases the action norm, scaled to
L2 norm ``epsilon`` (in normalised-observation units, since it acts on what the policy receives). The
perturbed observations are what PPO stores and learns from.

>>> import numpy as np, gymnasium as gym
>>> from stable_baselines3 import PPO
>>> pol = PPO("MlpPolicy", gym.make("InvertedPendulum-v5"), seed=0).policy
>>> d = arpl_perturbation(pol, np.random.default_rng(0).normal(size=(3, 4)), epsilon=0.1)
>>> d.shape, bool(np.allclose(np.linalg.norm(d, axis=1), 0.1, atol=1e-6))
((3, 4), True)
"""

from __future__ import annotations

import numpy as np
import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from thesis_repro.validation import check_nonneg


def mean_action(policy: ActorCriticPolicy, obs: th.Tensor) -> th.Tensor:
    """The Gaussian policy's mean action (before clipping) for a batch of (normalised) observations."""
    return policy.get_distribution(obs).distribution.mean


def arpl_perturbation(policy: ActorCriticPolicy, obs: np.ndarray, epsilon: float) -> np.ndarray:
    """``epsilon * g/||g||`` per row, ``g = grad_s ||mean_action(s)||``; zero rows where ``g`` vanishes."""
    x = th.as_tensor(np.asarray(obs, dtype=np.float32), device=policy.device).requires_grad_(True)
    with th.enable_grad():
        norm = th.linalg.vector_norm(mean_action(policy, x), dim=-1)
        (grad,) = th.autograd.grad(norm.sum(), x)
    g = grad.detach().cpu().numpy().astype(np.float64)
    gn = np.linalg.norm(g, axis=-1, keepdims=True)
    return (epsilon * np.divide(g, gn, out=np.zeros_like(g), where=gn > 1e-12)).astype(np.float32)


class ARPLVecEnv(VecEnvWrapper):
    """Outermost VecEnv wrapper attacking a random fraction ``prob`` of observations with ``arpl_perturbation``.

    The policy is attached after the model is built (``wrapper.policy = model.policy``); until then, and
    for terminal observations used for bootstrapping, observations pass unchanged.
    """

    def __init__(self, venv: VecEnv, epsilon: float, prob: float, seed: int = 0):
        super().__init__(venv)
        self.epsilon = check_nonneg(epsilon, "arpl epsilon")
        self.prob = check_nonneg(prob, "arpl prob")
        if self.prob > 1:
            raise ValueError(f"arpl prob must be in [0, 1], got {prob}")
        self.rng = np.random.default_rng(seed)
        self.policy: ActorCriticPolicy | None = None
        self.n_attacked = 0

    def _attack(self, obs: np.ndarray) -> np.ndarray:
        if self.policy is None or self.epsilon == 0 or self.prob == 0:
            return obs
        mask = self.rng.random(len(obs)) < self.prob
        if not mask.any():
            return obs
        obs = obs.copy()
        obs[mask] += arpl_perturbation(self.policy, obs[mask], self.epsilon)
        self.n_attacked += int(mask.sum())
        return obs

    def reset(self) -> np.ndarray:
        return self._attack(self.venv.reset())

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        return self._attack(obs), rewards, dones, infos
