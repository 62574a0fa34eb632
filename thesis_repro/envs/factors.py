"""Environment factors θ^h of thesis Table 3.2, read from and written to a live MuJoCo model.

How a factor value maps onto the simulator (σ is the noise / shift scale, ε ~ N(0, 1)):

* **relative factors** (``cart_mass``, ``pole_mass``, ``pole1_mass``, ``pole2_mass``, ``body_mass``,
  ``friction``, ``gravity``): the value is a *ratio* r to the default, written as default × r.
  Sampled as r = max(1 + σ·ε, MIN_RATIO) with ``MIN_RATIO = 0.05`` (masses, friction and gravity must stay
  positive; at σ ≤ 0.4 the clip is hit with probability < 1e-6).

  - ``body_mass``: ALL bodies of the robot scaled together by one ratio (``model.body_mass`` and
    ``model.body_inertia``, i.e. as if the density were scaled, so the bodies' shapes stay consistent).
  - ``cart_mass`` / ``pole_mass`` / ``pole1_mass`` / ``pole2_mass``: the one named body (mass and inertia).
  - ``friction``: the sliding friction coefficient of every geom (``model.geom_friction[:, 0]``); MuJoCo
    uses the max over the two geoms of a contact, so every contact's friction is scaled by r.
  - ``gravity``: the gravity vector ``model.opt.gravity``.

* **wind** (``wind``, Walker2d and Hopper only): default 0, so it is not relative. Its value ξ is a
  horizontal acceleration in m/s²; the wind is the constant horizontal force F = ξ · M0 (N) at the torso's
  centre of mass, along +x (the running direction) for ξ > 0, M0 the robot's *default* total mass (so
  wind and ``body_mass`` are independent factors). Sampled as ξ = σ·ε·WIND_SCALE with
  ``WIND_SCALE = g = 9.81`` m/s²: σ = 0.2 is a wind force of std 20 % of the robot's weight, the same
  relative size as a 20 % mass/gravity change. Chapter 4's ξ ~ U(-2.5, 2.5) and
  test range [-5, 5] are read in the same unit (|ξ| = 5 is a force of half the robot's weight).
  It is written into ``data.xfrc_applied[torso, 0]``, which ``mj_resetData`` (every ``reset()``) zeroes,
  so the wrappers re-apply it after every reset and before every step.

Defaults are read once per simulator (stored on the unwrapped env, shared by nested wrappers) and every
write is computed from them, so values never drift and ``restore()`` is exact.

>>> import gymnasium as gym
>>> env = gym.make("Hopper-v5").unwrapped
>>> mass = FACTORS["Hopper"]["body_mass"].bind(env)
>>> mass.set(1.5); round(float(env.model.body_mass[1:].sum() / mass.defaults[0].sum()), 6)
1.5
>>> mass.restore(); float(mass.value)
1.0
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import mujoco
import numpy as np

from thesis_repro.core.validation import check_choice
from thesis_repro.envs.registry import ENVS, short_name

MIN_RATIO: float = 0.05
WIND_SCALE: float = 9.81  # m/s² of horizontal acceleration per unit of σ·ε (= |g|)
_DEFAULTS_ATTR = "_thesis_repro_factor_defaults"


def _body_id(model: mujoco.MjModel, name: str) -> int:
    """Body index of ``name``; ``ValueError`` if missing (mj_name2id's -1 would silently hit the last body)."""
    idx = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
    if idx < 0:
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(model.nbody)]
        raise ValueError(f"body {name!r} not in the MuJoCo model; bodies are: {names}")
    return int(idx)


