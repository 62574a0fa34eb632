"""The job registry: every kind of cached job, the function that computes it and its folder label.

A :class:`~thesis_repro.core.cache.Job` names its work by a short *kind* (``"train"``, ``"evaluate"``,
``"arm-source"``, ...), never by a module path: the cache key is ``sha256(v<version>|<kind>|<config>)``,
so moving or renaming a job function only changes its entry here (:func:`register`) and keeps every
cached and shipped run. This module is the one place that imports the kit's own job functions by name
(:func:`resolve`). Each kind has a *label* function giving a readable folder name from the config
(``train/ppo-scn-16__Hopper__s0__<key>``); the label is decoration, lookups go by key.

A kind registers what the storage and the backends must know about it, so that neither names any kind:

* ``deps``: a ``"module:function"`` hook, ``fn(config) -> {name: Job}``, giving the jobs a job of this kind
  loads through the run cache (an evaluation's training run, a transfer job's source run). The Ray backend
  ships them to the worker (:func:`dependencies`).
* ``pin``: the identity of each dependency's entry is part of the key (``config[name] = identity``, filled in
  by :meth:`thesis_repro.core.cache.RunCache.bind`), so a recomputed dependency never reuses old results.
* ``resources``: what one Ray task of the kind asks for (:data:`RESOURCES`).

The hooks are imported only when called: this module imports no job module, and the run cache and the
backends import none either.

>>> KINDS["train"]
'thesis_repro.learners:train_job'
>>> kind_of("thesis_repro.learners:train_job")  # the path form maps to its kind
'train'
>>> label("train", {"algorithm": "ppo-scn-16", "env": "Hopper", "seed": 0})
'ppo-scn-16__Hopper__s0'
>>> label("train", {"algorithm": "kl-avg", "env": "Walker2d", "seed": 0, "c_a": 1.0, "wind": [-2.5, 2.5]})
'kl-avg__Walker2d__ca1__wind-2.5_2.5__s0'
>>> kind_of("trian")  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
ValueError: unknown job kind 'trian'; valid job kinds are: ...
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Callable, Mapping
from typing import Any

from thesis_repro.core.validation import check_choice

#: kind -> ``"module:function"`` computing it (called as ``fn(config, workdir)``).
KINDS: dict[str, str] = {}
#: kind -> ``label(config) -> str`` (readable part of the run folder name).
LABELS: dict[str, Callable[[Mapping[str, Any]], str]] = {}
#: kind -> ``"module:function"`` of its dependency hook, ``fn(config) -> {name: Job}`` (:func:`dependencies`).
DEPENDENCIES: dict[str, str] = {}
#: Kinds whose key pins the identity of their dependencies' entries (:meth:`~thesis_repro.core.cache.RunCache.bind`).
PINNED: set[str] = set()
#: kind -> Ray resources of one task (``num_cpus``, ``memory`` in bytes); others get the backend's default.
RESOURCES: dict[str, dict[str, float]] = {}
#: ``"module:function"`` -> kind, for jobs written in the path form ``Job("module:function", cfg)``
#: (every path a kind was ever registered at, so a moved function keeps its old spelling working).
PATHS: dict[str, str] = {}

_KIND_RE = re.compile(r"^[a-z0-9][a-z0-9_-]*$")
_UNSAFE = re.compile(r"[^A-Za-z0-9._+-]+")
#: Longest label kept in a folder name (the key follows it).
MAX_LABEL = 80


def _seed(config: Mapping[str, Any]) -> str:
    return f"s{config['seed']}" if "seed" in config else ""


def default_label(config: Mapping[str, Any]) -> str:
    """A few identifying values of ``config`` (algorithm, strategy, condition, family, env, seed), if present.

    >>> default_label({"family": "bic", "seed": 2, "generations": 100})
    'bic__s2'
    >>> default_label({"x": 3})
    ''
    """
    keys = ("algorithm", "policy", "strategy", "condition", "family", "env")
    parts = [str(config[k]) for k in keys if isinstance(config.get(k), str | int) and not isinstance(config[k], bool)]
    return "__".join(p for p in [*parts, _seed(config)] if p)


def train_label(config: Mapping[str, Any]) -> str:
    """``<algorithm>__<env>[__ca<c_a>][__wind<low>_<high>]__s<seed>`` of a training config.

    The chapter-4 env settings ``c_a`` and ``wind`` appear only when set, so runs of different chapter-4
    conditions get different folder names (chapter-3 labels, where both are None, are unchanged).

    >>> train_label({"algorithm": "joint", "env": "Hopper", "seed": 1, "c_a": 0.1, "wind": [-0.5, 0.5]})
    'joint__Hopper__ca0.1__wind-0.5_0.5__s1'
    """
    parts = [config.get("algorithm"), config.get("env")]
    if config.get("c_a") is not None:
        parts.append(f"ca{config['c_a']:g}")
    wind = config.get("wind")
    if wind is not None:
        parts.append(f"wind{wind[0]:g}_{wind[1]:g}")
    parts.append(_seed(config))
    return "__".join(str(p) for p in parts if p not in (None, ""))


def evaluate_label(config: Mapping[str, Any]) -> str:
    """The train block's label, then the test: perturbation (or ``shift``) and the snapshot step if any."""
    test = config.get("test", {})
    parts = [train_label(config.get("train", {}))]
    parts.append("shift" if "ratios" in test else str(test.get("perturbation", config.get("kind", ""))))
    if test.get("snapshot") is not None:
        parts.append(f"step{test['snapshot']}")
    return "__".join(p for p in parts if p)


