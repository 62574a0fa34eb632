"""Gymnasium wrappers for the noise and domain shifts of thesis Eq. 3.1-3.2 and §3.2.2 (one per concern).

* :class:`ObservationNoise` σ^o: o_t = obs_t + σ·ε_t (also on the reset observation).
* :class:`ActionNoise` σ^u: u_t = clip(a_t + σ·ε_t, action bounds).
* :class:`EnvironmentNoise` σ^s: the factors θ^h are resampled before EVERY step ("Env").
* :class:`DomainShift` Σ: Θ ~ N(Θ0, Σ) sampled ONCE per episode, at reset ("Dom"); or held across episodes
  (:meth:`~_EpisodeDomain.hold_domain`: the meta-learners' one Θ_i per batch, Alg 1/2).
* :class:`SystematicShift`: fixed factor values (heatmap grids).
* :class:`Wind` (chapter 4): ξ ~ U(low, high) once per episode, the horizontal wind of ``factors``.

Randomness: each wrapper's ``self.np_random`` is its OWN generator, seeded by ``reset(seed=s)`` as
``default_rng([s, salt])`` (salt fixed per wrapper class). The base env's generator (initial states) is
therefore untouched by the noise draws: with the same seed, every σ and every perturbation starts its
episodes from the same initial states (common random numbers across a σ sweep). Without a seed the
wrapper's generator is derived once from the base env's seed.

Every wrapper records its constructor arguments (``gymnasium.utils.RecordConstructorArgs``), so ``env.spec``
recreates it and ``gymnasium.utils.env_checker.check_env`` passes in full. The factor wrappers work on any MuJoCo
env whose model has the bodies their factors scale (:mod:`thesis_repro.envs.factors`); any other env is a
one-line ``ValueError`` naming what is missing.

Factor wrappers put the applied values in ``info["factors"]`` (ratios; wind ξ in m/s²) and restore the
model's defaults on ``close()`` (and each ``reset()`` writes values computed from the defaults).

>>> from thesis_repro.envs import make_env
>>> env = make_env("Hopper", "dom", 0.2, seed=0)
>>> obs, info = env.reset(seed=1)
>>> sorted(info["factors"])
['body_mass', 'friction', 'gravity', 'wind']
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from typing import Any

import gymnasium as gym
import numpy as np

from thesis_repro.core.validation import check_nonneg
from thesis_repro.envs.factors import FactorSet


class _Seeded(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Wrapper with its own ``np_random``, reseeded by ``reset(seed=...)``; records its constructor arguments."""

    _SALT = 0

    def __init__(self, env: gym.Env, **recorded: Any) -> None:
        if not isinstance(env, gym.Env):
            raise ValueError(f"{type(self).__name__} wraps a gymnasium.Env, got {type(env).__name__}")
        gym.utils.RecordConstructorArgs.__init__(self, **recorded)
        gym.Wrapper.__init__(self, env)
        self._own_rng: np.random.Generator | None = None

    @property
    def metadata(self) -> dict[str, Any]:  # type: ignore[override]
        """The env's metadata; without a display (no ``DISPLAY``/``WAYLAND_DISPLAY``) ``render_modes`` leaves out
        ``"human"``, which needs a window (MuJoCo's GLFW viewer aborts the process without a monitor)."""
        meta = self._metadata if self._metadata is not None else self.env.metadata
        modes = meta.get("render_modes") or []
        if "human" in modes and not _has_display():
            meta = {**meta, "render_modes": [m for m in modes if m != "human"]}
        return meta

    @metadata.setter
    def metadata(self, value: dict[str, Any]) -> None:
        self._metadata = value

    @property
    def np_random(self) -> np.random.Generator:  # type: ignore[override]
        if self._own_rng is None:
            seed = self.env.unwrapped.np_random_seed
            if seed is None or seed < 0:
                seed = int(self.env.unwrapped.np_random.integers(2**63 - 1))
            self._own_rng = np.random.default_rng([int(seed), self._SALT])
        return self._own_rng

    @np_random.setter
    def np_random(self, value: np.random.Generator) -> None:
        self._own_rng = value

    def _reseed(self, seed: int | None) -> None:
        if seed is not None:
            self._own_rng = np.random.default_rng([int(seed), self._SALT])


