"""``make_env``: a raw v5 task with one chapter-3 perturbation applied.

>>> env = make_env("Walker2d", "env", 0.2, max_episode_steps=10, seed=0)
>>> type(env).__name__
'EnvironmentNoise'
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import gymnasium as gym

from thesis_repro.envs.factors import check_factors
from thesis_repro.envs.registry import resolve_env, short_name
from thesis_repro.envs.wrappers import ActionNoise, DomainShift, EnvironmentNoise, ObservationNoise, SystematicShift
from thesis_repro.validation import check_choice, check_nonneg

#: thesis testing settings: none, Obs (σ^o), Act (σ^u), Env (σ^s), Dom (Σ).
PERTURBATIONS: tuple[str, ...] = ("none", "obs", "act", "env", "dom")


def make_env(
    env: str,
    perturbation: str = "none",
    sigma: float = 0.0,
    *,
    factors: Iterable[str] | None = None,
    ratios: Mapping[str, float] | None = None,
    max_episode_steps: int | None = None,
    seed: int | None = None,
) -> gym.Env:
    """Build task ``env`` (short name or v5 id) with ``perturbation`` of scale ``sigma``.

    ``factors`` restricts "env"/"dom" to some factors of Table 3.2 (default all). ``ratios`` adds a
    :class:`SystematicShift` underneath (it may not share factors with "env"/"dom"). ``seed`` seeds the
    action space and the first ``reset``. Unknown names and negative σ raise ``ValueError``.
    """
    task = short_name(env)
    check_choice(perturbation, PERTURBATIONS, "perturbation")
    sigma = check_nonneg(sigma, "sigma")
    if factors is not None:
        if perturbation not in ("env", "dom"):
            raise ValueError(f"factors only apply to perturbation 'env' or 'dom', not {perturbation!r}")
        factors = check_factors(task, factors)
    if max_episode_steps is not None and (int(max_episode_steps) != max_episode_steps or max_episode_steps < 1):
        raise ValueError(f"max_episode_steps must be a positive integer or None, got {max_episode_steps!r}")
    if seed is not None and (int(seed) != seed or seed < 0):
        raise ValueError(f"seed must be a non-negative integer or None, got {seed!r}")

    kwargs = {} if max_episode_steps is None else {"max_episode_steps": int(max_episode_steps)}
    out: gym.Env = gym.make(resolve_env(task), disable_env_checker=True, **kwargs)
    if ratios is not None:
        if perturbation in ("env", "dom"):
            shared = set(ratios) & set(factors if factors is not None else check_factors(task, None))
            if shared:
                raise ValueError(f"ratios and {perturbation!r} noise both set factors {sorted(shared)}")
        out = SystematicShift(out, ratios)
    if perturbation == "obs":
        out = ObservationNoise(out, sigma)
    elif perturbation == "act":
        out = ActionNoise(out, sigma)
    elif perturbation == "env":
        out = EnvironmentNoise(out, sigma, factors)
    elif perturbation == "dom":
        out = DomainShift(out, sigma, factors)
    if seed is not None:
        out.action_space.seed(int(seed))
        out.reset(seed=int(seed))
    return out
