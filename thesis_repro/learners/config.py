"""Hyperparameters as data (``config/hyperparams.yaml``) and the resolved training config of one run.

Every learner of the kit, chapter 3's and the multi-domain ones of chapters 3-4, resolves through the one
:func:`train_config` into one schema: identity (``algorithm``, ``class``, ``env``, ``seed``, ``timesteps``),
the env settings (``perturbation``, ``sigma``, ``c_a``, ``wind``, ``max_episode_steps``), the entry's
settings (``n_envs``, ``net_arch``, ...), the run settings (``checkpoint_every``, ``snapshot_every``,
``curve_every``, all in env steps) and ``sb3``, the keyword arguments of the algorithm class.

>>> cfg = train_config("ppo-16", "InvertedPendulum", seed=0, timesteps=4096, n_steps=64)
>>> cfg["net_arch"], cfg["sb3"]["n_steps"], cfg["perturbation"], cfg["c_a"]
({'pi': [16, 16], 'vf': [16, 16]}, 64, 'none', None)
>>> cfg = train_config("kl-avg", "Walker2d", 0, 8192, c_a=1.0, wind=[-2.5, 2.5])
>>> cfg["class"], cfg["n_envs"], iteration_steps(cfg), cfg["sb3"]["aggregate"]
('SubPolicyAggregation', 4, 4096, 'kl_avg')
>>> train_config("ppo", "Hopper", 0, 1000, n_step=64)
Traceback (most recent call last):
...
ValueError: unknown hyperparameter of 'ppo' 'n_step'; valid hyperparameters of 'ppo' are: ...
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from functools import cache
from typing import Any

from thesis_repro.core import paths, yamlfile
from thesis_repro.core.validation import check_choice, check_nonneg
from thesis_repro.envs.make import PERTURBATIONS
from thesis_repro.envs.registry import short_name

#: Algorithm classes (the ``class`` of an entry): SB3's, and the multi-domain PPOs of ``learners.multidomain``.
ON_POLICY: tuple[str, ...] = ("PPO", "TRPO", "EPOpt", "MAMLDG", "ReptileDG", "SubPolicyAggregation")
CLASSES: tuple[str, ...] = (*ON_POLICY, "DDPG", "SAC")
#: Classes that train one sub-policy / one batch per domain (one env per domain: ``n_envs`` = N domains).
MULTI_DOMAIN_CLASSES: tuple[str, ...] = ("EPOpt", "MAMLDG", "ReptileDG", "SubPolicyAggregation")
#: Aggregation steps of :class:`~thesis_repro.learners.multidomain.SubPolicyAggregation` (``mdl.aggregate``).
AGGREGATES: tuple[str, ...] = ("params_avg", "kl_avg", "kl_exact", "kl_diag")
#: Outer updates of :class:`~thesis_repro.learners.meta.MAMLDG`: one Adam step per iteration (Alg 1 read
#: literally) or PPO's epochs x minibatches on the post-adaptation data (the kit's default).
META_UPDATES: tuple[str, ...] = ("step", "ppo")
POLICIES: tuple[str, ...] = ("mlp", "scn")
ACTIVATIONS: tuple[str, ...] = ("tanh", "relu")

#: Run settings every config carries (besides the entry's hyperparameters); all may be overridden.
RUN_DEFAULTS: dict[str, Any] = {
    "c_a": None,  # action penalty of Eq 4.12 (ctrl_cost_weight); None: the task's own (v5 Hopper/Walker2d 1e-3)
    "wind": None,  # [low, high]: wind xi ~ U(low, high) m/s² once per episode (chapter 4); None: no wind
    "max_episode_steps": None,  # None: the environment's own limit (1000 for the MuJoCo tasks)
    "checkpoint_every": 100_000,  # env steps between resumable checkpoints in the job's workdir
    "snapshot_every": 0,  # env steps between policy snapshots in out/snapshots (0: none)
    "curve_every": 0,  # env steps between training-curve points (0: one per on-policy iteration, 1000 off-policy)
}
#: Run settings a config carries only when set to another value than this default (so adding one keeps every
#: existing key): ``snapshot_at``, env steps after which the run saves one policy snapshot each, at the first
#: iteration boundary (off-policy: rollout start) at or after each step; ``stop_at``: train only the first
#: ``stop_at`` env steps of the ``timesteps``-step run (its schedules still run over ``timesteps``; SB3 finishes the
#: iteration that crosses it). ``None``: none.
OPTIONAL_RUN: dict[str, Any] = {"snapshot_at": None, "stop_at": None}
#: Keys that identify the run; not overridable.
IDENTITY = ("algorithm", "class", "env", "seed", "timesteps")
#: Learning-rate schedules of the PPO-family learners (``lr_schedule``): OpenAI baselines ppo1's ``linear``
#: (learning rate AND clip range x max(1 - t/T, 0), t = env steps before the iteration, T = the run's budget),
#: or ``constant``.
LR_SCHEDULES: tuple[str, ...] = ("linear", "constant")
#: Training protocols: ``thesis``, every learner as the thesis ran it (baselines-style annealed PPO,
#: EPOpt ranking whole episodes, one domain per batch for MAML-DG / Reptile-DG, ARPL's δ as §3.2.1 writes it).
PROTOCOLS: tuple[str, ...] = ("thesis",)
#: Settings the thesis protocol sets (dotted paths into the resolved config); a config without them is of no protocol.
THESIS_PROTOCOL_KEYS: tuple[str, ...] = (
    "lr_schedule",
    "sb3.epopt_rank",  # EPOpt ranks whole episodes by their full return
    "sb3.epopt_warm_start",  # EPOpt's ε = 1 warm start in iterations (Rajeswaran et al.), replaces epopt_warmup
    "sb3.domain_per_batch",  # MAML-DG / Reptile-DG: one Θ_i for all of domain i's batches (item 3)
    "arpl.delta",  # ARPL's δ as §3.2.1 writes it (item 4)
)
#: What :class:`~thesis_repro.learners.multidomain.EPOpt` ranks (``sb3.epopt_rank``): complete episodes by their
#: full return, or the fragments of the rollout buffer cut at its ends, by partial return (also when the key is absent).
EPOPT_RANKS: tuple[str, ...] = ("episodes", "fragments")
#: ARPL's perturbation (``arpl.delta``): §3.2.1's ε ∇_s‖π(s)‖, or (also when absent) the gradient rescaled to length ε.
ARPL_DELTAS: tuple[str, ...] = ("gradient", "rescaled")


@cache
def _raw() -> dict[str, Any]:
    with open(paths.CONFIG / "hyperparams.yaml") as fh:
        table = yamlfile.parse(fh)
    if not isinstance(table, dict) or not table:
        raise ValueError("hyperparams.yaml must map algorithm names to entries")
    return table


def _resolve(name: str, seen: tuple[str, ...] = ()) -> dict[str, Any]:
    table = _raw()
    check_choice(name, list(table), "algorithm")
    if name in seen:
        raise ValueError(f"hyperparams.yaml: inheritance cycle {' -> '.join((*seen, name))}")
    entry = copy.deepcopy(table[name])
    base = entry.pop("base", None)
    if base is None:
        return entry
    merged = _resolve(base, (*seen, name))
    sb3 = merged.get("sb3", {})
    sb3.update(entry.pop("sb3", {}) or {})
    merged.update(entry)
    merged["sb3"] = sb3
    return merged


def algorithms() -> tuple[str, ...]:
    """Names of every entry of ``hyperparams.yaml`` (read at call time)."""
    return tuple(_raw())


#: Every learner id, in the order of ``hyperparams.yaml``.
ALGORITHMS: tuple[str, ...] = algorithms()
#: Learners that train on several domains with one env per domain (joint is plain PPO on the merged batch).
MULTI_DOMAIN: tuple[str, ...] = tuple(
    n for n in ALGORITHMS if n == "joint" or _resolve(n).get("class") in MULTI_DOMAIN_CLASSES
)


def hyperparams(algo: str) -> dict[str, Any]:
    """The resolved (inheritance applied) entry of ``algo``; ``ValueError`` listing valid names if unknown."""
    return _resolve(algo)


def train_config(
    algo: str, env: str, seed: int, timesteps: int, *, protocol: str = "thesis", **overrides: Any
) -> dict[str, Any]:
    """Full resolved, JSON-plain config of one training run (the input of the ``"train"`` job).

    ``protocol`` is one of :data:`PROTOCOLS` (``"thesis"``, the only one); figures pass their scale's setting.

    ``overrides`` may name any top-level setting (``n_envs``, ``perturbation``, ``sigma``, ``c_a``, ``wind``,
    ``net_arch``, ``snapshot_every``, ``max_episode_steps``, ...), any key of the entry's ``sb3`` block
    (``n_steps``, ``ent_coef``, ``epsilon``, ``damping``, ...) or of its ``optional_sb3`` block, whose keys
    enter ``sb3`` only when set to another value than their default (so adding one keeps every existing key),
    and :data:`OPTIONAL_RUN`'s ``stop_at``, likewise absent unless set.
    A name that exists nowhere is an error, so typos never pass silently.

    >>> a = train_config("ppo-reptile-dg", "Hopper", 0, 1000)
    >>> a == train_config("ppo-reptile-dg", "Hopper", 0, 1000, meta_step_size=None), "meta_step_size" in a["sb3"]
    (True, False)
    >>> train_config("ppo-reptile-dg", "Hopper", 0, 1000, meta_step_size=1.0)["sb3"]["meta_step_size"]
    1.0
    """
    check_choice(algo, ALGORITHMS, "algorithm")
    short_name(env)  # a typo ("Hoppr") is a one-line error naming the valid envs, not a failure at training
    entry = hyperparams(algo)
    if isinstance(seed, bool) or int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if isinstance(timesteps, bool) or int(timesteps) != timesteps or timesteps <= 0:
        raise ValueError(f"timesteps must be an integer > 0, got {timesteps!r}")
    cfg: dict[str, Any] = {"algorithm": algo, "env": str(env), "seed": int(seed), "timesteps": int(timesteps)}
    cfg.update(copy.deepcopy(RUN_DEFAULTS))
    cfg.update(entry)
    cfg.setdefault("sb3", {})
    optional = cfg.pop("optional_sb3", None) or {}
    check_choice(protocol, PROTOCOLS, "protocol")
    top = [k for k in cfg if k not in IDENTITY and k != "sb3"]
    for key, value in overrides.items():
        if key in top:
            if isinstance(cfg[key], dict) and key != "net_arch":
                if not isinstance(value, dict) or set(value) != set(cfg[key]):
                    raise ValueError(f"override {key!r} must be a dict with keys {sorted(cfg[key])}, got {value!r}")
            cfg[key] = value
        elif key in cfg["sb3"]:
            cfg["sb3"][key] = value
        elif key in optional:
            if value != optional[key]:  # the default stays absent, so configs without it keep their keys
                cfg["sb3"][key] = value
        elif key in OPTIONAL_RUN:
            if value != OPTIONAL_RUN[key]:  # as optional_sb3: absent at its default
                cfg[key] = value
        else:
            valid = sorted(top) + sorted(OPTIONAL_RUN) + sorted(cfg["sb3"]) + sorted(optional)
            check_choice(key, valid, f"hyperparameter of {algo!r}")
    if cfg["wind"] is not None:
        cfg["wind"] = [float(w) for w in cfg["wind"]] if isinstance(cfg["wind"], list | tuple) else cfg["wind"]
    _validate(cfg)
    return cfg


def iteration_steps(cfg: Mapping[str, Any]) -> int:
    """Env steps of one on-policy iteration of a training config: ``n_envs × n_steps`` (MAMLDG: twice that,
    it collects D_i and then D'_i in every domain). Off-policy classes have no iterations: ``ValueError``.

    >>> [iteration_steps(train_config(a, "Hopper", 0, 1)) for a in ("ppo", "joint", "ppo-maml-dg")]
    [2048, 4096, 8192]
    """
    check_choice(cfg["class"], ON_POLICY, "on-policy learner class")
    return int(cfg["n_envs"]) * int(cfg["sb3"]["n_steps"]) * (2 if cfg["class"] == "MAMLDG" else 1)


def n_iterations(cfg: Mapping[str, Any]) -> int:
    """On-policy iterations a training config runs: SB3's ``learn()`` finishes the iteration that crosses
    ``timesteps``, so ``ceil(timesteps / iteration_steps)``.

    >>> cfg = train_config("joint", "Walker2d", 0, 2_000_000)
    >>> iteration_steps(cfg), n_iterations(cfg)
    (4096, 489)
    """
    return -(-int(cfg["timesteps"]) // iteration_steps(cfg))


def rollout_steps(cfg: Mapping[str, Any]) -> int:
    """Env steps between two rollout starts of a training config (where its callbacks snapshot): one iteration
    on-policy (:func:`iteration_steps`), ``train_freq`` x ``n_envs`` off-policy (``train_freq`` in steps).

    >>> [rollout_steps(train_config(a, "Hopper", 0, 1)) for a in ("ppo", "trpo", "sac", "ddpg")]
    [2048, 1024, 50, 100]
    """
    if cfg["class"] in ON_POLICY:
        return iteration_steps(cfg)
    freq = cfg["sb3"].get("train_freq", 1)
    if isinstance(freq, bool) or not isinstance(freq, int):
        raise ValueError(f"snapshots of {cfg['class']} need train_freq in env steps (an integer), got {freq!r}")
    return int(freq) * int(cfg["n_envs"])


def snapshot_at_steps(cfg: Mapping[str, Any]) -> list[int]:
    """The env steps at which a run with ``snapshot_at`` saves its snapshots: the first rollout start at or after
    each listed step (:func:`rollout_steps`), those before the run's last rollout start (the final policy is the
    run's own).

    >>> cfg = train_config("ppo", "Hopper", 0, 4_000_000, snapshot_at=[1_000_000, 2_000_000, 3_000_000])
    >>> snapshot_at_steps(cfg)
    [1001472, 2000896, 3000320]
    >>> snapshot_at_steps(train_config("sac", "Hopper", 0, 4_000_000, snapshot_at=[1_000_000, 4_000_000]))
    [1000000]
    """
    every = rollout_steps(cfg)
    done = -(-int(cfg["timesteps"]) // every) * every  # learn() ends after the rollout crossing the budget
    out: list[int] = []
    for t in cfg.get("snapshot_at") or ():
        step = -(-int(t) // every) * every
        if step < done and (not out or step > out[-1]):
            out.append(step)
    return out


def _validate(cfg: dict[str, Any]) -> None:
    check_choice(cfg["class"], CLASSES, "learner class")
    check_choice(cfg["perturbation"], PERTURBATIONS, "perturbation")
    cfg["sigma"] = check_nonneg(cfg["sigma"], "sigma")
    check_choice(cfg.get("policy", "mlp"), POLICIES, "policy")
    check_choice(cfg.get("activation", "tanh"), ACTIVATIONS, "activation")
    if cfg["policy"] == "scn" and cfg["class"] not in ON_POLICY:
        raise ValueError("policy 'scn' is implemented for the on-policy classes only")
    if cfg.get("arpl") is not None and cfg["class"] != "PPO":
        raise ValueError("arpl is implemented for PPO only")
    for key in ("n_envs",):
        if int(cfg[key]) != cfg[key] or cfg[key] < 1:
            raise ValueError(f"{key} must be an integer >= 1, got {cfg[key]!r}")
    for key in ("checkpoint_every", "snapshot_every", "curve_every"):
        if int(cfg[key]) != cfg[key] or cfg[key] < 0:
            raise ValueError(f"{key} must be an integer >= 0, got {cfg[key]!r}")
    if "snapshot_at" in cfg:
        at = cfg["snapshot_at"]
        if not isinstance(at, list) or not at or any(isinstance(t, bool) or not isinstance(t, int) for t in at):
            raise ValueError(f"snapshot_at must be a non-empty list of env steps (integers), got {at!r}")
        if any(t <= 0 for t in at) or at != sorted(set(at)):
            raise ValueError(f"snapshot_at must hold increasing env steps > 0, got {at!r}")
        if cfg["snapshot_every"]:
            raise ValueError("set snapshot_every or snapshot_at, not both")
        cfg["snapshot_at"] = [int(t) for t in at]
    if "stop_at" in cfg:
        stop = cfg["stop_at"]
        if isinstance(stop, bool) or not isinstance(stop, int) or not 0 < stop < cfg["timesteps"]:
            raise ValueError(f"stop_at must be an integer in (0, timesteps = {cfg['timesteps']}), got {stop!r}")
    if cfg["max_episode_steps"] is not None and (int(cfg["max_episode_steps"]) < 1):
        raise ValueError(f"max_episode_steps must be None or >= 1, got {cfg['max_episode_steps']!r}")
    if cfg["c_a"] is not None:
        check_nonneg(cfg["c_a"], "c_a")
    wind = cfg["wind"]
    if wind is not None and (not isinstance(wind, list) or len(wind) != 2 or wind[0] > wind[1]):
        raise ValueError(f"wind must be None or [low, high] with low <= high, got {wind!r}")
    if cfg.get("arpl") is not None:
        check_nonneg(cfg["arpl"]["epsilon"], "arpl.epsilon")
        p = check_nonneg(cfg["arpl"]["prob"], "arpl.prob")
        if p > 1:
            raise ValueError(f"arpl.prob must be in [0, 1], got {p}")
    sb3 = cfg["sb3"]
    if "epsilon" in sb3 and not 0.0 < sb3["epsilon"] <= 1.0:
        raise ValueError(f"epsilon must be in (0, 1], got {sb3['epsilon']!r}")
    if "aggregate" in sb3:
        check_choice(sb3["aggregate"], AGGREGATES, "aggregate")
    if "lr_schedule" in cfg:
        check_choice(cfg["lr_schedule"], LR_SCHEDULES, "lr_schedule")
        if cfg["class"] not in ON_POLICY or cfg["class"] == "TRPO":
            raise ValueError(f"lr_schedule is implemented for the PPO-family learners only, not {cfg['class']}")
    if "meta_step_size" in sb3:
        eps = sb3["meta_step_size"]
        if isinstance(eps, bool) or not isinstance(eps, int | float) or not eps > 0:
            raise ValueError(f"meta_step_size must be a number > 0 (or None: Alg 2's Adam step), got {eps!r}")
    if "meta_update" in sb3:
        check_choice(sb3["meta_update"], META_UPDATES, "meta_update")
    if cfg.get("arpl") is not None and "delta" in cfg["arpl"]:
        check_choice(cfg["arpl"]["delta"], ARPL_DELTAS, "arpl.delta")
    if "epopt_rank" in sb3:
        check_choice(sb3["epopt_rank"], EPOPT_RANKS, "epopt_rank")
    if "epopt_warm_start" in sb3:
        w = sb3["epopt_warm_start"]
        if isinstance(w, bool) or not isinstance(w, int) or w < 0:
            raise ValueError(f"epopt_warm_start must be an integer >= 0 (iterations), got {w!r}")
        if sb3.get("epopt_warmup", 0) != 0:
            raise ValueError("set epopt_warm_start (the thesis protocol's warm-up), not epopt_warmup (in batches)")
    if "domain_per_batch" in sb3:
        if not isinstance(sb3["domain_per_batch"], bool):
            raise ValueError(f"domain_per_batch must be true or false, got {sb3['domain_per_batch']!r}")
        if cfg["class"] not in ("MAMLDG", "ReptileDG"):
            raise ValueError(f"domain_per_batch is implemented for MAMLDG and ReptileDG only, not {cfg['class']}")
    for key in ("line_search", "trust_region"):
        if key in sb3 and not isinstance(sb3[key], bool):
            raise ValueError(f"{key} must be true or false, got {sb3[key]!r}")
    if sb3.get("trust_region") and (sb3.get("line_search") or sb3.get("aggregate") != "kl_avg"):
        raise ValueError("trust_region is a step rule of aggregate 'kl_avg' without line_search")
    if sb3.get("kl_bound") is not None and not sb3.get("trust_region"):
        raise ValueError("kl_bound is the bound of trust_region; set trust_region too")
    for key in ("damping", "cg_rtol", "inner_lr", "kl_bound"):
        if key in sb3:
            check_nonneg(sb3[key], key)
