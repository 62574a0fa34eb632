"""Chapter-4 environments: Eq 4.12 reward with action-penalty c_a, per-episode wind, test shifts.

A thin alias of :func:`thesis_repro.envs.make_env`; only the ``ctrl_cost_weight`` of the v5 task
(= c_a of Eq 4.12: r = v + 1 − c_a‖a‖², the v5 Walker2d/Hopper reward with healthy bonus 1) and the
``wind`` range are added. The signature matches ``make_env`` so the batched evaluator can use it.

>>> env = make_mdl_env("Hopper", c_a=1.0, wind=(-2.5, 2.5), seed=0)
>>> -2.5 <= env.reset(seed=0)[1]["factors"]["wind"] <= 2.5
True
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import gymnasium as gym

from thesis_repro.envs import PERTURBATIONS, make_env
from thesis_repro.validation import check_nonneg

__all__ = ["PERTURBATIONS", "make_mdl_env"]


def make_mdl_env(
    env: str,
    perturbation: str = "none",
    sigma: float = 0.0,
    *,
    c_a: float | None = None,
    wind: float | Sequence[float] | None = None,
    ratios: Mapping[str, float] | None = None,
    max_episode_steps: int | None = None,
    seed: int | None = None,
    render_mode: str | None = None,
) -> gym.Env:
    """Task ``env`` with reward Eq 4.12 (``c_a``; None = the task default 1e-3), wind and a perturbation.

    ``wind``: ``(low, high)`` samples ξ ~ U(low, high) once per episode (training); a number fixes ξ
    (testing). ``ratios``: fixed factor ratios (e.g. ``{"body_mass": 1.2, "friction": 0.8}``).
    ``perturbation``/``sigma`` as in :func:`thesis_repro.envs.make_env` (obs, act, env, dom noise).
    """
    env_kwargs: dict = {}
    if c_a is not None:
        env_kwargs["ctrl_cost_weight"] = check_nonneg(c_a, "c_a")
    if render_mode is not None:
        env_kwargs.update(render_mode=render_mode, width=480, height=320)
    fixed = dict(ratios or {})
    wind_range = None
    if wind is not None and not isinstance(wind, int | float):
        if "wind" in fixed:
            raise ValueError("give the wind either as a range (wind=...) or as a fixed ratio, not both")
        wind_range = tuple(float(w) for w in wind)
    elif wind is not None:
        fixed["wind"] = float(wind)
    return make_env(
        env,
        perturbation,
        sigma,
        ratios=fixed or None,
        wind=wind_range,
        max_episode_steps=max_episode_steps,
        env_kwargs=env_kwargs,
        seed=seed,
    )
