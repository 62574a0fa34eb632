"""Adversarially Robust Policy Learning (Mandlekar et al., 2017), observation attacks only (thesis §3.2.1).

During training, each observation the policy sees is, with probability ``prob``, replaced by
``s + delta``, with ``g = grad_s ||pi(s)||`` the gradient of the norm of the policy's mean action (the
direction that most increases the action norm), in normalised-observation units (it acts on what the
policy receives). ``delta`` (:data:`DELTAS`) is

* ``gradient``: ``delta = epsilon * g``, §3.2.1's formula as written (δ_t = ε ∇_s ‖π_θ(s_t)‖): its length
  is ε·‖g‖, so the attack grows with the policy's sensitivity to its input;
* ``rescaled``: ``delta = epsilon * g / ||g||``, the gradient rescaled to length ε (closer to §2.3.3's
  "rescaled gradient"; the default when the setting is absent).

The perturbed observations are what PPO stores and learns from.

>>> import numpy as np, gymnasium as gym
>>> from stable_baselines3 import PPO
>>> pol = PPO("MlpPolicy", gym.make("InvertedPendulum-v5"), seed=0).policy
>>> obs = np.random.default_rng(0).normal(size=(3, 4))
>>> d = arpl_perturbation(pol, obs, epsilon=0.1, delta="rescaled")
>>> d.shape, bool(np.allclose(np.linalg.norm(d, axis=1), 0.1, atol=1e-6))
((3, 4), True)
>>> g = arpl_perturbation(pol, obs, epsilon=1.0, delta="gradient")  # = grad_s ||pi(s)|| itself
>>> bool(np.allclose(d, 0.1 * g / np.linalg.norm(g, axis=1, keepdims=True), atol=1e-6))
True
"""

from __future__ import annotations

import numpy as np
import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from thesis_repro.core.validation import check_choice, check_nonneg
from thesis_repro.learners.config import ARPL_DELTAS as DELTAS  # §3.2.1's ε·∇ or ∇ rescaled to length ε


def mean_action(policy: ActorCriticPolicy, obs: th.Tensor) -> th.Tensor:
    """The Gaussian policy's mean action (before clipping) for a batch of (normalised) observations."""
    return policy.get_distribution(obs).distribution.mean


def arpl_perturbation(
    policy: ActorCriticPolicy, obs: np.ndarray, epsilon: float, delta: str = "rescaled"
) -> np.ndarray:
    """Per row, with ``g = grad_s ||mean_action(s)||``: ``epsilon * g`` (``delta="gradient"``, §3.2.1) or
    ``epsilon * g/||g||`` (``"rescaled"``; zero rows where ``g`` vanishes)."""
    check_choice(delta, DELTAS, "arpl delta")
    x = th.as_tensor(np.asarray(obs, dtype=np.float32), device=policy.device).requires_grad_(True)
    with th.enable_grad():
        norm = th.linalg.vector_norm(mean_action(policy, x), dim=-1)
        (grad,) = th.autograd.grad(norm.sum(), x)
    g = grad.detach().cpu().numpy().astype(np.float64)
    if delta == "gradient":
        return (epsilon * g).astype(np.float32)
    gn = np.linalg.norm(g, axis=-1, keepdims=True)
    return (epsilon * np.divide(g, gn, out=np.zeros_like(g), where=gn > 1e-12)).astype(np.float32)


class ARPLVecEnv(VecEnvWrapper):
    """Outermost VecEnv wrapper attacking a random fraction ``prob`` of observations with ``arpl_perturbation``
    (form ``delta``, :data:`DELTAS`).

    The policy is attached after the model is built (``wrapper.policy = model.policy``); until then, and
    for terminal observations used for bootstrapping, observations pass unchanged.
    """

    #: class-level default: the instance attribute is set only for the non-default form (exact resume of a
    #: checkpoint written before ``delta`` existed is unchanged)
    delta: str = "rescaled"

    def __init__(self, venv: VecEnv, epsilon: float, prob: float, seed: int = 0, delta: str = "rescaled"):
        super().__init__(venv)
        if check_choice(delta, DELTAS, "arpl delta") != type(self).delta:
            self.delta = delta
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
        obs[mask] += arpl_perturbation(self.policy, obs[mask], self.epsilon, self.delta)
        self.n_attacked += int(mask.sum())
        return obs

    def reset(self) -> np.ndarray:
        return self._attack(self.venv.reset())

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        return self._attack(obs), rewards, dones, infos
