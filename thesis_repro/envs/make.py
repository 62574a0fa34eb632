"""``make_env``: a raw v5 task with one chapter-3 perturbation applied (``wrap_env`` for an existing env).

>>> env = make_env("Walker2d", "env", 0.2, max_episode_steps=10, seed=0)
>>> type(env).__name__
'EnvironmentNoise'
>>> env = make_env("Walker2d", wind=(-0.5, 0.5), c_a=1.0)
>>> type(env).__name__, env.unwrapped._ctrl_cost_weight
('Wind', 1.0)
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from typing import Any

import gymnasium as gym

from thesis_repro.core.validation import check_choice, check_nonneg
from thesis_repro.envs.factors import check_factors, env_short_name
from thesis_repro.envs.lean import lean_spec
from thesis_repro.envs.registry import model_kwargs, resolve_env, short_name
from thesis_repro.envs.wrappers import (
    ActionNoise,
    DomainShift,
    EnvironmentNoise,
    ObservationNoise,
    SystematicShift,
    Wind,
    _has_display,
)

#: thesis testing settings: none, Obs (σ^o), Act (σ^u), Env (σ^s), Dom (Σ).
PERTURBATIONS: tuple[str, ...] = ("none", "obs", "act", "env", "dom")


def wrap_env(env: gym.Env, perturbation: str = "none", sigma: float = 0.0, factors: Iterable[str] | None = None):
    """Wrap an existing task env with ``perturbation`` ("none" returns ``env`` itself).

    >>> import gymnasium as gym
    >>> type(wrap_env(gym.make("Hopper-v5"), "obs", 0.1)).__name__
    'ObservationNoise'
    """
    check_choice(perturbation, PERTURBATIONS, "perturbation")
    sigma = check_nonneg(sigma, "sigma")
    if factors is not None and perturbation not in ("env", "dom"):
        raise ValueError(f"factors only apply to perturbation 'env' or 'dom', not {perturbation!r}")
    if perturbation == "obs":
        return ObservationNoise(env, sigma)
    if perturbation == "act":
        return ActionNoise(env, sigma)
    if perturbation == "env":
        return EnvironmentNoise(env, sigma, factors)
    if perturbation == "dom":
        return DomainShift(env, sigma, factors)
    return env


def prepare_render(render_mode: str | None) -> None:
    """Ready this process for a task that renders in ``render_mode``: an offscreen mode (``rgb_array``,
    ``depth_array``, ...; the task checks the name) sets ``MUJOCO_GL=egl``
    (MuJoCo's renderer without a display) unless ``MUJOCO_GL`` is set already; ``"human"`` without a display
    (no ``DISPLAY``/``WAYLAND_DISPLAY``) is a one-line ``ValueError``, never MuJoCo's GLFW abort of the process
    (``tests/test_install.py``)."""
    if render_mode is None:
        return
    if render_mode == "human":
        if not _has_display():
            raise ValueError(
                "render_mode 'human' needs a display (no DISPLAY or WAYLAND_DISPLAY here); render offscreen with "
                "render_mode='rgb_array'"
            )
        return
    os.environ.setdefault("MUJOCO_GL", "egl")


def make_env(
    env: str,
    perturbation: str = "none",
    sigma: float = 0.0,
    *,
    factors: Iterable[str] | None = None,
    ratios: Mapping[str, float] | None = None,
    wind: tuple[float, float] | None = None,
    c_a: float | None = None,
    max_episode_steps: int | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    seed: int | None = None,
) -> gym.Env:
    """Build task ``env`` (short name or v5 id) with ``perturbation`` of scale ``sigma``.

    ``factors`` restricts "env"/"dom" to some factors of Table 3.2 (default all). ``ratios`` adds a
    :class:`SystematicShift` and ``wind=(low, high)`` a chapter-4 :class:`Wind` underneath the
    perturbation; no two of them may set the same factor. ``c_a`` is chapter 4's action penalty (Eq 4.12,
    r = v + 1 − c_a‖a‖², the v5 ``ctrl_cost_weight``; None: the task's own). ``env_kwargs`` go to
    ``gymnasium.make``. ``seed`` seeds the action space and calls
    ``reset(seed=seed)`` once. Unknown names, clashing factors and negative σ raise ``ValueError``.
    """
    task = short_name(env)
    check_choice(perturbation, PERTURBATIONS, "perturbation")
    check_nonneg(sigma, "sigma")
    if factors is not None:
        if perturbation not in ("env", "dom"):
            raise ValueError(f"factors only apply to perturbation 'env' or 'dom', not {perturbation!r}")
        factors = check_factors(task, factors)
    if max_episode_steps is not None and (int(max_episode_steps) != max_episode_steps or max_episode_steps < 1):
        raise ValueError(f"max_episode_steps must be a positive integer or None, got {max_episode_steps!r}")
    if seed is not None and (int(seed) != seed or seed < 0):
        raise ValueError(f"seed must be a non-negative integer or None, got {seed!r}")
    if wind is not None and (not isinstance(wind, (tuple, list)) or len(wind) != 2):
        raise ValueError(f"wind must be a (low, high) pair in m/s², got {wind!r}")

    owners: dict[str, str] = {}
    claims = [("ratios", list(ratios or ())), ("wind", ["wind"] if wind is not None else [])]
    if perturbation in ("env", "dom"):
        claims.append((perturbation, list(factors if factors is not None else check_factors(task, None))))
    for who, names in claims:
        for n in names:
            if n in owners:
                raise ValueError(f"factor {n!r} is set by both {owners[n]!r} and {who!r}")
            owners[n] = who

    kwargs: dict[str, Any] = {**model_kwargs(task), **(env_kwargs or {})}
    prepare_render(kwargs.get("render_mode"))
    if c_a is not None:
        kwargs["ctrl_cost_weight"] = check_nonneg(c_a, "c_a")
    if max_episode_steps is not None:
        kwargs["max_episode_steps"] = int(max_episode_steps)
    out: gym.Env = gym.make(lean_spec(resolve_env(task)), disable_env_checker=True, **kwargs)  # = gym's transitions
    assert env_short_name(out) == task
    if ratios is not None:
        out = SystematicShift(out, ratios)
    if wind is not None:
        out = Wind(out, wind[0], wind[1])
    out = wrap_env(out, perturbation, sigma, factors)
    if seed is not None:
        out.action_space.seed(int(seed))
        out.reset(seed=int(seed))
    return out


def make_registered(
    task: str,
    test: str,
    sigma: float = 0.0,
    seed: int | None = None,
    render_mode: str | None = None,
    **kwargs: Any,
) -> gym.Env:
    """Entry point of the registered ids (:func:`thesis_repro.envs.registry.register_envs`): ``make_env(task,
    test, sigma, seed=seed, **kwargs)``, ``render_mode`` passed to the task.

    >>> type(make_registered("Hopper", "act", 0.1)).__name__
    'ActionNoise'
    """
    env_kwargs = dict(kwargs.pop("env_kwargs", None) or {})
    if render_mode is not None:
        env_kwargs["render_mode"] = render_mode
    return make_env(task, test, sigma, seed=seed, env_kwargs=env_kwargs or None, **kwargs)


#: Chapter 4's wind range of Fig 4.1 (a) (ξ ~ U(-0.5, 0.5) m/s²): the default of the registered ``-wind`` ids.
DEFAULT_WIND: tuple[float, float] = (-0.5, 0.5)


def make_context(
    task: str,
    context: str,
    wind: tuple[float, float] | None = None,
    ratios: Mapping[str, float] | None = None,
    seed: int | None = None,
    render_mode: str | None = None,
    **kwargs: Any,
) -> gym.Env:
    """Entry point of the registered context ids (:data:`thesis_repro.envs.registry.CONTEXT_IDS`), as CARL
    registers contexts: ``context="wind"`` is chapter 4's wind, ξ ~ U(``wind``) per episode (default
    :data:`DEFAULT_WIND`); ``context="fixed"`` fixes factor values (``ratios``: factor -> ratio, wind in m/s²;
    ``None``: the task as it is). Other keywords (``c_a``, ``max_episode_steps``, ...) go to :func:`make_env`.

    >>> env = make_context("Hopper", "fixed", ratios={"body_mass": 1.5})
    >>> env.reset(seed=0)[1]["factors"]
    {'body_mass': 1.5}
    >>> type(make_context("Walker2d", "wind")).__name__
    'Wind'
    """
    env_kwargs = dict(kwargs.pop("env_kwargs", None) or {})
    if render_mode is not None:
        env_kwargs["render_mode"] = render_mode
    if context == "wind":
        if ratios is not None:
            raise ValueError("the wind ids take wind=(low, high); fixed factor values go to the -fixed ids (ratios=)")
        wind = DEFAULT_WIND if wind is None else wind
    elif context == "fixed":
        if wind is not None:
            raise ValueError("the -fixed ids take ratios= (wind in m/s² among them); wind=(low, high): the -wind ids")
    else:
        raise ValueError(f"unknown context {context!r}; valid contexts are: 'wind', 'fixed'")
    return make_env(task, wind=wind, ratios=ratios, seed=seed, env_kwargs=env_kwargs or None, **kwargs)
