"""Batched evaluation of a deterministic policy under the chapter-3 testing conditions (thesis §3.2.2).

Many environment copies are stepped together with ONE batched policy forward per step. Each
(condition, rollout) pair is one episode; a slot whose episode ends (termination, truncation or the
step budget) takes the next pending episode, so episodes of different lengths are masked correctly.
Rollout ``i`` is reset with ``test_seeds(seed, n)[i]`` under every condition (common random numbers
across the sigma grid); testing seeds are drawn from their own stream and are all ``>= 2**32``, so
they never collide with (small integer) training seeds. All randomness of an env must come from its
``np_random``, which ``reset(seed=...)`` reseeds, so results do not depend on ``n_envs``.

>>> import numpy as np
>>> zero = lambda obs: np.zeros((len(obs), 1))
>>> R = evaluate(zero, "InvertedPendulum-v5", "none", [0.0, 0.5], 2, max_episode_steps=20,
...              make=gym_make)  # doctest: +SKIP
>>> R.shape  # doctest: +SKIP
(2, 2)
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from thesis_repro.core.validation import check_choice, check_nonneg
from thesis_repro.envs import PERTURBATIONS, make_env

#: Testing conditions of chapter 3 (``"none"``: the unperturbed training domain).
#: Tag mixed into the testing-seed stream (the bytes of "test").
_TEST_STREAM = 0x74657374

Policy = Callable[[np.ndarray], np.ndarray]
EnvMaker = Callable[..., gym.Env]


def test_seeds(seed: int, n: int) -> list[int]:
    """``n`` testing seeds for evaluation seed ``seed``, from a stream separate from training seeds.

    All are in ``[2**32, 2**33)`` so they cannot equal a training seed below ``2**32``.

    >>> s = test_seeds(0, 3)
    >>> len(set(s)), min(s) >= 2**32, s == test_seeds(0, 5)[:3]
    (3, True, True)
    """
    seed = int(check_nonneg(seed, "seed"))
    n = _check_count(n, "n_rollouts")
    state = np.random.SeedSequence([_TEST_STREAM, seed]).generate_state(n, dtype=np.uint32)
    return [int(s) + 2**32 for s in state]


test_seeds.__test__ = False  # type: ignore[attr-defined]  # not a pytest test despite its name


def _check_count(n: Any, what: str) -> int:
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ValueError(f"{what} must be a positive integer, got {n!r}")
    return int(n)


def gym_make(
    env: str,
    perturbation: str = "none",
    sigma: float = 0.0,
    *,
    max_episode_steps: int | None = None,
    seed: int | None = None,
    **kwargs: Any,
) -> gym.Env:
    """Plain ``gymnasium.make`` with the ``make_env`` signature; only ``perturbation="none"`` (for tests/bench)."""
    if perturbation != "none" or sigma != 0.0:
        raise ValueError("gym_make cannot perturb; use thesis_repro.envs.make_env for obs/act/env/dom tests")
    return gym.make(env, max_episode_steps=max_episode_steps, **kwargs)


def default_make() -> EnvMaker:
    """The kit's env factory, :func:`thesis_repro.envs.make_env`."""
    return make_env


def check_shapes(
    task: str,
    task_obs: tuple[int, ...],
    task_act: tuple[int, ...],
    policy_obs: tuple[int, ...] | None,
    policy_act: tuple[int, ...] | None,
) -> None:
    """``ValueError`` naming the task and both shapes if a policy's observation/action shapes do not fit the task.

    ``None`` skips a side (unknown for a plain callable).

    >>> check_shapes("Hopper", (11,), (3,), (4,), (1,))
    Traceback (most recent call last):
    ...
    ValueError: policy does not fit task 'Hopper': it takes observations of shape (4,) and gives actions of \
shape (1,), the task has observations of shape (11,) and actions of shape (3,)
    """
    obs_ok = policy_obs is None or tuple(policy_obs) == tuple(task_obs)
    act_ok = policy_act is None or tuple(policy_act) == tuple(task_act)
    if obs_ok and act_ok:
        return
    ours = "?" if policy_obs is None else tuple(policy_obs)
    acts = "?" if policy_act is None else tuple(policy_act)
    raise ValueError(
        f"policy does not fit task {task!r}: it takes observations of shape {ours} and gives actions of "
        f"shape {acts}, the task has observations of shape {tuple(task_obs)} and actions of shape {tuple(task_act)}"
    )


@dataclass(frozen=True)
class Rollouts:
    """Undiscounted returns and episode lengths, both shaped ``(n_conditions, n_rollouts)``."""

    returns: np.ndarray
    lengths: np.ndarray


