"""Deterministic batch policies loaded from a training run's artefacts (what the evaluator calls).

>>> import numpy as np
>>> # pol = load_policy(result)              # a cache Result of train_job, its out/ folder, or a snapshot folder
>>> # pol(np.zeros((8, pol.obs_dim))).shape  # -> (8, pol.act_dim): mean actions, clipped to the action space
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy, BasePolicy
from stable_baselines3.sac.policies import SACPolicy
from stable_baselines3.td3.policies import TD3Policy

from thesis_repro.learners.policies import SCNPolicy
from thesis_repro.validation import check_choice

#: Policy classes a run may save (``learner.json``'s ``policy_class``, ``"module:qualname"``): every kit learner's.
POLICY_CLASSES: dict[str, type[BasePolicy]] = {
    f"{c.__module__}:{c.__qualname__}": c for c in (ActorCriticPolicy, SCNPolicy, SACPolicy, TD3Policy)
}


class Policy:
    """``policy(obs[n, obs_dim]) -> actions[n, act_dim]``: saved obs filter, one torch forward, mean action.

    Stochastic policies return their mean (SAC: ``tanh(mean)``); squashed actions are rescaled to the
    action bounds; all actions are clipped to the action space. A 1-D observation gives a 1-D action.
    """

    def __init__(self, net: BasePolicy, obs_norm: Mapping[str, Any] | None = None, meta: Mapping | None = None):
        self.net = net.to("cpu")
        self.net.set_training_mode(False)
        self.meta = dict(meta or {})
        space = net.action_space
        self.low = np.asarray(space.low, dtype=np.float32)
        self.high = np.asarray(space.high, dtype=np.float32)
        self.obs_dim = int(np.prod(net.observation_space.shape))
        self.act_dim = int(np.prod(space.shape))
        if obs_norm is not None:
            self.obs_mean = np.asarray(obs_norm["mean"], dtype=np.float64)
            self.obs_std = np.sqrt(np.asarray(obs_norm["var"], dtype=np.float64) + float(obs_norm["epsilon"]))
            self.clip_obs = float(obs_norm["clip_obs"])
        else:
            self.obs_mean = self.obs_std = None
            self.clip_obs = None

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        """The observation filter of training (identity if there was none)."""
        x = np.asarray(obs, dtype=np.float64)
        if self.obs_mean is None:
            return x.astype(np.float32)
        return np.clip((x - self.obs_mean) / self.obs_std, -self.clip_obs, self.clip_obs).astype(np.float32)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        x = np.asarray(obs)
        single = x.ndim == 1
        x = x.reshape(-1, self.obs_dim) if not single else x.reshape(1, self.obs_dim)
        with th.no_grad():
            a = self.net._predict(th.as_tensor(self.normalize(x)), deterministic=True).numpy()
        a = a.reshape(len(x), self.act_dim)
        if self.net.squash_output:
            a = self.low + 0.5 * (a + 1.0) * (self.high - self.low)
        a = np.clip(a, self.low, self.high)
        return a[0] if single else a

    def __repr__(self) -> str:
        return f"Policy({self.meta.get('algorithm', '?')}, obs_dim={self.obs_dim}, act_dim={self.act_dim})"


def _folder(result_or_path: Any) -> Path:
    out = getattr(result_or_path, "out", None)
    path = Path(out if out is not None else result_or_path)
    if path.is_file():
        path = path.parent
    if not (path / "policy.pth").exists() and (path / "out" / "policy.pth").exists():
        path = path / "out"
    if not (path / "policy.pth").exists():
        raise FileNotFoundError(f"no policy.pth in {path}: pass a train_job Result, its out/ folder or a snapshot")
    return path


def snapshots(result_or_path: Any) -> list[int]:
    """Timesteps of the policy snapshots saved by a run (``snapshot_every`` > 0), ascending."""
    snaps = _folder(result_or_path) / "snapshots"
    return sorted(int(p.name.split("_")[1]) for p in snaps.glob("step_*")) if snaps.exists() else []


def load_policy(result_or_path: Any, snapshot: int | None = None) -> Policy:
    """The deterministic batch :class:`Policy` of a run (final, or the snapshot at timestep ``snapshot``)."""
    folder = _folder(result_or_path)
    if snapshot is not None:
        available = snapshots(folder)
        if snapshot not in available:
            raise ValueError(f"unknown snapshot {snapshot!r}; valid snapshots are: {available}")
        folder = folder / "snapshots" / f"step_{int(snapshot):09d}"
    meta = json.loads((folder / "learner.json").read_text())
    cls = POLICY_CLASSES[check_choice(meta["policy_class"], list(POLICY_CLASSES), "policy class")]
    net = cls.load(str(folder / "policy.pth"), device="cpu")
    norm = None
    if (folder / "obs_norm.npz").exists():
        with np.load(folder / "obs_norm.npz") as z:
            norm = {k: z[k] for k in z.files}
    return Policy(net, norm, meta)
