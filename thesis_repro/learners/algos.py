"""Thin SB3 subclasses for Appendix-A details SB3 lacks.

``DDPGSplit``: OpenAI-baselines DDPG uses separate actor/critic learning rates (1e-4 / 1e-3) and an L2
penalty on the critic weights (0.01). SB3's DDPG has one learning rate and no L2 term; we add both:
the L2 term as Adam ``weight_decay`` (gradient ``c * w``, the same as baselines' ``c/2 * ||w||^2``) on
the critic's hidden-layer weight matrices (baselines: all critic weights except the output layer).

>>> import gymnasium as gym
>>> m = DDPGSplit("MlpPolicy", gym.make("InvertedPendulum-v5"), actor_lr=1e-4, critic_lr=1e-3, critic_l2=0.01)
>>> [g["weight_decay"] for g in m.critic.optimizer.param_groups]
[0.01, 0.0]
"""

from __future__ import annotations

from typing import Any

import torch as th
from stable_baselines3.common.utils import update_learning_rate

from thesis_repro.learners.fast_offpolicy import FastDDPG


class DDPGSplit(FastDDPG):
    """SB3 DDPG (leaner, equivalent ``FastDDPG.train``) with separate actor/critic lrs and a critic L2 penalty."""

    def __init__(self, *args: Any, actor_lr: float = 1e-4, critic_lr: float = 1e-3, critic_l2: float = 0.0, **kw):
        self.actor_lr = float(actor_lr)
        self.critic_lr = float(critic_lr)
        self.critic_l2 = float(critic_l2)
        kw.setdefault("learning_rate", self.critic_lr)
        super().__init__(*args, **kw)

    def _setup_model(self) -> None:
        super()._setup_model()
        opt_cls = type(self.critic.optimizer)
        extra = {k: v for k, v in self.policy.optimizer_kwargs.items() if k != "weight_decay"}
        decay, rest = [], []
        for name, p in self.critic.named_parameters():
            # critic.qf0 = Sequential(Linear, act, Linear, act, Linear): every weight but the output layer
            is_hidden_weight = name.endswith("weight") and not name.endswith(f"{len(self.critic.qf0) - 1}.weight")
            (decay if is_hidden_weight and "features_extractor" not in name else rest).append(p)
        self.critic.optimizer = opt_cls(
            [{"params": decay, "weight_decay": self.critic_l2}, {"params": rest, "weight_decay": 0.0}],
            lr=self.critic_lr,
            **extra,
        )
        for g in self.actor.optimizer.param_groups:
            g["lr"] = self.actor_lr

    def _update_learning_rate(self, optimizers: list[th.optim.Optimizer] | th.optim.Optimizer) -> None:
        if hasattr(self, "_logger"):  # set by learn()
            self.logger.record("train/actor_lr", self.actor_lr)
            self.logger.record("train/critic_lr", self.critic_lr)
        update_learning_rate(self.actor.optimizer, self.actor_lr)
        update_learning_rate(self.critic.optimizer, self.critic_lr)
