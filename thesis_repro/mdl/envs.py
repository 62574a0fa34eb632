"""Chapter-4 environments: Eq 4.12 reward with action-penalty c_a, per-episode wind, test shifts.

Built from the kit's wrappers (:mod:`thesis_repro.envs`); only the ``ctrl_cost_weight`` of the v5 task
(= c_a of Eq 4.12: r = v + 1 − c_a‖a‖², the v5 Walker2d/Hopper reward with healthy bonus 1) and the
``wind`` range are added. The signature matches ``make_env`` so the batched evaluator can use it.

>>> env = make_mdl_env("Hopper", c_a=1.0, wind=(-2.5, 2.5), seed=0)
>>> -2.5 <= env.reset(seed=0)[1]["factors"]["wind"] <= 2.5
True
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import gymnasium as gym

from thesis_repro.envs import (
    ActionNoise,
    DomainShift,
    EnvironmentNoise,
    ObservationNoise,
    SystematicShift,
    Wind,
    resolve_env,
)
from thesis_repro.validation import check_choice, check_nonneg

PERTURBATIONS: tuple[str, ...] = ("none", "obs", "act", "env", "dom")


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
    check_choice(perturbation, PERTURBATIONS, "perturbation")
    sigma = check_nonneg(sigma, "sigma")
    if wind is not None and perturbation in ("env", "dom"):
        raise ValueError(f"perturbation {perturbation!r} already samples the wind factor; do not also give wind")
    kwargs: dict = {"disable_env_checker": True}
    if c_a is not None:
        kwargs["ctrl_cost_weight"] = check_nonneg(c_a, "c_a")
    if max_episode_steps is not None:
        kwargs["max_episode_steps"] = int(max_episode_steps)
    if render_mode is not None:
        kwargs.update(render_mode=render_mode, width=480, height=320)
    out: gym.Env = gym.make(resolve_env(env), **kwargs)
    fixed = dict(ratios or {})
    if wind is not None and not isinstance(wind, int | float):
        low, high = (float(w) for w in wind)
        if "wind" in fixed:
            raise ValueError("give the wind either as a range (wind=...) or as a fixed ratio, not both")
    elif wind is not None:
        fixed["wind"] = float(wind)
        low = high = None
    else:
        low = high = None
    if fixed:
        out = SystematicShift(out, fixed)
    if low is not None:
        out = Wind(out, low, high)
    if perturbation == "obs":
        out = ObservationNoise(out, sigma)
    elif perturbation == "act":
        out = ActionNoise(out, sigma)
    elif perturbation == "env":
        out = EnvironmentNoise(out, sigma)
    elif perturbation == "dom":
        out = DomainShift(out, sigma)
    if seed is not None:
        out.action_space.seed(int(seed))
        out.reset(seed=int(seed))
    return out