def arm_target_label(config: Mapping[str, Any]) -> str:
    """``<strategy>__<source family>-to-<target>__s<seed>`` of a chapter-5 transfer job."""
    src = config.get("source", {})
    pair = f"{src.get('family', '?')}-to-{config.get('target', '?')}"
    return "__".join(p for p in (str(config.get("strategy", "")), pair, _seed(config)) if p)


def sanitize(text: str) -> str:
    """``text`` as a safe folder-name fragment: ``[A-Za-z0-9._+-]`` only, at most :data:`MAX_LABEL` chars.

    >>> sanitize("a b/c:d")
    'a-b-c-d'
    """
    return _UNSAFE.sub("-", text).strip("-.")[:MAX_LABEL]


def _check_path(path: str, what: str) -> None:
    if not isinstance(path, str) or path.count(":") != 1:
        raise ValueError(f"{what} must look like 'package.module:function', got {path!r}")


def register(
    kind: str,
    target: str,
    label: Callable[[Mapping[str, Any]], str] | None = None,
    aliases: tuple[str, ...] = (),
    *,
    deps: str | None = None,
    pin: bool = False,
    resources: Mapping[str, float] | None = None,
) -> str:
    """Register (or move) job ``kind`` computed by ``target`` (``"module:function"``); returns ``kind``.

    Re-registering a kind at another path *moves* it: keys do not change and the old path keeps mapping
    to the kind. ``aliases`` are further paths computing the same kind (e.g. a dispatching wrapper).
    ``deps``, ``pin`` and ``resources`` are described in the module docstring; a re-registration without
    them keeps the earlier ones.

    >>> register("my-kind", "mypkg.jobs:my_job", label=lambda c: f"n{c['n']}")
    'my-kind'
    >>> kind_of("mypkg.jobs:my_job"), label("my-kind", {"n": 3})
    ('my-kind', 'n3')
    >>> _ = KINDS.pop("my-kind"), LABELS.pop("my-kind"), PATHS.pop("mypkg.jobs:my_job")
    """
    if not isinstance(kind, str) or not _KIND_RE.match(kind):
        raise ValueError(f"job kind must be a short lowercase name like 'train' or 'arm-source', got {kind!r}")
    for path in (target, *aliases):
        _check_path(path, "job target")
        if PATHS.get(path, kind) != kind:
            raise ValueError(f"{path} is already registered as job kind {PATHS[path]!r}, not {kind!r}")
    if deps is not None:
        _check_path(deps, "dependency hook")
    if pin and deps is None and kind not in DEPENDENCIES:
        raise ValueError(f"job kind {kind!r}: pin=True needs a dependency hook (deps=...)")
    KINDS[kind] = target
    for path in (target, *aliases):
        PATHS[path] = kind
    if label is not None or kind not in LABELS:
        LABELS[kind] = label or default_label
    if deps is not None:
        DEPENDENCIES[kind] = deps
    if pin:
        PINNED.add(kind)
    if resources is not None:
        RESOURCES[kind] = dict(resources)
    return kind


