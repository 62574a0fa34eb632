"""The five chapter-3 tasks (thesis Table 3.2) as Gymnasium v5 MuJoCo ids.

>>> resolve_env("Hopper")
'Hopper-v5'
>>> resolve_env("Hopper-v5")
'Hopper-v5'
"""

from __future__ import annotations

from thesis_repro.validation import check_choice

#: short name -> Gymnasium id (the thesis used the -v2 versions of the same tasks; v2 needs mujoco-py).
ENVS: dict[str, str] = {
    "InvertedPendulum": "InvertedPendulum-v5",
    "InvertedDoublePendulum": "InvertedDoublePendulum-v5",
    "Walker2d": "Walker2d-v5",
    "Hopper": "Hopper-v5",
    "HalfCheetah": "HalfCheetah-v5",
}
_BY_ID: dict[str, str] = {v: k for k, v in ENVS.items()}


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