class BatchedEvaluator:
    """Run episodes of ``policy`` on many env copies at once, one batched policy call per step.

    ``make(**condition)`` builds an env for a condition (a dict of keyword arguments of ``make_env``);
    ``policy(obs[n, obs_dim]) -> actions[n, act_dim]`` must be deterministic (the mean action).
    Actions are clipped to the action space when ``clip_actions`` (like SB3's ``predict``).

    **Batch composition.** The result is deterministic for a given list of conditions and seeds, but a rollout's
    return is not a function of its (condition, seed) alone when the policy is a torch MLP: a matrix product over
    1-2 rows can round differently from one over more rows (measured with torch 2.13 on the development CPU: up
    to ~3e-8 in the actions), and the locomotion dynamics amplify such differences over 1,000 steps. So the same
    policy, condition and seed can return differently inside another sweep (e.g. Table 3.3(b)'s σ = 0 rows of
    Obs, Act, Env and Dom, which run the same nominal task, differ slightly), with another ``n_envs``, or on
    another CPU. A row-wise policy is unaffected (``tests/test_evaluation.py``).

    >>> import numpy as np
    >>> ev = BatchedEvaluator(lambda o: np.zeros((len(o), 3)), lambda **c: gym_make(**c), n_envs=4,
    ...                       max_episode_steps=10)
    >>> ev.run([{"env": "Hopper-v5"}], test_seeds(0, 2)).lengths.tolist()
    [[10, 10]]
    """

    def __init__(
        self,
        policy: Policy,
        make: EnvMaker,
        *,
        n_envs: int = 16,
        max_episode_steps: int = 1000,
        clip_actions: bool = True,
    ):
        if not callable(policy) or not callable(make):
            raise TypeError("policy and make must be callables")
        self.policy = policy
        self.make = make
        self.n_envs = _check_count(n_envs, "n_envs")
        self.max_episode_steps = _check_count(max_episode_steps, "max_episode_steps")
        self.clip_actions = bool(clip_actions)

    def _first_call(self, obs: np.ndarray, env: gym.Env, task: str) -> np.ndarray:
        """Call the policy once and check its action shape; a failure on the task's observations names both."""
        act_shape = tuple(env.action_space.shape or ())
        obs_shape = tuple(env.observation_space.shape or ())
        try:
            actions = np.asarray(self.policy(obs))
        except (RuntimeError, ValueError, IndexError) as err:  # e.g. torch's "shape '[-1, 4]' is invalid"
            raise ValueError(
                f"policy failed on task {task!r}'s observations (batch of shape {obs.shape[1:]}; the policy may "
                f"expect another task's observations): {type(err).__name__}: {(str(err).splitlines() or [''])[0]}"
            ) from err
        if act_shape and actions.ndim >= 1 and tuple(actions.shape[1:]) != act_shape:
            check_shapes(task, obs_shape, act_shape, None, tuple(actions.shape[1:]))
        return actions

    def run(self, conditions: Sequence[Mapping[str, Any]], seeds: Sequence[int]) -> Rollouts:
        """One episode per (condition, seed); returns ``Rollouts`` shaped ``(len(conditions), len(seeds))``."""
        if len(conditions) == 0 or len(seeds) == 0:
            raise ValueError("need at least one condition and one seed")
        n_c, n_r = len(conditions), len(seeds)
        returns = np.zeros((n_c, n_r))
        lengths = np.zeros((n_c, n_r), dtype=np.int64)
        queue = [(c, r) for c in range(n_c) for r in range(n_r)]
        pools: dict[int, list[gym.Env]] = {}
        n = min(self.n_envs, len(queue))
        envs: list[gym.Env | None] = [None] * n
        task: list[tuple[int, int] | None] = [None] * n
        obs_rows: list[np.ndarray | None] = [None] * n
        ret = np.zeros(n)
        steps = np.zeros(n, dtype=np.int64)
        nxt = 0
        low = high = None

        def start(k: int) -> bool:
            nonlocal nxt, low, high
            if task[k] is not None and envs[k] is not None:
                pools.setdefault(task[k][0], []).append(envs[k])  # return the env to its condition's pool
            if nxt >= len(queue):
                task[k], envs[k] = None, None
                return False
            c, r = queue[nxt]
            nxt += 1
            pool = pools.get(c)
            env = pool.pop() if pool else self.make(**conditions[c])
            if low is None and isinstance(env.action_space, gym.spaces.Box):
                low, high = env.action_space.low, env.action_space.high
            obs, _ = env.reset(seed=int(seeds[r]))
            envs[k], task[k], obs_rows[k] = env, (c, r), np.asarray(obs, dtype=np.float64)
            ret[k], steps[k] = 0.0, 0
            return True

        task_name = str(conditions[0].get("env", "?"))
        checked = False
        try:
            active = [k for k in range(n) if start(k)]
            while active:
                obs = np.stack([obs_rows[k] for k in active])
                if checked:
                    actions = np.asarray(self.policy(obs))
                else:
                    actions = self._first_call(obs, envs[active[0]], task_name)
                    checked = True
                if actions.shape[0] != len(active):
                    raise ValueError(f"policy returned {actions.shape[0]} actions for {len(active)} observations")
                if self.clip_actions and low is not None:
                    actions = np.clip(actions, low, high)
                still = []
                for i, k in enumerate(active):
                    o, rew, term, trunc, _ = envs[k].step(actions[i])
                    ret[k] += float(rew)
                    steps[k] += 1
                    if term or trunc or steps[k] >= self.max_episode_steps:
                        c, r = task[k]
                        returns[c, r], lengths[c, r] = ret[k], steps[k]
                        if start(k):
                            still.append(k)
                    else:
                        obs_rows[k] = np.asarray(o, dtype=np.float64)
                        still.append(k)
                active = still
        finally:
            for env in [e for e in envs if e is not None] + [e for p in pools.values() for e in p]:
                env.close()
        return Rollouts(returns, lengths)


