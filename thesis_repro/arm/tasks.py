"""The 2-D arm dynamic tasks of §5.3.1, simulated for a whole population at once.

Model. The end-effector is a point in the vertical plane (x right, y up, metres; it starts at rest at
the origin). An ideal inverse kinematics is assumed, so the policy's two outputs are directly the
end-effector's horizontal and vertical accelerations (clipped per component to ``accel_limit``). The arm
has a workspace box (``workspace``, like joint limits) that it cannot leave: its speed towards a wall at
distance d is capped at ``sqrt(2 accel_limit d)``, i.e. it brakes within the actuator limit (no infinite
deceleration at a wall to exploit); positions are also clipped as a safeguard. Four families:

* ``reach`` (goal_x, goal_y): cost ``Σ_{t=0}^{T} γ^t (|x_t - g|² + w_v |v_t|² - b_reach) + Σ_t α|a_t|``
  (x_t, v_t: end-effector position and velocity at control step t); success if the final distance is
  below ``reach_tolerance``. Reading of §5.3.1: the thesis writes the reach cost as
  ``Σ_t [γ^t ((x - x_target)² - b) + α|a_t|]``, "quadratic functions with respect to the distance to
  target STATE", and says Reach penalises "large velocities and accelerations". The agent's state is
  position and velocity, so we read x = (position, velocity) and x_target = (goal, 0); the accelerations
  are penalised by the α|a_t| term (the actions ARE accelerations). The thesis gives no weight between
  metres and m/s. Minimising Σ (d² + w_v ḋ²) gives d̈ = d / w_v, i.e. the cost-optimal approach is
  d(t) = d_0 e^{-t/τ} with τ = √w_v seconds. The units-blind w_v = 1 (τ = 1 s) leaves e^{-2} ≈ 14 % of
  the start distance after the 2 s episode — more than ``reach_tolerance`` for goals beyond 0.37 m, so
  the cost would punish the reaches the task calls successful. We use w_v = ``reach_velocity_weight``
  = 0.04 (τ = 0.2 s, a tenth of the episode): large velocities are penalised and the cost-optimal reach
  still settles well inside the episode. ``reach_velocity_weight=0`` is the kit's earlier,
  position-only cost (SIM_VERSION 2).
* ``throw`` (basket_x, basket_y): the ball is held until ``release_time`` then flies ballistically.
* ``bic`` (string_length, ball_mass): the cup is on the end-effector; the ball hangs on a string of length
  L at rest below it and must be caught in the cup.
* ``cast`` (string_length, ball_mass): the string is tied to the end-effector, the cup is fixed at
  ``cast_cup``.

Ball physics (throw after release, bic, cast). Gravity plus quadratic air drag of acceleration
``-(drag_coef / m) |u| u``: this is where the **ball mass** acts — a lighter ball is slowed more by the
air (with an ideal-IK kinematic arm and a massless string, mass would otherwise not change the motion at
all). The thrown ball (no mass parameter) has no drag. The string is massless and inextensible: when the
ball would be farther than L from the end-effector it is *taut* — the position is projected back onto
the circle of radius L and the outward radial component of the relative velocity is removed (a
perfectly inelastic jerk; inward motion is kept, so the string goes slack again by itself); otherwise
it is *slack* and the ball is ballistic.

Integrator. Control step ``dt`` = 0.02 s (50 Hz) with zero-order hold of the action over
``n_substeps`` = 2 physics substeps of h = 0.01 s; default horizon T = 100 control steps (2 s). Each
substep: arm semi-implicit Euler (``v += a h; x += v h``), workspace clip; ball
``q += u h + ½ g_eff h²; u += g_eff h`` (exact for the drag-free ballistic flight) when the string is
slack — if this overshoots the length L, the string projection above; when taut (at length L, not moving
inward, non-negative tension), the pendulum angle in the end-effector's frame is integrated by velocity
Verlet instead (second order: a 85° pendulum keeps its energy within 0.1 % of m g L over 3 s). One
Python loop over time steps; everything else is numpy over the batch B (B = population × tasks).

Catch / hit (Eq 5.12). The first time the ball comes down through the height of the cup/basket (the
ball–cup height difference goes from > 0 to <= 0) fixes ``m`` (control step at which it happened) and the
horizontal offset ``x_b - x_c`` (linearly interpolated inside the substep). Cost
``γ^m min(b1 (x_b - x_c)² - b, 0) + Σ_t α|a_t|`` with ``b = cost_b`` and ``b1 = b / cost_r0²`` (the bonus
vanishes beyond ``cost_r0`` metres), or only the action term if the heights never match. Success:
``|x_b - x_c| <`` the cup radius (``cup_radius``; ``basket_radius`` for throw). A caught ball then stays
in the cup (in cast the string is then considered released: the ball rests in the fixed cup). The
cup/basket is solid from below: a ball rising into its bottom (within the radius) is put back just
below it with its relative vertical velocity reversed × ``cup_restitution``, so the ball cannot be
caught by jerking the cup straight up through it; other collisions (cup walls, string) are not modelled.

``shaped=True`` adds a dense term ``shaping_weight × min_t |ball_t - target_t|`` (target: the cup, the
basket; for reach nothing) to ``Rollout.cost`` to help autonomous learning; ``Rollout.task_cost`` is
always the thesis's cost.

>>> rng = np.random.default_rng(0)
>>> tasks = sample_tasks("bic", 3, rng)
>>> W = np.zeros((3, 12, 2))
>>> r = simulate("bic", tasks, W)
>>> r.cost.shape, bool(r.success.any()), float(r.cost.max())
((3,), False, 0.0)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np

from thesis_repro.arm.policy import A, RBFPolicy
from thesis_repro.core.validation import check_choice, check_nonneg, check_positive

#: Bump whenever the simulated physics or costs change; put it in every cached job's config that simulates.
SIM_VERSION: int = 3  # 3: reach cost penalises velocity (|v_t|² in the target-state distance)
FAMILIES: tuple[str, ...] = ("reach", "throw", "bic", "cast")
TASK_PARAM_NAMES: dict[str, tuple[str, ...]] = {
    "reach": ("goal_x", "goal_y"),
    "throw": ("basket_x", "basket_y"),
    "bic": ("string_length", "ball_mass"),
    "cast": ("string_length", "ball_mass"),
}
#: Uniform sampling ranges of every task parameter (metres, kilograms).
TASK_RANGES: dict[str, tuple[tuple[float, float], ...]] = {
    "reach": ((-0.35, 0.35), (-0.1, 0.4)),
    "throw": ((0.8, 1.6), (-0.4, 0.0)),
    "bic": ((0.2, 0.4), (0.01, 0.1)),
    "cast": ((0.3, 0.45), (0.01, 0.1)),
}


@dataclass
class ArmConfig:
    """Simulator and cost settings (module docstring explains each); validated on construction."""

    dt: float = 0.02
    horizon: int = 100
    n_substeps: int = 2
    gravity: float = 9.81
    gamma: float = 0.99
    alpha: float = 0.001
    accel_limit: float = 60.0
    workspace: tuple[tuple[float, float], tuple[float, float]] = ((-0.45, 0.45), (-0.15, 0.45))
    release_time: float = 0.6
    drag_coef: float = 1e-3
    cup_radius: float = 0.05
    cup_restitution: float = 0.5
    basket_radius: float = 0.08
    cast_cup: tuple[float, float] = (0.65, 0.0)
    reach_baseline: float = 0.01
    reach_tolerance: float = 0.05
    reach_velocity_weight: float = 0.04  # (0.2 s)²: see the reach bullet of the module docstring
    cost_b: float = 10.0
    cost_r0: float = 0.3
    shaped: bool = False
    shaping_weight: float = 10.0

    def __post_init__(self) -> None:
        for name in ("dt", "gravity", "accel_limit", "cup_radius", "basket_radius", "reach_tolerance", "cost_r0"):
            setattr(self, name, check_positive(getattr(self, name), name))
        nonneg = (
            "alpha",
            "cup_restitution",
            "release_time",
            "drag_coef",
            "reach_baseline",
            "reach_velocity_weight",
            "cost_b",
            "shaping_weight",
        )
        for name in nonneg:
            setattr(self, name, check_nonneg(getattr(self, name), name))
        for name in ("horizon", "n_substeps"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
            setattr(self, name, int(v))
        if not 0.0 < self.gamma <= 1.0:
            raise ValueError(f"gamma must be in (0, 1], got {self.gamma!r}")
        ws = np.asarray(self.workspace, dtype=float)
        if ws.shape != (2, 2) or not np.all(ws[:, 0] < 0) or not np.all(ws[:, 1] > 0):
            raise ValueError(f"workspace must be ((xmin<0, xmax>0), (ymin<0, ymax>0)), got {self.workspace!r}")
        self.workspace = tuple(map(tuple, ws.tolist()))
        self.cast_cup = tuple(float(c) for c in self.cast_cup)
        if len(self.cast_cup) != 2:
            raise ValueError(f"cast_cup must be an (x, y) pair, got {self.cast_cup!r}")

    @property
    def h(self) -> float:
        """Physics substep (seconds)."""
        return self.dt / self.n_substeps

    @property
    def cost_b1(self) -> float:
        """b1 of Eq 5.12, chosen so that the bonus vanishes at ``cost_r0`` metres."""
        return self.cost_b / self.cost_r0**2

    @property
    def release_step(self) -> int:
        """Physics substep index at which the thrown ball is released."""
        return int(round(self.release_time / self.h))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def make(cls, config: ArmConfig | dict[str, Any] | None) -> ArmConfig:
        """An ``ArmConfig`` from ``None`` (defaults), a dict of overrides, or an ``ArmConfig``."""
        if config is None:
            return cls()
        if isinstance(config, cls):
            return config
        if isinstance(config, dict):
            valid = [f.name for f in fields(cls)]
            for k in config:
                check_choice(k, valid, "ArmConfig field")
            return cls(**config)
        raise TypeError(f"config must be an ArmConfig, a dict or None, got {type(config).__name__}")


@dataclass
class Rollout:
    """Result of :func:`simulate` for B rollouts.

    ``cost`` (B,) the optimised cost (= ``task_cost`` unless ``shaped``), ``task_cost`` (B,) the thesis's
    cost, ``success`` (B,) bool, ``action_cost`` (B,) the ``Σ α|a|`` part, ``hit`` (B,) bool (heights
    matched), ``hit_step`` (B,) control step m (-1 if none), ``hit_dx`` (B,) x_b - x_c at m (nan if none),
    ``min_dist`` (B,) closest ball–target distance (nan for reach). With ``record``: ``ee`` and ``ball``
    (B, T+1, 2) positions at control steps, ``ee_vel`` (B, T+1, 2) end-effector velocities, ``taut``
    (B, T+1) string taut flags, ``actions`` (B, T, 2).
    """

    cost: np.ndarray
    task_cost: np.ndarray
    success: np.ndarray
    action_cost: np.ndarray
    hit: np.ndarray
    hit_step: np.ndarray
    hit_dx: np.ndarray
    min_dist: np.ndarray
    ee: np.ndarray | None = None
    ee_vel: np.ndarray | None = None
    ball: np.ndarray | None = None
    taut: np.ndarray | None = None
    actions: np.ndarray | None = None
    extra: dict[str, Any] = field(default_factory=dict)


def check_family(family: str) -> str:
    """Return ``family`` if valid, else raise ``ValueError`` listing the families."""
    return check_choice(family, FAMILIES, "family")


def validate_tasks(family: str, params: np.ndarray) -> np.ndarray:
    """Task parameters as a float array (n, k); raises ``ValueError`` on bad shapes or values.

    String lengths and ball masses must be > 0; every value finite.

    >>> validate_tasks("bic", [[0.3, -1.0]])
    Traceback (most recent call last):
    ...
    ValueError: bic task 0: ball_mass must be > 0 kg, got -1.0
    """
    check_family(family)
    names = TASK_PARAM_NAMES[family]
    p = np.asarray(params, dtype=float)
    if p.ndim == 1:
        p = p[None]
    if p.ndim != 2 or p.shape[1] != len(names) or p.shape[0] < 1:
        raise ValueError(
            f"{family} task parameters must have shape (n, {len(names)}) with columns {names}; got {np.shape(params)}"
        )
    bad = ~np.isfinite(p)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise ValueError(f"{family} task {i}: {names[j]} must be finite, got {p[i, j]}")
    if family in ("bic", "cast"):
        for j, unit in ((0, "m"), (1, "kg")):
            nonpos = np.flatnonzero(p[:, j] <= 0)
            if nonpos.size:
                i = nonpos[0]
                raise ValueError(f"{family} task {i}: {names[j]} must be > 0 {unit}, got {p[i, j]}")
    return p


def sample_tasks(family: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` tasks of ``family`` drawn uniformly from ``TASK_RANGES``, shape (n, 2).

    >>> sample_tasks("reach", 2, np.random.default_rng(0)).shape
    (2, 2)
    """
    check_family(family)
    if int(n) != n or n < 1:
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
    lo, hi = np.asarray(TASK_RANGES[family], dtype=float).T
    return lo + (hi - lo) * rng.random((int(n), len(lo)))


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Row-wise dot product of (B, 2) arrays (faster than a ``sum(-1)`` reduction for two columns)."""
    return x[:, 0] * y[:, 0] + x[:, 1] * y[:, 1]


def pendulum_step(
    p_old: np.ndarray,
    v_old: np.ndarray,
    p: np.ndarray,
    v: np.ndarray,
    q: np.ndarray,
    u: np.ndarray,
    length: np.ndarray,
    g_eff: np.ndarray,
    h: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One substep of a ball (q, u) on a massless inextensible string of ``length`` tied to the end-effector,
    which moves from (p_old, v_old) to (p, v) during the substep; ``g_eff`` (B, 2) is gravity + drag.

    Taut rows (at full length, not moving inward, positive tension ``m(L φ̇² + f·n) >= 0`` with ``f`` the
    forcing in the end-effector frame) integrate the pendulum angle φ with velocity Verlet
    (``φ̈ = f·t(φ)/L``, t the tangent). Slack rows fly ballistically; if that takes them beyond L the position is
    projected onto the circle and the outward relative radial velocity removed (inelastic jerk).
    Returns the new ball position, velocity and taut flags (B,).
    """
    r = q - p_old
    w = u - v_old
    dist = np.sqrt(_dot(r, r))
    n = r / np.maximum(dist, 1e-12)[:, None]
    tang = np.stack([-n[:, 1], n[:, 0]], axis=1)  # counter-clockwise tangent
    f = g_eff - (v - v_old) / h  # forcing in the (accelerating) end-effector frame
    omega = _dot(w, tang) / length
    tension = length * omega**2 + _dot(f, n)
    on_circle = (dist >= length * (1 - 1e-9)) & (_dot(w, n) >= -1e-9) & (tension >= 0)
    # taut candidate: pendulum angle, velocity Verlet (f is constant over the substep)
    omega = omega + 0.5 * h * _dot(f, tang) / length
    phi = np.arctan2(n[:, 1], n[:, 0]) + omega * h
    n_new = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    t_new = np.stack([-n_new[:, 1], n_new[:, 0]], axis=1)
    omega = omega + 0.5 * h * _dot(f, t_new) / length
    q_taut = p + length[:, None] * n_new
    u_taut = v + (length * omega)[:, None] * t_new
    # slack candidate: ballistic, then the string catches it if it overshoots
    q_free = q + u * h + 0.5 * g_eff * h * h
    u_free = u + g_eff * h
    r = q_free - p
    dist = np.sqrt(_dot(r, r))
    over = dist > length
    n = r / np.maximum(dist, 1e-12)[:, None]
    q_free = np.where(over[:, None], p + length[:, None] * n, q_free)
    w_r = _dot(u_free - v, n)
    u_free = u_free - np.where(over & (w_r > 0), w_r, 0.0)[:, None] * n
    q = np.where(on_circle[:, None], q_taut, q_free)
    u = np.where(on_circle[:, None], u_taut, u_free)
    return q, u, on_circle | over


