"""Public one-call API: score any Stable-Baselines3 model (one per training seed) on the chapter-3 benchmark,
under the book's own protocol, with 95 % CIs across training seeds.

:func:`score_model` defaults to a scale's book grid (σ points, testing rollouts, episode length and test types of
the chapter-3 pages in ``config/scales.yaml``) and the book's testing seeds, so its AUCs are comparable with the
shipped learners' (:func:`thesis_repro.book.agent.compare_with_shipped` puts them side by side). The CIs are the pages'
(:func:`thesis_repro.evaluation.tables.seed_ci`: per seed the mean over its rollouts, then the t-interval across
seeds; one model: no interval).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro.core import paths, scales, yamlfile
from thesis_repro.core.validation import check_choice
from thesis_repro.evaluation import tables
from thesis_repro.evaluation.evaluator import PERTURBATIONS, EnvMaker, Policy, check_shapes, default_make, evaluate
from thesis_repro.evaluation.metrics import auc, sigma_step

#: The chapter-3 item whose settings give a scale's book grid (every chapter-3 item shares it, scales.yaml).
GRID_ITEM = "table-3.4"
#: The method name of the scored agent in tables and figures (``label=`` changes it).
AGENT = "your agent"


@cache
def default_sigmas() -> tuple[float, ...]:
    """The thesis-scale testing grid (``defaults.full.sigmas`` of ``config/scales.yaml``)."""
    table = yamlfile.parse((paths.CONFIG / "scales.yaml").read_text())
    return tuple(float(s) for s in table["defaults"]["full"]["sigmas"])


def book_grid(scale: str = "small") -> dict[str, Any]:
    """The chapter-3 pages' testing protocol at ``scale``: ``tests``, ``sigmas``, ``n_rollouts``,
    ``max_episode_steps`` (the scale's training protocol's overrides applied, as the book runs it).

    >>> g = book_grid("small")
    >>> g["sigmas"], g["n_rollouts"], g["tests"]
    ([0.0, 0.2, 0.4, 0.6, 0.8], 10, ['obs', 'act', 'env', 'dom'])
    """
    s = scales.figure_settings(GRID_ITEM, scale)
    return {
        "tests": list(s["tests"]),
        "sigmas": [float(x) for x in s["sigmas"]],
        "n_rollouts": int(s["test_rollouts"]),
        "max_episode_steps": int(s["max_episode_steps"]),
    }


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


@dataclass(frozen=True)
class Scores:
    """What :func:`score_model` returns: per test type the testing returns of every model (training seed).

    ``returns[test]`` has shape ``(n_models, len(sigmas), n_rollouts)``. :meth:`table` gives the AUC (Eq. 3.6)
    per test with its 95 % CI across models, :meth:`auc` the mean AUC per test.
    """

    task: str
    scale: str | None
    label: str
    sigmas: tuple[float, ...]
    n_rollouts: int
    seed: int
    returns: dict[str, np.ndarray]

    @property
    def tests(self) -> list[str]:
        return list(self.returns)

    @property
    def n_models(self) -> int:
        return int(next(iter(self.returns.values())).shape[0])

    def returns_frame(self) -> pd.DataFrame:
        """Tidy returns: ``env, method, seed, test, sigma, rollout, return`` (``seed`` = the model's index)."""
        parts = []
        for test, r in self.returns.items():
            mi, si, ri = np.indices(r.shape).reshape(3, -1)
            parts.append(
                pd.DataFrame(
                    {
                        "env": self.task,
                        "method": self.label,
                        "seed": mi,
                        "test": test,
                        "sigma": np.asarray(self.sigmas)[si],
                        "rollout": ri,
                        "return": r.reshape(-1),
                    }
                )
            )
        return pd.concat(parts, ignore_index=True)

    def aucs(self) -> pd.DataFrame:
        """Eq. 3.6 per testing rollout, as the chapter-3 pages tabulate it: ``env, method, seed, test, rollout,
        value`` (the AUC of a seed's mean return curve is the mean of its rollouts' AUCs)."""
        parts = []
        for test, r in self.returns.items():
            per = auc(r, list(self.sigmas), axis=1)  # (models, rollouts)
            mi, ri = np.indices(per.shape).reshape(2, -1)
            parts.append(
                pd.DataFrame(
                    {
                        "env": self.task,
                        "method": self.label,
                        "seed": mi,
                        "test": test,
                        "rollout": ri,
                        "value": per.reshape(-1),
                    }
                )
            )
        return pd.concat(parts, ignore_index=True)

    def table(self) -> pd.DataFrame:
        """AUC per test across models: ``env, test, method, seed_mean, ci_lo, ci_hi, n_seeds`` (95 % t-interval
        over per-model means, the pages' :func:`~thesis_repro.evaluation.tables.seed_ci`; one model: NaN bounds)."""
        return tables.seed_ci(self.aucs())

    def auc(self) -> dict[str, float]:
        """Mean AUC over models per test type."""
        t = self.table()
        return {str(r.test): float(r.seed_mean) for r in t.itertuples()}

    def ci_label(self) -> str:
        """What the intervals are (the pages' caption: level and number of training seeds)."""
        return tables.ci_label(self.n_models)

    def __str__(self) -> str:
        t = self.table()
        lines = [
            f"{self.label} on {self.task} (scale {self.scale}, σ {list(self.sigmas)}, "
            f"{self.n_rollouts} rollouts): testing AUC, {self.ci_label()}"
        ]
        for r in t.itertuples():
            ci = "" if not np.isfinite(r.ci_lo) else f" [{r.ci_lo:.1f}, {r.ci_hi:.1f}]"
            lines.append(f"  {r.test:4s} {r.seed_mean:10.1f}{ci}  (seeds: {int(r.n_seeds)})")
        return "\n".join(lines)


def _models(model_or_models: Any) -> list[Any]:
    if isinstance(model_or_models, (list, tuple)):
        if not model_or_models:
            raise ValueError("model_or_models must hold at least one model")
        return list(model_or_models)
    return [model_or_models]


def score_model(
    model_or_models: Any,
    task: str,
    scale: str | None = "small",
    *,
    tests: Sequence[str] | None = None,
    sigmas: Sequence[float] | None = None,
    n_rollouts: int | None = None,
    max_episode_steps: int | None = None,
    seed: int = 0,
    vecnormalize: Any = None,
    n_envs: int = 16,
    make: EnvMaker | None = None,
    label: str = AGENT,
    progress: bool = True,
) -> Scores:
    """Score SB3 model(s) on ``task`` under the book's protocol at ``scale``; returns :class:`Scores`.

    ``model_or_models``: one model or a list (one per training seed: the CIs are across them). ``task``: a task
    of :data:`thesis_repro.envs.ENVS` (``"Hopper"``). ``tests``, ``sigmas``, ``n_rollouts`` and
    ``max_episode_steps`` default to the scale's book grid (:func:`book_grid`; ``scale=None``: the thesis's full
    grid, 20 rollouts, 1,000 steps). ``seed`` is the testing seed (0: the book's, so every model meets the
    shipped learners' initial states and noise). ``vecnormalize``: one ``VecNormalize`` or a list, one per model.
    Shows a progress bar (``progress=False``: none).

    >>> from stable_baselines3 import PPO  # doctest: +SKIP
    >>> models = [PPO("MlpPolicy", "Hopper-v5", seed=s).learn(10_000) for s in range(3)]  # doctest: +SKIP
    >>> print(score_model(models, "Hopper", "small"))  # doctest: +SKIP
    """
    if tests is None:
        tests = book_grid(scale)["tests"] if scale is not None else PERTURBATIONS[1:]
    if isinstance(tests, str):
        tests = (tests,)
    for t in tests:
        check_choice(t, PERTURBATIONS, "test type")
    grid = (
        book_grid(scale)
        if scale is not None
        else {
            "sigmas": list(default_sigmas()),
            "n_rollouts": 20,
            "max_episode_steps": 1000,
        }
    )
    sig = [float(x) for x in (grid["sigmas"] if sigmas is None else sigmas)]
    sigma_step(sig)  # validate the grid before spending any compute
    n_rollouts = int(grid["n_rollouts"] if n_rollouts is None else n_rollouts)
    steps = int(grid["max_episode_steps"] if max_episode_steps is None else max_episode_steps)
    models = _models(model_or_models)
    norms = vecnormalize if isinstance(vecnormalize, (list, tuple)) else [vecnormalize] * len(models)
    if len(norms) != len(models):
        raise ValueError(f"got {len(norms)} vecnormalize objects for {len(models)} models; give one per model")
    for m in models:
        check_model_fits(m, task, make)
    policies = [sb3_policy(m, v) for m, v in zip(models, norms, strict=True)]
    from tqdm import tqdm  # the text bar (stderr), as every bar of the kit: in a kernel it reaches the terminal

    returns: dict[str, list[np.ndarray]] = {t: [] for t in tests}
    todo = [(t, i) for t in tests for i in range(len(policies))]
    bar = tqdm(todo, desc=f"score {task}", unit="test", disable=not progress, leave=False)
    for t, i in bar:
        bar.set_postfix_str(f"{t}, model {i + 1}/{len(policies)}")
        returns[t].append(
            evaluate(
                policies[i], task, t, sig, n_rollouts, seed=seed, max_episode_steps=steps, n_envs=n_envs, make=make
            )
        )
    from thesis_repro.envs import short_name

    return Scores(
        task=short_name(task),
        scale=scale,
        label=str(label),
        sigmas=tuple(sig),
        n_rollouts=n_rollouts,
        seed=int(seed),
        returns={t: np.stack(r) for t, r in returns.items()},
    )


def summarise(scores: Scores | Mapping[str, Mapping[str, Any]]) -> dict[str, float]:
    """``{test: mean AUC}`` of a :func:`score_model` result."""
    if isinstance(scores, Scores):
        return scores.auc()
    return {t: float(s["auc"]) for t, s in scores.items()}