@dataclass(frozen=True)
class Factor:
    """One environment factor: knows how to read its default and write a value into a MuJoCo env.

    ``relative`` factors take a ratio to the default (1 = default); the others take an absolute value.
    """

    name: str
    relative: bool = True

    @property
    def neutral(self) -> float:
        """The value that leaves the simulator at its default (1 for ratios, 0 for absolute values)."""
        return 1.0 if self.relative else 0.0

    def bind(self, env) -> BoundFactor:
        """Attach to an (unwrapped) MuJoCo env; defaults are read on first bind and then shared."""
        base = env.unwrapped
        store = base.__dict__.setdefault(_DEFAULTS_ATTR, {})
        key = repr(self)
        if key not in store:
            store[key] = tuple(np.array(a, dtype=np.float64, copy=True) for a in self._read(base))
        return BoundFactor(self, base, store[key])

    # --- subclass hooks ---------------------------------------------------------------------------------
    def _read(self, base) -> tuple[np.ndarray, ...]:
        raise NotImplementedError

    def _targets(self, base) -> tuple[np.ndarray, ...]:
        """Live arrays (views into the model/data) that ``_read`` read from, in the same order."""
        raise NotImplementedError


@dataclass(frozen=True)
class BodyMass(Factor):
    """Mass and inertia of the named bodies (``bodies=()``: every body but the world) scaled by one ratio."""

    bodies: tuple[str, ...] = ()

    def _index(self, model) -> slice | np.ndarray:
        if not self.bodies:
            return slice(1, model.nbody)
        return np.array([_body_id(model, b) for b in self.bodies])

    def _read(self, base):
        idx = self._index(base.model)
        return base.model.body_mass[idx], base.model.body_inertia[idx]

    def _targets(self, base):
        idx = self._index(base.model)
        if isinstance(idx, slice):
            return base.model.body_mass[idx], base.model.body_inertia[idx]
        return _Fancy(base.model.body_mass, idx), _Fancy(base.model.body_inertia, idx)


@dataclass(frozen=True)
class Friction(Factor):
    """Sliding friction coefficient of every geom (``geom_friction[:, 0]``)."""

    def _read(self, base):
        return (base.model.geom_friction[:, 0],)

    def _targets(self, base):
        return (base.model.geom_friction[:, 0],)


@dataclass(frozen=True)
class Gravity(Factor):
    """The gravity vector ``opt.gravity``."""

    def _read(self, base):
        return (base.model.opt.gravity,)

    def _targets(self, base):
        return (base.model.opt.gravity,)


@dataclass(frozen=True)
class WindForce(Factor):
    """Horizontal force ξ·M0 (N) on ``body``; ξ in m/s², M0 the default total mass. Not relative."""

    relative: bool = False
    body: str = "torso"

    def _read(self, base):
        mass = np.asarray(base.model.body_mass[1:], dtype=np.float64).sum()
        return (np.array([mass]), np.array([_body_id(base.model, self.body)], dtype=np.float64))

    def _targets(self, base):
        return ()


class _Fancy:
    """Write-through view of ``array[idx]`` for a non-contiguous index (numpy fancy indexing copies)."""

    __slots__ = ("array", "idx")

    def __init__(self, array: np.ndarray, idx: np.ndarray) -> None:
        self.array, self.idx = array, idx


class BoundFactor:
    """A factor attached to one simulator: ``set(value)``, ``restore()``, ``reapply()``, ``value``."""

    def __init__(self, factor: Factor, base, defaults: tuple[np.ndarray, ...]) -> None:
        self.factor, self.name, self.relative = factor, factor.name, factor.relative
        self.defaults = defaults
        self.value: float = factor.neutral
        self._base = base
        self._wind = isinstance(factor, WindForce)
        if self._wind:
            self._total_mass = float(defaults[0][0])
            self._bid = int(defaults[1][0])
            self._xfrc = base.data.xfrc_applied  # stable array; mj_resetData zeroes it in place
            self._force = 0.0
        else:
            targets = factor._targets(base)
            self._fancy = any(isinstance(t, _Fancy) for t in targets)
            self._pairs = tuple(zip(targets, defaults, strict=True))

    def set(self, value: float) -> None:
        """Write ``value`` (a ratio for relative factors, ξ in m/s² for wind) into the simulator."""
        self.value = value
        if self._wind:
            self._force = value * self._total_mass
            self._xfrc[self._bid, 0] = self._force
            return
        if self._fancy:
            for t, d in self._pairs:
                t.array[t.idx] = d * value
        else:
            for t, d in self._pairs:
                np.multiply(d, value, out=t)

    def reapply(self) -> None:
        """Re-write state that ``reset()`` clears (only the wind force lives in ``data``)."""
        if self._wind:
            self._xfrc[self._bid, 0] = self._force

    def restore(self) -> None:
        """Write the saved defaults back exactly."""
        self.set(self.factor.neutral)