def _conditions(
    env: str, perturbation: str, sigmas: Sequence[float], max_episode_steps: int, extra: Mapping[str, Any] | None
) -> list[dict[str, Any]]:
    check_choice(perturbation, PERTURBATIONS, "perturbation")
    if len(sigmas) == 0:
        raise ValueError("sigmas must not be empty")
    sig = [check_nonneg(s, "sigma") for s in sigmas]
    return [
        {"env": env, "perturbation": perturbation, "sigma": s, "max_episode_steps": max_episode_steps, **(extra or {})}
        for s in sig
    ]


def _run(
    policy: Policy,
    conds: list[dict[str, Any]],
    n_rollouts: int,
    seed: int,
    max_episode_steps: int,
    n_envs: int,
    make: EnvMaker | None,
    return_lengths: bool,
) -> Any:
    """Run every condition for the testing seeds of ``seed``; returns or the full :class:`Rollouts`."""
    ev = BatchedEvaluator(policy, make or default_make(), n_envs=n_envs, max_episode_steps=max_episode_steps)
    out = ev.run(conds, test_seeds(seed, n_rollouts))
    return out if return_lengths else out.returns


def evaluate(
    policy: Policy,
    env: str,
    perturbation: str,
    sigmas: Sequence[float],
    n_rollouts: int,
    *,
    seed: int = 0,
    max_episode_steps: int = 1000,
    n_envs: int = 16,
    make: EnvMaker | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    return_lengths: bool = False,
) -> Any:
    """Testing returns of ``policy`` on ``env`` for each noise scale: array ``(len(sigmas), n_rollouts)``.

    ``perturbation`` is one of :data:`PERTURBATIONS`; for ``"dom"`` σ is the Σ scale of the domain
    distribution. ``make`` defaults to ``thesis_repro.envs.make_env``; ``env_kwargs`` are extra keyword
    arguments for it (e.g. ``factors``). With ``return_lengths`` a :class:`Rollouts` is returned instead.

    >>> R = evaluate(policy, "Hopper", "obs", [0.0, 0.1, 0.2], 20)  # doctest: +SKIP
    >>> auc(R.mean(axis=1), [0.0, 0.1, 0.2])  # doctest: +SKIP
    """
    n_rollouts = _check_count(n_rollouts, "n_rollouts")
    conds = _conditions(env, perturbation, sigmas, max_episode_steps, env_kwargs)
    return _run(policy, conds, n_rollouts, seed, max_episode_steps, n_envs, make, return_lengths)


def evaluate_shift(
    policy: Policy,
    env: str,
    ratios: Sequence[Any],
    n_rollouts: int,
    *,
    seed: int = 0,
    max_episode_steps: int = 1000,
    n_envs: int = 16,
    make: EnvMaker | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    return_lengths: bool = False,
) -> Any:
    """Testing returns under systematic shifts (heatmaps, Fig. 3.4e-h): array ``(len(ratios), n_rollouts)``.

    Each element of ``ratios`` is passed unchanged as ``make_env(env, "none", 0.0, ratios=...)`` (e.g. the
    per-factor ratios of one heatmap cell); reshape the first axis to the heatmap grid afterwards.
    """
    n_rollouts = _check_count(n_rollouts, "n_rollouts")
    if len(ratios) == 0:
        raise ValueError("ratios must not be empty")
    base = _conditions(env, "none", [0.0], max_episode_steps, env_kwargs)[0]
    conds = [{**base, "ratios": r} for r in ratios]
    return _run(policy, conds, n_rollouts, seed, max_episode_steps, n_envs, make, return_lengths)