class ObservationNoise(_Seeded):
    """Gaussian observation noise σ^o added to every observation (thesis "Obs").

    >>> import gymnasium as gym
    >>> env = ObservationNoise(gym.make("Hopper-v5"), sigma=0.1)
    >>> env.reset(seed=0)[0].shape
    (11,)
    """

    _SALT = 1

    def __init__(self, env: gym.Env, sigma: float) -> None:
        sigma = check_nonneg(sigma, "observation noise sigma")
        super().__init__(env, sigma=sigma)
        self.sigma = sigma

    def _noisy(self, obs: np.ndarray) -> np.ndarray:
        if self.sigma == 0.0:
            return obs
        noise = self.np_random.standard_normal(np.shape(obs))
        return (obs + self.sigma * noise).astype(np.asarray(obs).dtype, copy=False)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self._reseed(seed)
        return self._noisy(obs), info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self._noisy(obs), reward, terminated, truncated, info


class ActionNoise(_Seeded):
    """Gaussian actuation noise σ^u added to each action before the env, then clipped to the bounds ("Act").

    >>> import gymnasium as gym
    >>> env = ActionNoise(gym.make("Hopper-v5"), sigma=0.1)
    >>> _ = env.reset(seed=0); _ = env.step(env.action_space.sample())
    """

    _SALT = 2

    def __init__(self, env: gym.Env, sigma: float) -> None:
        sigma = check_nonneg(sigma, "action noise sigma")
        super().__init__(env, sigma=sigma)
        self.sigma = sigma
        space = env.action_space
        if not isinstance(space, gym.spaces.Box):
            raise ValueError(f"ActionNoise needs a Box action space, got {space}")
        self._low = space.low.astype(np.float64)
        self._high = space.high.astype(np.float64)

    def noisy_action(self, action) -> np.ndarray:
        """The action that reaches the simulator."""
        a = np.asarray(action, dtype=np.float64)
        if self.sigma != 0.0:
            a = a + self.sigma * self.np_random.standard_normal(a.shape)
        return np.clip(a, self._low, self._high)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        out = self.env.reset(seed=seed, options=options)
        self._reseed(seed)
        return out

    def step(self, action):
        return self.env.step(self.noisy_action(action))


class _FactorWrapper(_Seeded):
    """Base of the wrappers that write environment factors; restores defaults on ``close()``."""

    def __init__(self, env: gym.Env, names: Iterable[str] | None, /, **recorded: Any) -> None:
        super().__init__(env, **recorded)
        self.factors = FactorSet(env, names, who=type(self).__name__)

    @property
    def factor_names(self) -> tuple[str, ...]:
        return self.factors.names

    def factor_values(self) -> dict[str, float]:
        """Currently applied values: ratios for relative factors, ξ (m/s²) for wind."""
        return self.factors.values()

    def _on_reset(self) -> None:
        self.factors.restore()

    def _before_step(self) -> None:
        self.factors.reapply()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self._reseed(seed)
        self._on_reset()
        info["factors"] = self.factors.values()
        return obs, info

    def step(self, action):
        self._before_step()
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["factors"] = self.factors.values()
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        self.factors.restore()
        super().close()


class EnvironmentNoise(_FactorWrapper):
    """Environment-parameter noise σ^s: every factor resampled before EVERY step ("Env").

    Relative factors r = max(1 + σε, 0.05); wind ξ = σ·ε·9.81 m/s² (see :mod:`thesis_repro.envs.factors`).
    ``info["factors"]`` of a step holds the values used during that step; reset restores the defaults.
    """

    _SALT = 3

    def __init__(self, env: gym.Env, sigma: float, factors: Iterable[str] | None = None) -> None:
        sigma, factors = check_nonneg(sigma, "environment noise sigma"), _names(factors)
        super().__init__(env, factors, sigma=sigma, factors=factors)
        self.sigma = sigma

    def _before_step(self) -> None:
        if self.sigma == 0.0:
            self.factors.reapply()
        else:
            self.factors.sample(self.np_random, self.sigma)


