"""Exact resume: capture every piece of a training run's live state that ``model.save`` does not hold, and
write it back IN PLACE into a freshly built run, so an interrupted run continues bit-identically.

``model.save`` keeps the parameters, optimiser states and SB3's bookkeeping; it does not keep the
simulators (MuJoCo ``MjModel`` edits of the domain wrappers, ``MjData`` mid-episode, warm starts), the
wrappers' counters and random generators, the VecEnv wrappers' running statistics, the multi-domain
learners' per-domain views, the action noise, nor the global RNGs (numpy's legacy global state draws
PPO's minibatch permutations, torch's draws the actions). :func:`capture` walks the object graph of a
model (attribute by attribute, each object once) and records

* every ``numpy`` array (copied), scalar, string and plain container,
* every ``numpy`` random ``Generator`` / ``RandomState`` (its bit-generator state),
* every ``mujoco.MjData`` (a full copy) and ``mujoco.MjModel`` (its arrays and options),

skipping torch modules, tensors and optimisers (``model.save`` holds them), the replay buffer (saved
apart) and callables. :func:`restore` walks the same graph of a freshly built run (same config, same
code) and writes the recorded values back in place: arrays with ``a[...] = saved`` (so views into a
simulator, e.g. a factor's target array, keep pointing at the live simulator), simulators with
``mj_copyData`` / array copies, generators by state. A graph that differs (other code, another config)
raises :class:`ResumeMismatch`; the caller then starts the run afresh, which is exact too.

>>> import numpy as np
>>> class Box:
...     def __init__(self):
...         self.rng, self.x, self.n = np.random.default_rng(0), np.zeros(2), 0
>>> a = Box(); _ = a.rng.random(); a.x += 1; a.n = 5
>>> saved = capture(a)
>>> b = Box(); view = b.x; restore(b, saved)
>>> b.n, view.tolist(), b.rng.random() == a.rng.random()
(5, [1.0, 1.0], True)
"""

from __future__ import annotations

import functools
import inspect
import random
import re
import types
from collections import deque
from typing import Any

import mujoco
import numpy as np
import torch as th

#: Attribute names never walked (SB3 keeps them itself, or they hold no run state).
SKIP_ATTRS = frozenset(
    {
        "class_attributes",  # VecEnvWrapper's copy of its class dict (functions, mappingproxies)
        "replay_buffer",  # off-policy: saved apart with save_replay_buffer
        "policy_class",
        "lr_schedule",
        "_logger",
        "_custom_logger",
        "mujoco_renderer",
        "spec",
        "_cached_spec",
    }
)
_SCALARS = (bool, int, float, complex, str, bytes, type(None), np.generic)


_ATTR_PATH = re.compile(r"^(.*)(\.[A-Za-z_][A-Za-z0-9_]*)$")


class ResumeMismatch(RuntimeError):
    """The freshly built run does not have the structure of the captured one."""


def _plain(obj: Any, depth: int = 0) -> bool:
    """True for data that can be copied and replaced wholesale (scalars, arrays, containers of them)."""
    if isinstance(obj, (*_SCALARS, np.ndarray)):
        return True
    if depth > 6:
        return False
    if isinstance(obj, list | tuple | deque):
        return all(_plain(v, depth + 1) for v in obj)
    if isinstance(obj, dict):
        return all(isinstance(k, _SCALARS) and _plain(v, depth + 1) for k, v in obj.items())
    return False


def _skip(obj: Any) -> bool:
    """Objects that hold no run state of ours (torch state is in ``model.save``; code is code)."""
    if isinstance(obj, th.Tensor | th.nn.Module | th.optim.Optimizer | type | types.ModuleType | functools.partial):
        return True
    return inspect.isroutine(obj) or isinstance(obj, set | frozenset | range | slice)


def _children(obj: Any) -> list[tuple[str, Any]]:
    if isinstance(obj, list | tuple | deque):
        return [(f"[{i}]", v) for i, v in enumerate(obj)]
    if isinstance(obj, dict):
        return [(f"[{k!r}]", v) for k, v in obj.items() if isinstance(k, _SCALARS)]
    names: dict[str, Any] = {}
    if hasattr(obj, "__dict__"):
        names.update(vars(obj))
    for cls in type(obj).__mro__:
        for slot in getattr(cls, "__slots__", ()):
            if hasattr(obj, slot):
                names[slot] = getattr(obj, slot)
    return [(f".{k}", v) for k, v in sorted(names.items()) if k not in SKIP_ATTRS]


