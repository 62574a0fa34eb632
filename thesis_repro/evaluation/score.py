"""Public one-call API: score any Stable-Baselines3 model on the chapter-3 generalisation benchmark."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import cache
from typing import Any

import numpy as np
import yaml

from thesis_repro import paths
from thesis_repro.evaluation.evaluator import PERTURBATIONS, EnvMaker, Policy, check_shapes, default_make, evaluate
from thesis_repro.evaluation.metrics import auc, expected_return, sigma_step
from thesis_repro.validation import check_choice


@cache
def default_sigmas() -> tuple[float, ...]:
    """The thesis-scale testing grid (``defaults.full.sigmas`` of ``config/scales.yaml``)."""
    table = yaml.safe_load((paths.CONFIG / "scales.yaml").read_text())
    return tuple(float(s) for s in table["defaults"]["full"]["sigmas"])


def sb3_policy(model: Any, vecnormalize: Any = None) -> Policy:
    """Wrap an SB3 model (anything with ``.policy.predict``) as a batched deterministic policy.

    Observations are normalised with ``vecnormalize.normalize_obs`` (a ``VecNormalize``) if given;
    the actions are SB3's deterministic ones (mean action, unsquashed/clipped to the action space).

    >>> act = sb3_policy(PPO("MlpPolicy", "Hopper-v5"))  # doctest: +SKIP
    >>> act(np.zeros((16, 11))).shape  # doctest: +SKIP
    (16, 3)
    """
    policy = getattr(model, "policy", model)
    if not hasattr(policy, "predict"):
        raise TypeError(f"expected an SB3 model or policy with .predict, got {type(model).__name__}")
    if vecnormalize is not None and not hasattr(vecnormalize, "normalize_obs"):
        raise TypeError("vecnormalize must be a stable_baselines3 VecNormalize (with .normalize_obs)")

    fast = _fast_forward(policy)

    def act(obs: np.ndarray) -> np.ndarray:
        if vecnormalize is not None:
            obs = vecnormalize.normalize_obs(obs)
        if fast is not None:
            return fast(obs)
        actions, _ = policy.predict(obs, deterministic=True)
        return actions

    return act


def _fast_forward(policy: Any) -> Any:
    """Batched deterministic actions without ``predict``'s per-call overhead (Box spaces only, else ``None``).

    Same computation as SB3's ``predict(obs, deterministic=True)``: for a Gaussian actor-critic policy the
    mean ``action_net(mlp_extractor.forward_actor(features))`` (what ``mode()`` returns, without building
    the distribution object), otherwise ``_predict``; then unsquash or clip to the action bounds.
    """
    import gymnasium as gym
    import torch
    from stable_baselines3.common.distributions import DiagGaussianDistribution
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.common.preprocessing import preprocess_obs

    obs_space, act_space = getattr(policy, "observation_space", None), getattr(policy, "action_space", None)
    if not (isinstance(obs_space, gym.spaces.Box) and isinstance(act_space, gym.spaces.Box)):
        return None
    if not hasattr(policy, "_predict"):
        return None
    policy.set_training_mode(False)
    low, high = act_space.low, act_space.high
    squash = bool(getattr(policy, "squash_output", False))
    gaussian_ac = isinstance(policy, ActorCriticPolicy) and isinstance(policy.action_dist, DiagGaussianDistribution)

    def mean_action(t: torch.Tensor) -> torch.Tensor:
        if gaussian_ac:
            pre = preprocess_obs(t, obs_space, normalize_images=policy.normalize_images)
            return policy.action_net(policy.mlp_extractor.forward_actor(policy.pi_features_extractor(pre)))
        return policy._predict(t, deterministic=True)

    def forward(obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            t = torch.as_tensor(np.asarray(obs), dtype=torch.float32, device=policy.device)
            a = mean_action(t.reshape(-1, *obs_space.shape)).cpu().numpy()
        a = a.reshape(-1, *act_space.shape)
        return policy.unscale_action(a) if squash else np.clip(a, low, high)

    return forward


def check_model_fits(model: Any, env: str, make: EnvMaker | None = None) -> None:
    """``ValueError`` naming the task and the shapes if an SB3 model's spaces do not match task ``env``'s.

    >>> from stable_baselines3 import PPO  # doctest: +SKIP
    >>> check_model_fits(PPO("MlpPolicy", "InvertedPendulum-v5"), "Hopper")  # doctest: +SKIP
    Traceback (most recent call last):
    ValueError: policy does not fit task 'Hopper': it takes observations of shape (4,) and gives actions of ...
    """
    policy = getattr(model, "policy", model)
    obs_space = getattr(model, "observation_space", None) or getattr(policy, "observation_space", None)
    act_space = getattr(model, "action_space", None) or getattr(policy, "action_space", None)
    if obs_space is None and act_space is None:
        return
    task_env = (make or default_make())(env)
    try:
        check_shapes(
            env,
            task_env.observation_space.shape,
            task_env.action_space.shape,
            None if obs_space is None else obs_space.shape,
            None if act_space is None else act_space.shape,
        )
    finally:
        task_env.close()


def score_model(
    model: Any,
    env: str,
    *,
    tests: Sequence[str] = ("obs", "act", "env", "dom"),
    sigmas: Sequence[float] | None = None,
    n_rollouts: int = 20,
    seed: int = 0,
    vecnormalize: Any = None,
    max_episode_steps: int = 1000,
    n_envs: int = 16,
    make: EnvMaker | None = None,
) -> dict[str, dict[str, Any]]:
    """Score any SB3 model on the benchmark: per test type the returns, expected return per σ and AUC.

    ``env`` is a task name of ``thesis_repro.envs.make_env`` (e.g. ``"Hopper"``); ``sigmas`` defaults to
    the thesis-scale grid :func:`default_sigmas`. Returns ``{test: {"sigmas", "returns" (len(sigmas),
    n_rollouts), "expected_return" (len(sigmas),), "auc" (Eq. 3.6)}}``.

    >>> from stable_baselines3 import PPO  # doctest: +SKIP
    >>> model = PPO("MlpPolicy", "Hopper-v5").learn(10_000)  # doctest: +SKIP
    >>> scores = score_model(model, "Hopper", sigmas=[0.0, 0.1, 0.2], n_rollouts=5)  # doctest: +SKIP
    >>> {t: round(s["auc"], 1) for t, s in scores.items()}  # doctest: +SKIP
    {'obs': 41.3, 'act': 55.0, 'env': 60.2, 'dom': 58.7}
    """
    sig = list(default_sigmas() if sigmas is None else sigmas)
    sigma_step(sig)  # validate the grid before spending any compute
    if isinstance(tests, str):
        tests = (tests,)
    for t in tests:
        check_choice(t, PERTURBATIONS, "test type")
    check_model_fits(model, env, make)
    policy = sb3_policy(model, vecnormalize)
    out: dict[str, dict[str, Any]] = {}
    for t in tests:
        returns = evaluate(
            policy, env, t, sig, n_rollouts, seed=seed, max_episode_steps=max_episode_steps, n_envs=n_envs, make=make
        )
        eta = expected_return(returns, axis=1)
        out[t] = {"sigmas": np.asarray(sig), "returns": returns, "expected_return": eta, "auc": auc(eta, sig)}
    return out


def summarise(scores: Mapping[str, Mapping[str, Any]]) -> dict[str, float]:
    """``{test: AUC}`` of a :func:`score_model` result."""
    return {t: float(s["auc"]) for t, s in scores.items()}
