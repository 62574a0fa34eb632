"""Chapter-3 environment model (thesis §3.1.1, Eq. 3.1-3.2, §3.2.2, Table 3.2) as Gymnasium wrappers.

Five v5 MuJoCo tasks (:data:`ENVS`), their environment factors (:data:`FACTORS`, Table 3.2) and one
wrapper per source of uncertainty: :class:`ObservationNoise` (σ^o), :class:`ActionNoise` (σ^u),
:class:`EnvironmentNoise` (σ^s, factors resampled every step), :class:`DomainShift` (Θ ~ N(Θ0, Σ) once
per episode), :class:`SystematicShift` (fixed ratios for heatmaps) and :class:`Wind` (chapter 4).

How σ maps onto each factor (details in :mod:`thesis_repro.envs.factors`): masses, friction and
gravity are relative, value = default × max(1 + σε, 0.05); "body mass" scales ALL bodies' masses (and
inertias) together; wind (Walker2d, Hopper) is a horizontal force ξ·M0 on the torso, ξ = σ·ε·9.81 m/s²
(M0 the default total mass), so σ = 0.2 is a force of std 20 % of the robot's weight.

>>> from thesis_repro.envs import make_env
>>> env = make_env("Hopper", "env", 0.2, seed=0)
>>> obs, info = env.reset(seed=0)
>>> obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
>>> sorted(info["factors"])
['body_mass', 'friction', 'gravity', 'wind']
>>> env.close()

The same env as a registered Gymnasium id (five tasks x four test types; σ and seed are ``make`` arguments):

>>> import gymnasium as gym
>>> env = gym.make("thesis_repro/Hopper-env-v0", sigma=0.2, seed=0)
"""

from thesis_repro.envs.factors import FACTORS, MIN_RATIO, WIND_SCALE, BoundFactor, Factor, FactorSet, check_factors
from thesis_repro.envs.make import PERTURBATIONS, make_context, make_env, make_registered, prepare_render, wrap_env
from thesis_repro.envs.registry import (
    CONTEXT_IDS,
    ENV_IDS,
    ENVS,
    TESTS,
    env_id,
    register_envs,
    resolve_env,
    short_name,
)
from thesis_repro.envs.wrappers import (
    ActionNoise,
    DomainShift,
    EnvironmentNoise,
    ObservationNoise,
    SystematicShift,
    Wind,
)

__all__ = [
    "ENVS",
    "FACTORS",
    "MIN_RATIO",
    "PERTURBATIONS",
    "WIND_SCALE",
    "ActionNoise",
    "BoundFactor",
    "DomainShift",
    "EnvironmentNoise",
    "Factor",
    "FactorSet",
    "ObservationNoise",
    "SystematicShift",
    "Wind",
    "check_factors",
    "make_env",
    "prepare_render",
    "resolve_env",
    "short_name",
    "wrap_env",
    "ENV_IDS",
    "CONTEXT_IDS",
    "make_context",
    "TESTS",
    "env_id",
    "make_registered",
    "register_envs",
]

register_envs()