class _EpisodeDomain(_FactorWrapper):
    """A factor wrapper that draws a new domain at every reset, unless one is held.

    :meth:`hold_domain` draws a domain NOW (from the wrapper's own seeded generator, as a reset would) and
    keeps it across episode resets until the next ``hold_domain`` or :meth:`release_domain`: the
    meta-learners' "sample a batch of domains Θ_i ~ p(Θ)" of Alg 1/2, one Θ_i for all of domain i's batches.
    """

    # class-level default: the instance attribute exists only once a domain was held (exact resume of runs
    # that never hold one is unchanged)
    _held: dict[str, float] | None = None

    def _draw(self) -> None:
        raise NotImplementedError

    def _on_reset(self) -> None:
        if self._held is not None:
            self.factors.set(self._held)
        else:
            self._draw()

    def hold_domain(self) -> dict[str, float]:
        """Draw a new domain, apply it now and keep it across resets; returns its factor values."""
        self._draw()
        self._held = self.factors.values()
        return dict(self._held)

    def release_domain(self) -> None:
        """Back to a new domain per episode (from the next reset on)."""
        self._held = None


class DomainShift(_EpisodeDomain):
    """Domain shift Θ ~ N(Θ0, Σ), Σ = σ²I, sampled ONCE per episode at reset ("Dom"), or held (``hold_domain``)."""

    _SALT = 4

    def __init__(self, env: gym.Env, sigma: float, factors: Iterable[str] | None = None) -> None:
        sigma, factors = check_nonneg(sigma, "domain shift sigma"), _names(factors)
        super().__init__(env, factors, sigma=sigma, factors=factors)
        self.sigma = sigma

    def _draw(self) -> None:
        if self.sigma == 0.0:
            self.factors.restore()
        else:
            self.factors.sample(self.np_random, self.sigma)


class SystematicShift(_FactorWrapper):
    """Fixed factor values for heatmap grids: ratios for relative factors, wind ξ in m/s².

    Applied at construction and re-applied after every reset.

    >>> import gymnasium as gym
    >>> env = SystematicShift(gym.make("Hopper-v5"), {"body_mass": 1.5, "wind": 1.0})
    >>> env.reset(seed=0)[1]["factors"]
    {'body_mass': 1.5, 'wind': 1.0}
    """

    _SALT = 5

    def __init__(self, env: gym.Env, ratios: Mapping[str, float]) -> None:
        if not isinstance(ratios, Mapping) or not ratios:
            raise ValueError(f"ratios must be a non-empty dict of factor -> value, got {ratios!r}")
        super().__init__(env, list(ratios), ratios=dict(ratios))
        values: dict[str, float] = {}
        for b in self.factors.bound:
            v = ratios[b.name]
            if b.relative:
                values[b.name] = _check_ratio(v, b.name)
            else:
                values[b.name] = _check_finite(v, b.name)
        self.ratios = values
        self.factors.set(values)

    def _on_reset(self) -> None:
        self.factors.set(self.ratios)


class Wind(_EpisodeDomain):
    """Chapter 4 wind: ξ ~ U(low, high) (m/s², force ξ·M0 on the torso) sampled once per episode (or held).

    >>> import gymnasium as gym
    >>> env = Wind(gym.make("Walker2d-v5"), -0.5, 0.5)
    >>> -0.5 <= env.reset(seed=0)[1]["factors"]["wind"] <= 0.5
    True
    """

    _SALT = 6

    def __init__(self, env: gym.Env, low: float, high: float) -> None:
        lo, hi = _check_finite(low, "wind low"), _check_finite(high, "wind high")
        if lo > hi:
            raise ValueError(f"wind low must be <= high, got low={low!r}, high={high!r}")
        super().__init__(env, ["wind"], low=lo, high=hi)
        self.low, self.high = lo, hi
        (self._bound,) = self.factors.bound

    def _draw(self) -> None:
        self._bound.set(float(self.np_random.uniform(self.low, self.high)))


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _names(factors: Iterable[str] | None) -> tuple[str, ...] | None:
    """Factor names as a tuple (recorded and compared by ``env.spec``); ``None`` stays ``None``."""
    if factors is None:
        return None
    if isinstance(factors, str):
        return (factors,)
    if not isinstance(factors, Iterable):
        raise ValueError(f"factors must be factor names or None, got {factors!r}")
    return tuple(factors)


def _check_finite(value: float, what: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{what} must be a finite number, got {value!r}") from err
    if not np.isfinite(v):
        raise ValueError(f"{what} must be a finite number, got {value!r}")
    return v


def _check_ratio(value: float, what: str) -> float:
    v = _check_finite(value, f"{what} ratio")
    if v <= 0.0:
        raise ValueError(f"{what} ratio must be > 0 (1 = default), got {value!r}")
    return v
