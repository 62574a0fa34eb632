"""A trained policy's file (tensors only) and the deterministic batch policy the evaluator loads from it.

A policy is stored as tensors only, never as a pickle: ``policy.pth`` is a plain state dict (``torch.save`` of
``{name: tensor}``, read back with ``torch.load(weights_only=True)``), and ``learner.json`` beside it holds the
policy's class (one of :data:`POLICY_CLASSES`) and its constructor arguments as JSON (``policy_kwargs``: spaces,
layer sizes, activation by name from :data:`TORCH_CLASSES`). :func:`save_policy` writes both,
:func:`read_state_dict` and :func:`build_policy` read them; a file that is not tensors only (a pickled SB3
``BasePolicy.save``, or a planted payload) is refused with one line, its code never run. Resumable checkpoints
(``model.zip``, ``vecnormalize.pkl``, ``live.pkl``) still pickle: they stay in the local work folder and are
never shipped (:data:`thesis_repro.core.cache.UNSHIPPED`).

>>> import numpy as np
>>> # pol = load_policy(result)              # a cache Result of train_job, its out/ folder, or a snapshot folder
>>> # pol(np.zeros((8, pol.obs_dim))).shape  # -> (8, pol.act_dim): mean actions, clipped to the action space
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy, BasePolicy
from stable_baselines3.common.torch_layers import FlattenExtractor
from stable_baselines3.sac.policies import SACPolicy
from stable_baselines3.td3.policies import TD3Policy

from thesis_repro.core.validation import check_choice
from thesis_repro.learners.policies import SCNPolicy

#: Policy classes a run may save (``learner.json``'s ``policy_class``, ``"module:qualname"``): every kit learner's.
POLICY_CLASSES: dict[str, type[BasePolicy]] = {
    f"{c.__module__}:{c.__qualname__}": c for c in (ActorCriticPolicy, SCNPolicy, SACPolicy, TD3Policy)
}
#: Classes a policy's constructor arguments may name (activation, optimiser, features extractor), by name.
TORCH_CLASSES: dict[str, type] = {
    f"{c.__module__}:{c.__qualname__}": c
    for c in (th.nn.Tanh, th.nn.ReLU, th.nn.ELU, th.nn.LeakyReLU, th.nn.Sigmoid, th.optim.Adam, FlattenExtractor)
}
#: Constructor arguments not stored: the learning-rate schedule (evaluation never steps the optimiser).
_NOT_STORED = ("lr_schedule",)


class UnsafePolicyFile(ValueError):
    """A policy file that is not a plain state dict of tensors (refused without running any of it)."""


def _bound(b: np.ndarray) -> Any:
    """A box bound as JSON: one number if uniform, else a flat list; JSON has no inf/nan: "inf", "-inf", "nan"."""
    num = [x if np.isfinite(x) else str(x) for x in map(float, b.flat)]
    return num[0] if len(set(map(str, num))) == 1 else num


def _encode(value: Any) -> Any:
    if isinstance(value, gym.spaces.Box):
        shape, dtype = list(value.shape), str(value.dtype)
        return {"box": {"low": _bound(value.low), "high": _bound(value.high), "shape": shape, "dtype": dtype}}
    if isinstance(value, type):
        name = f"{value.__module__}:{value.__qualname__}"
        return {"class": check_choice(name, list(TORCH_CLASSES), "policy constructor class")}
    if isinstance(value, Mapping):
        return {"dict": {str(k): _encode(v) for k, v in value.items()}}
    if isinstance(value, (list, tuple)):
        return [_encode(v) for v in value]
    if value is None or isinstance(value, (bool, int, str)) or (isinstance(value, float) and np.isfinite(value)):
        return value
    raise ValueError(f"policy constructor argument {value!r} has no JSON form")


def _decode(value: Any) -> Any:
    if isinstance(value, list):
        return [_decode(v) for v in value]
    if not isinstance(value, dict):
        return value
    tag, body = next(iter(value.items())) if len(value) == 1 else (None, None)
    if tag == "box":
        shape, dtype = tuple(body["shape"]), np.dtype(body["dtype"])
        low, high = (
            np.broadcast_to(np.asarray(body[b], dtype=np.float64).astype(dtype), shape) for b in ("low", "high")
        )
        return gym.spaces.Box(low.copy(), high.copy(), shape, dtype=dtype)
    if tag == "class":
        return TORCH_CLASSES[check_choice(body, list(TORCH_CLASSES), "policy constructor class")]
    if tag == "dict":
        return {k: _decode(v) for k, v in body.items()}
    raise ValueError(f"unreadable policy constructor argument {value!r}: expected a box, class or dict")


def policy_spec(net: BasePolicy) -> dict[str, Any]:
    """``policy_class`` and the JSON ``policy_kwargs`` that rebuild ``net`` (:func:`build_policy`)."""
    kwargs = {k: _encode(v) for k, v in net._get_constructor_parameters().items() if k not in _NOT_STORED}
    cls = type(net)
    return {"policy_class": f"{cls.__module__}:{cls.__qualname__}", "policy_kwargs": kwargs}


def save_policy(net: BasePolicy, folder: str | Path) -> dict[str, Any]:
    """Write ``folder/policy.pth`` (the state dict, tensors only) and return :func:`policy_spec` (for
    ``learner.json``): the one way the kit stores a policy."""
    state = {k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()}
    th.save(state, Path(folder) / "policy.pth")
    return policy_spec(net)


def read_state_dict(path: str | Path) -> dict[str, th.Tensor]:
    """The tensors of a policy file, read with ``torch.load(weights_only=True)``; :class:`UnsafePolicyFile`
    (one line) for anything else, whose code is never run."""
    try:
        state = th.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - every way a file fails to be plain tensors is the same refusal
        why = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise UnsafePolicyFile(f"refusing {path}: not a tensors-only policy file ({why[:160]})") from None
    if not isinstance(state, Mapping) or not all(
        isinstance(k, str) and isinstance(v, th.Tensor) for k, v in state.items()
    ):
        raise UnsafePolicyFile(f"refusing {path}: not a state dict of named tensors")
    return dict(state)


def build_policy(meta: Mapping[str, Any], state: Mapping[str, th.Tensor]) -> BasePolicy:
    """The SB3 policy of ``learner.json``'s ``meta`` (class and ``policy_kwargs``) with the weights ``state``."""
    if "policy_kwargs" not in meta:
        raise UnsafePolicyFile(
            "learner.json has no policy_kwargs: a policy saved before policies were stored as tensors only"
        )
    cls = POLICY_CLASSES[check_choice(meta["policy_class"], list(POLICY_CLASSES), "policy class")]
    kwargs = {k: _decode(v) for k, v in meta["policy_kwargs"].items()}
    net = cls(**kwargs, lr_schedule=BasePolicy._dummy_schedule)
    net.load_state_dict(state)
    return net.to("cpu")


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
    try:
        net = build_policy(meta, read_state_dict(folder / "policy.pth"))
    except UnsafePolicyFile as err:
        raise UnsafePolicyFile(f"{folder}: {err}" if str(folder) not in str(err) else str(err)) from None
    norm = None
    if (folder / "obs_norm.npz").exists():
        with np.load(folder / "obs_norm.npz", allow_pickle=False) as z:
            norm = {k: z[k] for k in z.files}
    return Policy(net, norm, meta)