#: Table 3.2: env short name -> factor name -> Factor.
FACTORS: dict[str, dict[str, Factor]] = {
    "InvertedPendulum": {
        "cart_mass": BodyMass("cart_mass", bodies=("cart",)),
        "pole_mass": BodyMass("pole_mass", bodies=("pole",)),
    },
    "InvertedDoublePendulum": {
        "cart_mass": BodyMass("cart_mass", bodies=("cart",)),
        "pole1_mass": BodyMass("pole1_mass", bodies=("pole",)),
        "pole2_mass": BodyMass("pole2_mass", bodies=("pole2",)),
    },
    "Walker2d": {
        "body_mass": BodyMass("body_mass"),
        "wind": WindForce("wind"),
        "friction": Friction("friction"),
        "gravity": Gravity("gravity"),
    },
    "Hopper": {
        "body_mass": BodyMass("body_mass"),
        "wind": WindForce("wind"),
        "friction": Friction("friction"),
        "gravity": Gravity("gravity"),
    },
    "HalfCheetah": {
        "body_mass": BodyMass("body_mass"),
        "friction": Friction("friction"),
        "gravity": Gravity("gravity"),
    },
}
assert set(FACTORS) == set(ENVS)


#: Every factor by name, for MuJoCo envs outside the five tasks: a factor applies to any model that has the bodies
#: it names (``body_mass``, ``friction`` and ``gravity`` apply to every model; ``wind`` needs a ``torso``).
CATALOGUE: dict[str, Factor] = {name: f for table in FACTORS.values() for name, f in table.items()}
#: Factors of a MuJoCo env outside the five tasks when none are named.
GENERIC_DEFAULT: tuple[str, ...] = ("body_mass", "friction", "gravity")


def env_short_name(env) -> str:
    """Short task name of a Gymnasium env (wrapped or not) from its spec id."""
    spec = env.unwrapped.spec
    if spec is None:
        raise ValueError("env has no spec; build it with gymnasium.make or thesis_repro.envs.make_env")
    return short_name(spec.id)


def task_of(env) -> str | None:
    """Short task name of one of the five tasks, else ``None`` (any other env, or one without a spec).

    >>> import gymnasium as gym
    >>> task_of(gym.make("Hopper-v5")), task_of(gym.make("Ant-v5"))
    ('Hopper', None)
    """
    spec = env.unwrapped.spec
    if spec is None:
        return None
    try:
        return short_name(spec.id)
    except ValueError:
        return None


def env_label(env) -> str:
    """The env's spec id, or its class name when it has no spec (for error messages)."""
    spec = env.unwrapped.spec
    return spec.id if spec is not None else type(env.unwrapped).__name__


def check_mujoco(env, who: str) -> None:
    """``ValueError`` naming ``who`` and the env unless ``env`` is a MuJoCo env (``model`` and ``data``).

    >>> import gymnasium as gym
    >>> check_mujoco(gym.make("Pendulum-v1"), "DomainShift")
    Traceback (most recent call last):
    ...
    ValueError: DomainShift needs a MuJoCo env (with a mujoco.MjModel in .model and .data), but Pendulum-v1 is not one
    """
    base = env.unwrapped
    if not isinstance(getattr(base, "model", None), mujoco.MjModel) or getattr(base, "data", None) is None:
        raise ValueError(
            f"{who} needs a MuJoCo env (with a mujoco.MjModel in .model and .data), but {env_label(env)} is not one"
        )