def _mjmodel_state(model: mujoco.MjModel) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for holder, prefix in ((model, ""), (model.opt, "opt.")):
        for name in dir(holder):
            if name.startswith("_"):
                continue
            value = getattr(holder, name)
            if isinstance(value, np.ndarray) or (prefix and isinstance(value, int | float)):
                out[prefix + name] = value.copy() if isinstance(value, np.ndarray) else value
    return out


def _set_mjmodel(model: mujoco.MjModel, saved: dict[str, Any]) -> None:
    for key, value in saved.items():
        holder, name = (model.opt, key[4:]) if key.startswith("opt.") else (model, key)
        live = getattr(holder, name)
        if isinstance(live, np.ndarray):
            if live.shape != value.shape:
                raise ResumeMismatch(f"MjModel.{key}: shape {live.shape} != saved {value.shape}")
            live[...] = value
        else:
            setattr(holder, name, value)


def _signature(obj: Any) -> tuple:
    if isinstance(obj, dict):
        return (type(obj).__name__, tuple(repr(k) for k in obj))
    return (type(obj).__name__, len(obj))


def capture(root: Any) -> dict[str, Any]:
    """Every piece of run state reachable from ``root`` (see module docstring), keyed by attribute path."""
    out: dict[str, Any] = {}
    seen: set[int] = set()

    def walk(obj: Any, path: str) -> None:
        if isinstance(obj, _SCALARS):
            out[path] = ("value", obj)
            return
        if id(obj) in seen:
            return
        seen.add(id(obj))
        if isinstance(obj, np.ndarray):
            out[path] = ("array", obj.copy())
        elif isinstance(obj, np.random.Generator):
            out[path] = ("generator", obj.bit_generator.state)
        elif isinstance(obj, np.random.RandomState):
            out[path] = ("randomstate", obj.get_state())
        elif isinstance(obj, mujoco.MjData):
            out[path] = ("mjdata", obj.__copy__())
        elif isinstance(obj, mujoco.MjModel):
            out[path] = ("mjmodel", _mjmodel_state(obj))
        elif _skip(obj):
            return
        elif isinstance(obj, list | tuple | dict | deque):
            # containers: element-wise (arrays in them may be views into a simulator), plus a whole copy
            # when plain, for a rebuilt run whose container has another length (episode lists, infos)
            out[path] = ("container", _signature(obj), _copy(obj) if _plain(obj) else None)
            for name, child in _children(obj):
                walk(child, path + name)
        else:
            for name, child in _children(obj):
                walk(child, path + name)

    walk(root, "")
    return out


class _Replace(Exception):
    """A scalar inside a tuple differs: the tuple is replaced whole by its parent."""