def _bounce_below(
    q: np.ndarray,
    u: np.ndarray,
    cup: np.ndarray,
    cup_vel: np.ndarray,
    rows: np.ndarray,
    restitution: float,
    anchor: np.ndarray | None,
    length: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Put ``rows``' balls just below the cup bottom with their relative vertical velocity reversed × e."""
    qy = np.where(rows, cup[:, 1] - 1e-6, q[:, 1])
    q = np.stack([q[:, 0], qy], axis=1)
    uy = np.where(rows, cup_vel[:, 1] - restitution * (u[:, 1] - cup_vel[:, 1]), u[:, 1])
    u = np.stack([u[:, 0], uy], axis=1)
    if anchor is not None:  # keep the string inextensible after the shift
        r = q - anchor
        dist = np.sqrt(_dot(r, r))
        over = rows & (dist > length)
        q = np.where(over[:, None], anchor + (length / np.maximum(dist, 1e-12))[:, None] * r, q)
    return q, u


def _broadcast(family: str, task_params: np.ndarray, W: np.ndarray, policy: RBFPolicy) -> tuple[np.ndarray, ...]:
    params = validate_tasks(family, task_params)
    W = policy.check_W(W)
    B = max(params.shape[0], W.shape[0])
    for name, arr in (("task_params", params), ("W", W)):
        if arr.shape[0] not in (1, B):
            raise ValueError(
                f"cannot broadcast {name} with {arr.shape[0]} rows against B = {B} rollouts "
                f"(task_params has {params.shape[0]}, W has {W.shape[0]}; use 1 or B rows)"
            )
    return params, W, B


def simulate(
    family: str,
    task_params: np.ndarray,
    W: np.ndarray,
    *,
    policy: RBFPolicy | None = None,
    config: ArmConfig | dict[str, Any] | None = None,
    record: bool = False,
    controller: Callable[[int, np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> Rollout:
    """Roll out B policies on B tasks together (rows of 1 broadcast): ``task_params`` (B, k) or (k,),
    ``W`` (B, D, A) or (D, A). Returns a :class:`Rollout` with cost and success per row.

    ``controller(t, pos (B, A), vel (B, A)) -> acc (B, A)`` replaces the RBF-PD action of Eq 5.8 (for
    closed-loop policy classes such as the ELLA/FCNN baselines); ``W`` then only sets B (pass any
    ``(B, 3, A)`` array).
    """
    check_family(family)
    cfg = ArmConfig.make(config)
    Wa = np.asarray(W, dtype=float)
    if Wa.ndim not in (2, 3) or Wa.shape[-1] != A or Wa.shape[-2] < 3:
        raise ValueError(f"W must have shape (D, {A}) or (B, D, {A}) with D = N + 2 >= 3; got {Wa.shape}")
    if policy is None:
        policy = RBFPolicy(n_basis=Wa.shape[-2] - 2, horizon=cfg.horizon, dt=cfg.dt)
    elif policy.horizon != cfg.horizon or not np.isclose(policy.dt, cfg.dt):
        raise ValueError(
            f"policy (horizon={policy.horizon}, dt={policy.dt}) does not match the config "
            f"(horizon={cfg.horizon}, dt={cfg.dt})"
        )
    params, Wa, B = _broadcast(family, task_params, Wa, policy)
    params = np.broadcast_to(params, (B, params.shape[1]))
    xd, vd = policy.desired(Wa)
    kp, kd = policy.gains(Wa)
    xd, vd = np.broadcast_to(xd, (B, *xd.shape[1:])), np.broadcast_to(vd, (B, *vd.shape[1:]))
    kp, kd = np.broadcast_to(kp, (B, A)), np.broadcast_to(kd, (B, A))

    T, h, ns = cfg.horizon, cfg.h, cfg.n_substeps
    lo = np.array([cfg.workspace[0][0], cfg.workspace[1][0]])
    hi = np.array([cfg.workspace[0][1], cfg.workspace[1][1]])
    g = np.array([0.0, -cfg.gravity])
    two_a = 2.0 * cfg.accel_limit
    p = np.zeros((B, A))
    v = np.zeros((B, A))
    has_ball = family != "reach"
    string = family in ("bic", "cast")
    if string:
        length = params[:, 0].copy()
        drag = cfg.drag_coef / params[:, 1]
        q = np.stack([np.zeros(B), -length], axis=1)
    else:
        length = drag = None
        q = np.zeros((B, A))
    u = np.zeros((B, A))
    if family == "throw":
        target = params.copy()
    elif family == "cast":
        target = np.broadcast_to(np.asarray(cfg.cast_cup), (B, A)).copy()
    else:
        target = None  # bic: the cup is the end-effector; reach: no ball

    action_cost = np.zeros(B)
    decided = np.zeros(B, dtype=bool)
    caught = np.zeros(B, dtype=bool)
    hit_step = np.full(B, -1)
    hit_dx = np.full(B, np.nan)
    min_dist = np.full(B, np.inf) if has_ball else np.full(B, np.nan)
    reach_cost = np.zeros(B)
    radius = cfg.basket_radius if family == "throw" else cfg.cup_radius
    taut = np.zeros(B, dtype=bool)
    if string:
        taut[:] = True  # hanging at rest at full length

    if record:
        ee_rec = np.zeros((B, T + 1, A))
        vel_rec = np.zeros((B, T + 1, A))
        ball_rec = np.zeros((B, T + 1, A))
        taut_rec = np.zeros((B, T + 1), dtype=bool)
        act_rec = np.zeros((B, T, A))
        ball_rec[:, 0] = q
        taut_rec[:, 0] = taut
    if family == "reach":
        goal = params
        reach_cost += _dot(p - goal, p - goal) + cfg.reach_velocity_weight * _dot(v, v) - cfg.reach_baseline

    substep = 0
    for t in range(T):
        a = controller(t, p, v) if controller is not None else kp * (xd[:, t] - p) + kd * (vd[:, t] - v)
        action_cost += cfg.alpha * np.sqrt(_dot(a, a))
        if record:
            act_rec[:, t] = a  # the policy's output (the penalised action), before the actuator limit
        a = np.clip(a, -cfg.accel_limit, cfg.accel_limit)
        for _ in range(ns):
            p_old, v_old = p, v
            v = v + a * h
            # brake within the actuator limit before the workspace boundary: speed towards a wall at
            # distance d is at most sqrt(2 a_max d) (no infinite deceleration at the walls)
            v = np.clip(v, -np.sqrt(two_a * np.maximum(p - lo, 0.0)), np.sqrt(two_a * np.maximum(hi - p, 0.0)))
            p = p + v * h
            out_lo, out_hi = p < lo, p > hi
            if out_lo.any() or out_hi.any():
                p = np.clip(p, lo, hi)
                v = np.where((out_lo & (v < 0)) | (out_hi & (v > 0)), 0.0, v)
            if not has_ball:
                substep += 1
                continue
            q_prev = q
            cup = p if family == "bic" else target
            if family == "throw":
                if substep < cfg.release_step:
                    q, u = p.copy(), v.copy()
                    substep += 1
                    continue
                q = q + u * h + 0.5 * g * h * h
                u = u + g * h
                cup_prev = target
                free = np.ones(B, dtype=bool)
            else:
                speed = np.sqrt(_dot(u, u))
                g_eff = g - (drag * speed)[:, None] * u
                q, u, taut = pendulum_step(p_old, v_old, p, v, q, u, length, g_eff, h)
                cup_prev = p_old if family == "bic" else target
                # a caught ball rides in the cup (bic) or rests in the fixed cup (cast)
                q = np.where(caught[:, None], cup, q)
                u = np.where(caught[:, None], v if family == "bic" else 0.0, u)
                taut = taut & ~caught
                free = ~caught
            dh_prev = q_prev[:, 1] - cup_prev[:, 1]
            dh = q[:, 1] - cup[:, 1]
            event = ~decided & free & (dh_prev > 0) & (dh <= 0)
            if event.any():
                f = dh_prev / np.where(event, dh_prev - dh, 1.0)
                dx = (1 - f) * (q_prev[:, 0] - cup_prev[:, 0]) + f * (q[:, 0] - cup[:, 0])
                hit_dx = np.where(event, dx, hit_dx)
                hit_step = np.where(event, t + 1, hit_step)
                decided |= event
                got = event & (np.abs(dx) < radius)
                if string and got.any():
                    caught |= got
                    q = np.where(got[:, None], cup, q)
                    u = np.where(got[:, None], v if family == "bic" else 0.0, u)
            # the cup/basket is solid from below: a ball rising into its bottom bounces off it
            up = free & (dh_prev <= 0) & (dh > 0)
            if up.any():
                f = -dh_prev / np.where(up, dh - dh_prev, 1.0)
                dx = (1 - f) * (q_prev[:, 0] - cup_prev[:, 0]) + f * (q[:, 0] - cup[:, 0])
                blocked = up & (np.abs(dx) < radius)
                if blocked.any():
                    q, u = _bounce_below(
                        q,
                        u,
                        cup,
                        v if family == "bic" else np.zeros_like(v),
                        blocked,
                        cfg.cup_restitution,
                        p if string else None,
                        length,
                    )
                    if string:
                        dist = np.sqrt(_dot(q - p, q - p))
                        taut = np.where(blocked, dist >= length * (1 - 1e-9), taut)
            min_dist = np.minimum(min_dist, np.sqrt(_dot(q - cup, q - cup)))
            substep += 1
        if family == "reach":
            sq = _dot(p - goal, p - goal) + cfg.reach_velocity_weight * _dot(v, v)
            reach_cost += cfg.gamma ** (t + 1) * (sq - cfg.reach_baseline)
        if record:
            ee_rec[:, t + 1] = p
            vel_rec[:, t + 1] = v
            ball_rec[:, t + 1] = q if has_ball else np.nan
            taut_rec[:, t + 1] = taut

    if family == "reach":
        task_cost = reach_cost + action_cost
        success = np.sqrt(_dot(p - params, p - params)) < cfg.reach_tolerance
        shaping = np.zeros(B)
    else:
        bonus = np.where(
            decided,
            cfg.gamma ** np.maximum(hit_step, 0) * np.minimum(cfg.cost_b1 * np.nan_to_num(hit_dx) ** 2 - cfg.cost_b, 0),
            0.0,
        )
        task_cost = bonus + action_cost
        success = decided & (np.abs(np.nan_to_num(hit_dx, nan=np.inf)) < radius)
        shaping = cfg.shaping_weight * min_dist
    cost = task_cost + shaping if cfg.shaped else task_cost.copy()
    out = Rollout(
        cost=cost,
        task_cost=task_cost,
        success=success,
        action_cost=action_cost,
        hit=decided.copy(),
        hit_step=hit_step,
        hit_dx=hit_dx,
        min_dist=min_dist,
    )
    if record:
        out.ee, out.ee_vel, out.taut, out.actions = ee_rec, vel_rec, taut_rec, act_rec
        out.ball = ball_rec if has_ball else None
    return out