def _bodies(factor: Factor) -> tuple[str, ...]:
    if isinstance(factor, BodyMass):
        return factor.bodies
    if isinstance(factor, WindForce):
        return (factor.body,)
    return ()


def check_generic_factors(env, names: Iterable[str] | None) -> tuple[str, ...]:
    """Validated factor names for a MuJoCo env outside the five tasks (``None``: :data:`GENERIC_DEFAULT`).

    A factor needs the bodies it names; a missing one is a ``ValueError`` naming it and the model's bodies.
    """
    if names is None:
        return GENERIC_DEFAULT
    out = (names,) if isinstance(names, str) else tuple(names)
    if not out:
        raise ValueError(f"factors must not be empty; valid factors are: {', '.join(CATALOGUE)}")
    if len(set(out)) != len(out):
        raise ValueError(f"duplicate factor names in {out}")
    model = env.unwrapped.model
    all_bodies = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(model.nbody)]
    all_bodies = [b for b in all_bodies if b]
    for n in out:
        check_choice(n, list(CATALOGUE), "factor")
        missing = [b for b in _bodies(CATALOGUE[n]) if b not in all_bodies]
        if missing:
            raise ValueError(
                f"factor {n!r} needs body {missing[0]!r}, which the MuJoCo model of {env_label(env)} does not have "
                f"(its bodies: {', '.join(str(b) for b in all_bodies)})"
            )
    return out


def check_factors(env: str, names: Iterable[str] | None) -> tuple[str, ...]:
    """Validated factor names of task ``env`` (``None`` = all of Table 3.2); ``ValueError`` names the valid ones."""
    valid = FACTORS[short_name(env)]
    if names is None:
        return tuple(valid)
    if isinstance(names, str):
        names = (names,)
    out = tuple(names)
    if not out:
        raise ValueError(f"factors must not be empty; valid factors for {env} are: {', '.join(valid)}")
    for n in out:
        check_choice(n, list(valid), f"factor of {short_name(env)}")
    if len(set(out)) != len(out):
        raise ValueError(f"duplicate factor names in {out}")
    return out


class FactorSet:
    """Several bound factors of one MuJoCo env, sampled and written together (used by the wrappers).

    On one of the five tasks the factors are Table 3.2's (default: all of the task's); on any other MuJoCo env
    any factor of :data:`CATALOGUE` whose bodies the model has (default: :data:`GENERIC_DEFAULT`).

    ``sample(rng, sigma)`` draws one ε per factor: ratios max(1 + σε, MIN_RATIO), wind σ·ε·WIND_SCALE.
    """

    def __init__(self, env, names: Iterable[str] | None, who: str = "a factor wrapper") -> None:
        check_mujoco(env, who)
        task = task_of(env)
        if task is not None:  # one of the five tasks: Table 3.2's factors
            self.names = check_factors(task, names)
            table = FACTORS[task]
        else:
            self.names = check_generic_factors(env, names)
            table = CATALOGUE
        self.bound = [table[n].bind(env) for n in self.names]
        self._n = len(self.bound)
        self._wind = [b for b in self.bound if not b.relative]

    def sample(self, rng: np.random.Generator, sigma: float) -> None:
        eps = rng.standard_normal(self._n).tolist()
        for b, e in zip(self.bound, eps, strict=True):
            if b.relative:
                v = 1.0 + sigma * e
                b.set(v if v > MIN_RATIO else MIN_RATIO)
            else:
                b.set(sigma * WIND_SCALE * e)

    def set(self, values: Mapping[str, float]) -> None:
        for b in self.bound:
            if b.name in values:
                b.set(float(values[b.name]))

    def reapply(self) -> None:
        for b in self._wind:
            b.reapply()

    def restore(self) -> None:
        for b in self.bound:
            b.restore()

    def values(self) -> dict[str, float]:
        """Currently applied values: ratios for relative factors, ξ (m/s²) for wind."""
        return {b.name: b.value for b in self.bound}