def restore(root: Any, saved: dict[str, Any]) -> None:
    """Write ``saved`` (from :func:`capture`) back into the graph of ``root`` in place; ``ResumeMismatch`` if
    the graph differs."""
    seen: set[int] = set()
    done: set[str] = set()

    def put(parent: Any, name: str, value: Any) -> None:
        if parent is None:
            raise ResumeMismatch("cannot replace the root")
        if name.startswith("."):
            setattr(parent, name[1:], value)
        elif isinstance(parent, tuple):
            raise _Replace
        else:
            parent[_index(parent, name)] = value

    def mark(prefix: str) -> None:
        done.update(p for p in saved if p == prefix or p.startswith(prefix + "[") or p.startswith(prefix + "."))

    def walk(obj: Any, path: str, parent: Any, name: str) -> None:
        entry = saved.get(path)
        if (
            entry is not None
            and {entry[0], "array" if isinstance(obj, np.ndarray) else ""} == {"array", "value"}
            or (entry is not None and entry[0] == "array" and isinstance(obj, _SCALARS))
        ):  # a 0-d array that numpy arithmetic turned into a scalar, or back
            put(parent, name, _copy(entry[1]))
            done.add(path)
            return
        if isinstance(obj, _SCALARS):
            if entry is None or entry[0] != "value":
                raise ResumeMismatch(f"{path or 'root'}: no saved value")
            if not _same(obj, entry[1]):
                put(parent, name, entry[1])
            done.add(path)
            return
        if id(obj) in seen:
            return
        seen.add(id(obj))
        if isinstance(obj, np.ndarray):
            _expect(entry, "array", path)
            value = entry[1]
            if obj.shape == value.shape and obj.dtype == value.dtype and obj.flags.writeable:
                obj[...] = value
            else:
                put(parent, name, value.copy())
        elif isinstance(obj, np.random.Generator):
            _expect(entry, "generator", path)
            obj.bit_generator.state = entry[1]
        elif isinstance(obj, np.random.RandomState):
            _expect(entry, "randomstate", path)
            obj.set_state(entry[1])
        elif isinstance(obj, mujoco.MjData):
            _expect(entry, "mjdata", path)
            if obj.qpos.shape != entry[1].qpos.shape:
                raise ResumeMismatch(f"{path}: MjData of another model")
            mujoco.mj_copyData(obj, obj.model, entry[1])
        elif isinstance(obj, mujoco.MjModel):
            _expect(entry, "mjmodel", path)
            _set_mjmodel(obj, entry[1])
        elif _skip(obj):
            return
        elif isinstance(obj, list | tuple | dict | deque):
            _expect(entry, "container", path)
            _, signature, whole = entry
            if signature == _signature(obj):
                try:
                    for child_name, child in _children(obj):
                        walk(child, path + child_name, obj, child_name)
                except _Replace:
                    if whole is None:
                        raise ResumeMismatch(f"{path}: a tuple of objects changed") from None
                    put(parent, name, _copy(whole))
                    mark(path)
            elif whole is not None:
                put(parent, name, _copy(whole))
                mark(path)
            else:
                raise ResumeMismatch(f"{path}: container {_signature(obj)} != saved {signature}")
        else:
            live_names = set()
            for child_name, child in _children(obj):
                live_names.add(child_name)
                walk(child, path + child_name, obj, child_name)
            for child_name in attributes.get(path, ()):  # set lazily in the original (e.g. after a first step)
                if child_name not in live_names and child_name[1:] not in SKIP_ATTRS:
                    kind, value = saved[path + child_name][0], saved[path + child_name][-1]
                    if kind not in ("value", "array", "container") or value is None:
                        raise ResumeMismatch(f"{path + child_name}: missing in the rebuilt run")
                    setattr(obj, child_name[1:], _copy(value))
                    mark(path + child_name)
        done.add(path)

    attributes: dict[str, list[str]] = {}
    for p in saved:
        m = _ATTR_PATH.match(p)
        if m:
            attributes.setdefault(m.group(1), []).append(m.group(2))
    walk(root, "", None, "")
    missing = set(saved) - done
    if missing:
        raise ResumeMismatch(f"saved state not found in the rebuilt run: {', '.join(sorted(missing)[:5])}")


def _index(parent: Any, name: str) -> Any:
    if isinstance(parent, dict):
        for key in parent:
            if f"[{key!r}]" == name:
                return key
        raise ResumeMismatch(f"key {name} not in the rebuilt dict")
    return int(name[1:-1])


def _copy(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.copy()
    if isinstance(obj, list | tuple):
        return type(obj)(_copy(v) for v in obj)
    if isinstance(obj, deque):
        return deque((_copy(v) for v in obj), maxlen=obj.maxlen)
    if isinstance(obj, dict):
        return {k: _copy(v) for k, v in obj.items()}
    return obj


def _same(a: Any, b: Any) -> bool:
    try:
        return type(a) is type(b) and bool(a == b)
    except Exception:  # noqa: BLE001 - comparison of exotic scalars
        return False


def _expect(entry: tuple[str, Any] | None, kind: str, path: str) -> None:
    if entry is None or entry[0] != kind:
        raise ResumeMismatch(f"{path}: expected saved {kind}, found {entry[0] if entry else 'nothing'}")


def global_rng_state() -> dict[str, Any]:
    """The process-global generators a training step draws from: numpy's legacy one, torch's, Python's."""
    return {"numpy": np.random.get_state(), "torch": th.get_rng_state(), "python": random.getstate()}


def set_global_rng_state(state: dict[str, Any]) -> None:
    """Inverse of :func:`global_rng_state`."""
    np.random.set_state(state["numpy"])
    th.set_rng_state(state["torch"])
    random.setstate(state["python"])
