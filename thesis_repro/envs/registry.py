"""The five chapter-3 tasks (thesis Table 3.2) as Gymnasium v5 MuJoCo ids, and the kit's own Gymnasium ids.

>>> resolve_env("Hopper")
'Hopper-v5'
>>> resolve_env("Hopper-v5")
'Hopper-v5'

:func:`register_envs` (run by ``import thesis_repro.envs``) registers one id per task and test type, σ and seed
being ``gymnasium.make`` keyword arguments (as CARL and sunblaze's rl-generalization register theirs); without the
import, ``gymnasium.make("thesis_repro.envs:thesis_repro/Hopper-obs-v0", sigma=0.2)`` imports it first:

>>> import gymnasium as gym
>>> import thesis_repro.envs
>>> env = gym.make("thesis_repro/Hopper-dom-v0", sigma=0.2, seed=0)
>>> env.spec.id, sorted(env.reset(seed=1)[1]["factors"])
('thesis_repro/Hopper-dom-v0', ['body_mass', 'friction', 'gravity', 'wind'])
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from thesis_repro.core.validation import check_choice

#: short name -> Gymnasium id (the thesis used the -v2 versions of the same tasks; v2 needs mujoco-py).
ENVS: dict[str, str] = {
    "InvertedPendulum": "InvertedPendulum-v5",
    "InvertedDoublePendulum": "InvertedDoublePendulum-v5",
    "Walker2d": "Walker2d-v5",
    "Hopper": "Hopper-v5",
    "HalfCheetah": "HalfCheetah-v5",
}
_BY_ID: dict[str, str] = {v: k for k, v in ENVS.items()}

#: The kit's own copies of task models (passed as ``xml_file``). Gymnasium's half_cheetah.xml sets
#: ``settotalmass="14"``, which MuJoCo 4 reports as deprecated on every model load; our copy gives the
#: same masses and inertias with an explicit geom density (``tests/test_quiet.py`` checks they match).
MODEL_XML: dict[str, Path] = {"HalfCheetah": Path(__file__).resolve().parent / "assets" / "half_cheetah.xml"}


#: The test types a registered id perturbs with (thesis "Obs", "Act", "Env", "Dom"; see ``make.PERTURBATIONS``).
TESTS: tuple[str, ...] = ("obs", "act", "env", "dom")
NAMESPACE = "thesis_repro"


def env_id(task: str, test: str) -> str:
    """The kit's Gymnasium id of ``task`` under test type ``test``.

    >>> env_id("Walker2d-v5", "obs")
    'thesis_repro/Walker2d-obs-v0'
    """
    check_choice(test, TESTS, "test type")
    return f"{NAMESPACE}/{short_name(task)}-{test}-v0"


#: Every registered id: five tasks x four test types.
ENV_IDS: tuple[str, ...] = tuple(f"{NAMESPACE}/{t}-{p}-v0" for t in ENVS for p in TESTS)
#: The tasks with chapter 4's wind (a horizontal force on the torso).
WIND_TASKS: tuple[str, ...] = ("Walker2d", "Hopper")
#: The registered context ids, as CARL registers contexts: chapter 4's wind (``-wind``, ``wind=(low, high)``) and
#: fixed factor values (``-fixed``, ``ratios={...}``); :func:`thesis_repro.envs.make.make_context` builds them.
CONTEXT_IDS: tuple[str, ...] = tuple(f"{NAMESPACE}/{t}-wind-v0" for t in WIND_TASKS) + tuple(
    f"{NAMESPACE}/{t}-fixed-v0" for t in ENVS
)


def register_envs() -> None:
    """Register :data:`ENV_IDS` with Gymnasium (idempotent): ``gymnasium.make(id, sigma=..., seed=...)`` builds
    :func:`thesis_repro.envs.make_env` (task, test type, σ; any other ``make_env`` keyword passes through); and
    :data:`CONTEXT_IDS` (``gymnasium.make("thesis_repro/Hopper-wind-v0", wind=(-2, 2))``,
    ``gymnasium.make("thesis_repro/Hopper-fixed-v0", ratios={"body_mass": 1.5})``)."""
    import gymnasium as gym

    for task in ENVS:
        for test in TESTS:
            name = env_id(task, test)
            if name not in gym.registry:
                gym.register(
                    name,
                    entry_point="thesis_repro.envs.make:make_registered",
                    kwargs={"task": task, "test": test},
                    max_episode_steps=None,  # make_env's own time limit (the task's 1,000 steps)
                )
    for name in CONTEXT_IDS:
        task, context = name.removeprefix(f"{NAMESPACE}/").removesuffix("-v0").rsplit("-", 1)
        if name not in gym.registry:
            gym.register(
                name,
                entry_point="thesis_repro.envs.make:make_context",
                kwargs={"task": task, "context": context},
                max_episode_steps=None,
            )


def short_name(env: str) -> str:
    """Short name (key of :data:`ENVS`) of a short name or a full Gymnasium id; ``ValueError`` otherwise.

    >>> short_name("Walker2d-v5")
    'Walker2d'
    """
    if isinstance(env, str):
        if env in ENVS:
            return env
        if env in _BY_ID:
            return _BY_ID[env]
    check_choice(env, list(ENVS) + list(_BY_ID), "env")
    raise AssertionError("unreachable")  # check_choice raised


def resolve_env(env: str) -> str:
    """Gymnasium id of a short name or a full id; ``ValueError`` listing the valid names otherwise."""
    return ENVS[short_name(env)]


def model_kwargs(env: str) -> dict[str, Any]:
    """Extra ``gymnasium.make`` keyword arguments of a task: the kit's own model file where it has one.

    >>> model_kwargs("HalfCheetah")["xml_file"].endswith("half_cheetah.xml"), model_kwargs("Hopper")
    (True, {})
    """
    xml = MODEL_XML.get(short_name(env))
    return {"xml_file": str(xml)} if xml is not None else {}
