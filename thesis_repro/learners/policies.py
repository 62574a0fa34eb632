"""Structured Control Net (Srouji et al., 2018) as an SB3 on-policy actor-critic policy: the kit's policy classes.

The file keeps the name ``policies`` because the shipped runs' format names it: each SCN run's ``learner.json``
stores its class by module path (``thesis_repro.learners.policies:SCNPolicy``, looked up in
:data:`thesis_repro.learners.policy_file.POLICY_CLASSES`), so renaming the file would orphan every shipped SCN run.
:mod:`thesis_repro.learners.policy_file` is the other side: how a trained policy is saved and loaded.

The action mean is the sum of a linear stream and a nonlinear (MLP) stream of the (normalised)
observation, ``mu(s) = K s + b + W h(s)``, where ``h`` is the ``net_arch["pi"]`` MLP. We implement it
by letting the policy latent be ``[s, h(s)]``; SB3's linear ``action_net`` then computes exactly
``K s + W h(s) + b``. The value function stays a plain MLP.

>>> import gymnasium as gym
>>> from stable_baselines3.common.utils import ConstantSchedule
>>> env = gym.make("InvertedPendulum-v5")
>>> arch = {"pi": [16, 16], "vf": [16]}
>>> pol = SCNPolicy(env.observation_space, env.action_space, ConstantSchedule(3e-4), net_arch=arch)
>>> pol.mlp_extractor.latent_dim_pi  # 4 observation dims + 16 hidden units
20
"""

from __future__ import annotations

import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import MlpExtractor


class SCNExtractor(MlpExtractor):
    """``MlpExtractor`` whose policy latent is ``[features, mlp(features)]`` (linear + nonlinear streams)."""

    def __init__(self, feature_dim: int, *args, **kwargs):
        super().__init__(feature_dim, *args, **kwargs)
        self.feature_dim = feature_dim
        self.latent_dim_pi = feature_dim + self.latent_dim_pi

    def forward(self, features: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: th.Tensor) -> th.Tensor:
        return th.cat([features, self.policy_net(features)], dim=-1)


class SCNPolicy(ActorCriticPolicy):
    """PPO/TRPO policy with a Structured Control Net actor (see module docstring)."""

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = SCNExtractor(
            self.features_dim, net_arch=self.net_arch, activation_fn=self.activation_fn, device=self.device
        )

    def _streams(self, obs: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        features = self.extract_features(obs, self.pi_features_extractor)
        d = self.mlp_extractor.feature_dim
        w, b = self.action_net.weight, self.action_net.bias
        linear = features @ w[:, :d].T + b
        nonlinear = self.mlp_extractor.policy_net(features) @ w[:, d:].T
        return linear, nonlinear

    def linear_stream(self, obs: th.Tensor) -> th.Tensor:
        """``K s + b``: the linear controller's contribution to the action mean."""
        return self._streams(obs)[0]

    def nonlinear_stream(self, obs: th.Tensor) -> th.Tensor:
        """``W h(s)``: the MLP's contribution to the action mean."""
        return self._streams(obs)[1]