def kind_of(name: str) -> str:
    """The registered kind named by ``name`` (a kind or a ``"module:function"`` path); else a ``ValueError``."""
    if name in KINDS:
        return name
    if name in PATHS:
        return PATHS[name]
    if isinstance(name, str) and ":" in name:
        listed = ", ".join(repr(k) for k in sorted(KINDS))
        raise ValueError(f"unknown job function path {name!r}; valid job kinds are: {listed}")
    return check_choice(name, sorted(KINDS), "job kind")


def label(kind: str, config: Mapping[str, Any]) -> str:
    """Readable, filesystem-safe label of a ``kind`` job with ``config`` (``"job"`` if nothing identifies it)."""
    try:
        text = LABELS.get(kind_of(kind), default_label)(config)
    except (KeyError, TypeError, AttributeError):
        text = default_label(config) if isinstance(config, Mapping) else ""
    return sanitize(text) or "job"


def _import(path: str) -> Any:
    module, func = path.split(":")
    return getattr(importlib.import_module(module), func)


def dependencies(kind: str, config: Mapping[str, Any]) -> dict[str, Any]:
    """``{name: Job}``: the jobs a ``kind`` job with ``config`` loads through the run cache (``{}`` for most).

    >>> sorted(dependencies("evaluate", {"train": {"algorithm": "ppo"}, "test": {}}))
    ['policy']
    >>> dependencies("square", {"x": 1})
    {}
    """
    path = DEPENDENCIES.get(kind_of(kind))
    return dict(_import(path)(config)) if path else {}


def pins_dependencies(kind: str) -> bool:
    """Does the key of a ``kind`` job pin the identity of its dependencies' entries?

    >>> pins_dependencies("evaluate"), pins_dependencies("arm-target")
    (True, False)
    """
    return kind_of(kind) in PINNED


def resolve(kind: str, target: str | None = None) -> Callable[[dict[str, Any]], Any]:
    """The job function of ``kind`` (imported now). ``target`` is the path recorded when the job was made,
    used when this process has not registered the kind (a user kind in a spawned worker)."""
    path = KINDS.get(kind) or target
    if path is None:
        kind_of(kind)  # raises the ValueError listing the kinds
    return _import(path)


_GIB = 1024**3
# The kit's job kinds. Training: every learner of chapters 3 and 4 (one train_job); evaluation: every
# testing sweep of chapters 3 and 4 (sigmas, or ratios such as wind / mass × friction, and c_a).
# Resources: every kit job is single-threaded (``torch.set_num_threads(1)``); training holds a model, a rollout
# buffer (SAC/DDPG: a replay buffer of up to 1e6 transitions) and its env copies.
# An evaluation pins its training run's identity ("policy"): new weights, new evaluation. The chapter-5
# transfer job only declares its source run (pinning it would change the keys of the shipped runs).
_ONE = {"num_cpus": 1, "memory": 1 * _GIB}
register("train", "thesis_repro.learners:train_job", train_label, resources={"num_cpus": 1, "memory": 2 * _GIB})
register(
    "evaluate",
    "thesis_repro.evaluation:evaluate_job",
    evaluate_label,
    deps="thesis_repro.evaluation.jobs:evaluate_dependencies",
    pin=True,
    resources=_ONE,
)
register("arm-source", "thesis_repro.arm.learn:source_job", resources=_ONE)
register("arm-competitor-source", "thesis_repro.arm.baselines:competitor_source_job", resources=_ONE)
register(
    "arm-target",
    "thesis_repro.arm.baselines:target_job",
    arm_target_label,
    deps="thesis_repro.arm.baselines:target_dependencies",
    resources=_ONE,
)
register("arm-curriculum", "thesis_repro.arm.curriculum:curriculum_job", resources=_ONE)
register("arm-solve", "thesis_repro.arm.learn:solve_task", resources=_ONE)
register(
    "square", "thesis_repro.core.cache:_square", lambda c: f"x{c['x']}", aliases=("thesis_repro.cache:_square",)
)  # toy job of doctests and tests
