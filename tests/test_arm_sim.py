"""Physics invariants, costs (Eq 5.12), policy (Eq 5.5-5.8) and batching of the 2-D arm simulator."""

from __future__ import annotations

import numpy as np
import pytest

from thesis_repro.arm import FAMILIES, TASK_PARAM_NAMES, ArmConfig, RBFPolicy, sample_tasks, simulate, validate_tasks
from thesis_repro.arm.tasks import pendulum_step

G = 9.81


def _smoothstep(t, t0, t1):
    s = np.clip((t - t0) / (t1 - t0), 0, 1)
    return 3 * s**2 - 2 * s**3


def _random_W(rng, B, n_basis=10, scale=1.0):
    W = rng.normal(0, scale, (B, n_basis + 2, 2))
    W[:, n_basis:] = np.abs(W[:, n_basis:]) + 0.2  # stable-ish PD gains
    return W


# ------------------------------------------------------------------------------------------ physics
@pytest.mark.parametrize("angle_deg", [30.0, 60.0, 85.0])
def test_taut_pendulum_conserves_energy_without_arm_motion(angle_deg):
    L, h = np.array([0.3]), 0.01
    th = np.deg2rad(angle_deg)
    q = np.array([[L[0] * np.sin(th), -L[0] * np.cos(th)]])
    u = np.zeros((1, 2))
    p = v = np.zeros((1, 2))
    E0 = G * q[0, 1]
    energies, dists, tauts = [], [], []
    for _ in range(300):  # 3 s, > 2 periods
        q, u, taut = pendulum_step(p, v, p, v, q, u, L, np.array([[0.0, -G]]), h)
        energies.append(0.5 * (u**2).sum() + G * q[0, 1])
        dists.append(np.linalg.norm(q))
        tauts.append(taut[0])
    assert all(tauts)
    np.testing.assert_allclose(dists, L[0], atol=1e-12)
    # velocity Verlet on the angle: bounded second-order error, no drift; < 0.5% of m g L
    assert np.max(np.abs(np.array(energies) - E0)) < 0.005 * G * L[0]


def test_period_of_small_oscillation_matches_closed_form():
    L, h = np.array([0.4]), 0.005
    th = np.deg2rad(5)
    q = np.array([[L[0] * np.sin(th), -L[0] * np.cos(th)]])
    u, p = np.zeros((1, 2)), np.zeros((1, 2))
    xs = []
    for _ in range(1000):
        q, u, _ = pendulum_step(p, p, p, p, q, u, L, np.array([[0.0, -G]]), h)
        xs.append(q[0, 0])
    xs = np.array(xs)
    ups = np.flatnonzero((xs[:-1] < 0) & (xs[1:] >= 0))  # upward zero crossings
    period = np.mean(np.diff(ups)) * h
    assert period == pytest.approx(2 * np.pi * np.sqrt(L[0] / G), rel=0.02)


def test_slack_ball_flies_ballistically_in_closed_form():
    L, h = np.array([1.0]), 0.01
    q0, u0 = np.array([[0.0, -0.1]]), np.array([[1.0, 2.0]])
    p = np.zeros((1, 2))
    q, u = q0, u0
    for k in range(1, 31):
        q, u, taut = pendulum_step(p, p, p, p, q, u, L, np.array([[0.0, -G]]), h)
        t = k * h
        assert not taut[0]
        np.testing.assert_allclose(q[0], q0[0] + u0[0] * t + 0.5 * np.array([0, -G]) * t * t, atol=1e-12)
        np.testing.assert_allclose(u[0], u0[0] + np.array([0, -G]) * t, atol=1e-12)


def test_thrown_ball_after_release_has_constant_acceleration():
    pol = RBFPolicy(n_basis=10)
    t = np.arange(100) * 0.02
    target = np.stack([0.4 * _smoothstep(t, 0.0, 0.6), 0.3 * _smoothstep(t, 0.1, 0.6)], 1)
    r = simulate("throw", [1.0, -0.2], pol.fit(target), record=True)
    release = int(round(ArmConfig().release_time / ArmConfig().dt))
    ball = r.ball[0, release:]
    acc = np.diff(ball, 2, axis=0) / 0.02**2
    np.testing.assert_allclose(acc[:, 0], 0.0, atol=1e-8)
    np.testing.assert_allclose(acc[:, 1], -G, atol=1e-6)
    np.testing.assert_allclose(r.ball[0, :release], r.ee[0, :release])  # held before release


@pytest.mark.parametrize("family", ["bic", "cast"])
def test_string_length_never_exceeded(family):
    rng = np.random.default_rng(3)
    tasks = sample_tasks(family, 200, rng)
    r = simulate(family, tasks, _random_W(rng, 200), record=True)
    dist = np.linalg.norm(r.ball - r.ee, axis=-1)
    if family == "cast":  # a caught ball rests in the fixed cup: the string is released
        steps = np.arange(dist.shape[1])[None]
        dist = np.where(r.success[:, None] & (steps >= r.hit_step[:, None]), 0.0, dist)
        r.taut[dist == 0.0] = False
    assert np.all(dist <= tasks[:, :1] * (1 + 1e-9))
    assert r.taut.any() and (~r.taut).any()  # both phases occur
    # taut flags mean full length
    assert np.all(dist[r.taut] >= tasks[:, :1].repeat(dist.shape[1], 1)[r.taut] * (1 - 1e-6))


def test_arm_at_rest_leaves_ball_hanging():
    r = simulate("bic", [[0.3, 0.05]], np.zeros((12, 2)), record=True)
    np.testing.assert_allclose(r.ball[0], np.tile([0.0, -0.3], (101, 1)), atol=1e-12)
    assert r.taut.all() and r.cost[0] == 0.0 and not r.hit[0]


def test_ball_mass_acts_only_through_air_drag():
    rng = np.random.default_rng(4)
    W = _random_W(rng, 1)
    light = simulate("cast", [0.35, 0.01], W, record=True)
    heavy = simulate("cast", [0.35, 0.1], W, record=True)
    assert not np.allclose(light.ball, heavy.ball)
    no_drag = {"drag_coef": 0.0}
    a = simulate("cast", [0.35, 0.01], W, record=True, config=no_drag)
    b = simulate("cast", [0.35, 0.1], W, record=True, config=no_drag)
    np.testing.assert_array_equal(a.ball, b.ball)


def test_workspace_is_respected():
    rng = np.random.default_rng(5)
    r = simulate("reach", sample_tasks("reach", 100, rng), _random_W(rng, 100, scale=3.0), record=True)
    (x0, x1), (y0, y1) = ArmConfig().workspace
    assert r.ee[..., 0].min() >= x0 and r.ee[..., 0].max() <= x1
    assert r.ee[..., 1].min() >= y0 and r.ee[..., 1].max() <= y1


# ------------------------------------------------------------------------------------------- policy
def test_policy_layers_follow_eq_5_5_to_5_8():
    pol = RBFPolicy(n_basis=5, horizon=40, dt=0.05)
    rng = np.random.default_rng(0)
    W = rng.normal(size=(3, 7, 2))
    t = 0.7
    mu, s = pol.centres, pol.sigmas
    phi = np.exp(-((t - mu) ** 2) / (2 * s**2)) / np.sqrt(2 * np.pi * s)  # Eq 5.5
    np.testing.assert_allclose(pol.basis([t])[0], phi)
    xd, vd = pol.desired(W)
    k = 14  # t = 0.7 s
    np.testing.assert_allclose(xd[:, k], np.einsum("n,bna->ba", phi, W[:, :5]))  # Eq 5.6
    fd = (pol.basis([t + 0.05]) - pol.basis([t - 0.05]))[0] / 0.1  # Eq 5.7
    np.testing.assert_allclose(vd[:, k], np.einsum("n,bna->ba", fd, W[:, :5]))
    pos, vel = rng.normal(size=(3, 2)), rng.normal(size=(3, 2))
    a = pol.action(W, k, pos, vel)  # Eq 5.8
    np.testing.assert_allclose(a, 100 * W[:, 5] * (xd[:, k] - pos) + 20 * W[:, 6] * (vd[:, k] - vel))


def test_fit_recovers_rbf_weights_and_reproduces_trajectory():
    pol = RBFPolicy(n_basis=10)
    rng = np.random.default_rng(1)
    W = pol.default_params()
    W[:10] = rng.normal(0, 0.05, (10, 2))
    target = pol.desired(W)[0][0]
    W_fit = pol.fit(target)
    np.testing.assert_allclose(W_fit, W, atol=1e-6)
    # a smooth demonstrated trajectory is reproduced by the RBF layer ...
    t = np.arange(100) * 0.02
    demo = np.stack([0.2 * np.sin(np.pi * t / 2), 0.15 * (1 - np.cos(np.pi * t / 2))], 1)
    xd = pol.desired(pol.fit(demo))[0][0]
    assert np.max(np.abs(xd - demo)) < 0.03 * np.abs(demo).max()
    # ... and the PD layer makes the simulated end-effector follow it
    r = simulate("reach", [0.0, 0.0], pol.fit(demo, kp=4.0, kd=2.0), record=True)
    assert np.max(np.abs(r.ee[0, 1:] - demo)) < 0.05 * np.abs(demo).max() + 0.01


def test_flat_parameters_roundtrip():
    pol = RBFPolicy(n_basis=4)
    theta = np.arange(pol.n_params, dtype=float)
    pol.set_params(theta)
    np.testing.assert_array_equal(pol.get_params(), theta)
    assert pol.W[2, 1] == theta[2 * 2 + 1]  # C order: flat[d*A + i] = W[d, i]
    batch = np.random.default_rng(0).normal(size=(3, 5, pol.n_params))
    np.testing.assert_array_equal(pol.flatten(pol.unflatten(batch)), batch)
    with pytest.raises(ValueError, match="length 12"):
        pol.set_params(np.zeros(11))
    with pytest.raises(ValueError, match="n_basis"):
        RBFPolicy(n_basis=0)


# -------------------------------------------------------------------------------------------- costs
def test_reach_cost_of_a_still_arm_matches_the_formula():
    cfg = ArmConfig()
    goal = np.array([0.2, -0.1])
    r = simulate("reach", goal, np.zeros((12, 2)))
    disc = cfg.gamma ** np.arange(cfg.horizon + 1)
    expected = np.sum(disc * (goal @ goal - cfg.reach_baseline))
    assert r.cost[0] == pytest.approx(expected, rel=1e-12)
    assert not r.success[0]
    assert simulate("reach", [0.01, 0.0], np.zeros((12, 2))).success[0]


def test_reach_cost_with_motion_matches_the_formula():
    rng = np.random.default_rng(2)
    cfg = ArmConfig()
    goal = np.array([0.1, 0.2])
    r = simulate("reach", goal, _random_W(rng, 1, scale=0.2), record=True)
    disc = cfg.gamma ** np.arange(cfg.horizon + 1)
    # squared distance to the target state (goal, zero velocity), velocity weighted by w_v
    dist2 = ((r.ee[0] - goal) ** 2).sum(-1) + cfg.reach_velocity_weight * (r.ee_vel[0] ** 2).sum(-1)
    act = cfg.alpha * np.linalg.norm(r.actions[0], axis=-1).sum()
    assert r.cost[0] == pytest.approx(np.sum(disc * (dist2 - cfg.reach_baseline)) + act, rel=1e-10)
    assert r.action_cost[0] == pytest.approx(act, rel=1e-12)


def test_reach_cost_penalises_velocity():
    """§5.3.1: Reach penalises large velocities (|v_t|² term, weight w_v) and accelerations (α|a_t|)."""
    rng = np.random.default_rng(3)
    goals = sample_tasks("reach", 6, rng)
    W = _random_W(rng, 6, scale=0.1)
    cfg = ArmConfig()
    moving = simulate("reach", goals, W, record=True)
    old = simulate("reach", goals, W, config={"reach_velocity_weight": 0.0}, record=True)
    double = simulate("reach", goals, W, config={"reach_velocity_weight": 2 * cfg.reach_velocity_weight})
    # same motion; the cost difference is exactly Σ_t γ^t w_v |v_t|² (v_0 = 0)
    np.testing.assert_array_equal(moving.ee, old.ee)
    disc = cfg.gamma ** np.arange(cfg.horizon + 1)
    vel_term = cfg.reach_velocity_weight * (disc * (moving.ee_vel**2).sum(-1)).sum(-1)
    assert cfg.reach_velocity_weight > 0 and (vel_term > 1e-5).all()
    np.testing.assert_allclose(moving.cost - old.cost, vel_term, rtol=1e-10)
    np.testing.assert_allclose(double.cost - old.cost, 2 * vel_term, rtol=1e-10)
    # recorded velocities are the integrated (clipped) accelerations: Δv = a·dt away from the walls
    dv = np.diff(moving.ee_vel, axis=1)
    acc = np.clip(moving.actions, -cfg.accel_limit, cfg.accel_limit) * cfg.dt
    lo, hi = np.array(cfg.workspace)[:, 0], np.array(cfg.workspace)[:, 1]
    inside = ((moving.ee[:, 1:] > lo + 0.05) & (moving.ee[:, 1:] < hi - 0.05)).all(-1)
    inside &= ((moving.ee[:, :-1] > lo + 0.05) & (moving.ee[:, :-1] < hi - 0.05)).all(-1)
    assert inside.mean() > 0.5
    np.testing.assert_allclose(dv[inside], acc[inside], atol=1e-9)
    # a still arm pays no velocity cost (its cost is the position-only formula of the test above)
    still = simulate("reach", goals[0], np.zeros((12, 2)), record=True)
    assert np.all(still.ee_vel == 0.0)
    with pytest.raises(ValueError, match="reach_velocity_weight"):
        ArmConfig(reach_velocity_weight=-1.0)


def test_throw_cost_matches_eq_5_12_for_a_dropped_ball():
    """A still arm releases the ball at rest at the origin: it falls straight down at x = 0."""
    cfg = ArmConfig()
    W = np.zeros((12, 2))
    drop = np.sqrt(2 * 0.3 / G)  # fall time to y = -0.3
    m = int(np.floor((cfg.release_time + drop) / cfg.dt)) + 1  # control step of the crossing
    r = simulate("throw", [[0.05, -0.3], [0.5, -0.3], [0.0, 0.1]], W)
    assert r.hit.tolist() == [True, True, False]
    np.testing.assert_allclose(r.hit_dx[:2], [-0.05, -0.5], atol=1e-12)
    assert r.hit_step[0] == m
    expected = cfg.gamma**m * min(cfg.cost_b1 * 0.05**2 - cfg.cost_b, 0.0)
    assert r.cost[0] == pytest.approx(expected, rel=1e-12)
    assert r.cost[1] == 0.0  # too far: min(., 0) = 0
    assert r.cost[2] == 0.0  # heights never match
    assert r.success.tolist() == [True, False, False]


def test_string_cost_is_bonus_plus_action_penalty():
    rng = np.random.default_rng(6)
    cfg = ArmConfig()
    for family in ("bic", "cast"):
        tasks = sample_tasks(family, 300, rng)
        r = simulate(family, tasks, _random_W(rng, 300), record=True)
        act = cfg.alpha * np.linalg.norm(r.actions, axis=-1).sum(1)
        np.testing.assert_allclose(r.action_cost, act, rtol=1e-12)
        bonus = np.where(
            r.hit, cfg.gamma**r.hit_step * np.minimum(cfg.cost_b1 * np.nan_to_num(r.hit_dx) ** 2 - cfg.cost_b, 0), 0
        )
        np.testing.assert_allclose(r.cost, bonus + act, rtol=1e-12)
        assert r.hit.any() and (~r.hit).any()
        np.testing.assert_array_equal(r.success, r.hit & (np.abs(np.nan_to_num(r.hit_dx, nan=9)) < cfg.cup_radius))


def test_catch_is_detected_for_a_hand_made_swing():
    """Move the cup fast to the left (braking at the workspace edge) so the ball swings up over it, then
    lift the cup 0.2 m under the descending ball; without the lift the ball is missed."""
    pol = RBFPolicy(n_basis=10)
    t = np.arange(100) * 0.02

    def movement(lift):
        return np.stack([-0.45 * _smoothstep(t, 0.0, 0.15), lift * _smoothstep(t, 0.4, 0.55)], 1)

    r = simulate("bic", [0.3, 0.05], pol.fit(movement(0.2), kp=2.0), record=True)
    assert r.success[0] and r.hit[0]
    m = r.hit_step[0]
    ball, ee = r.ball[0], r.ee[0]
    assert abs(r.hit_dx[0]) < ArmConfig().cup_radius
    assert ball[m - 1, 1] > ee[m - 1, 1]  # it came down from above the cup ...
    assert (~r.taut[0, 1:m]).any()  # ... on a slack string
    np.testing.assert_allclose(ball[m:], ee[m:], atol=1e-12)  # then it rides in the cup
    cfg = ArmConfig()
    expected = cfg.gamma**m * (cfg.cost_b1 * r.hit_dx[0] ** 2 - cfg.cost_b) + r.action_cost[0]
    assert r.cost[0] == pytest.approx(expected, rel=1e-12)
    assert not simulate("bic", [0.3, 0.05], pol.fit(movement(0.0), kp=2.0)).success[0]


def test_ball_cannot_pass_up_through_the_cup():
    pol = RBFPolicy(n_basis=10)
    t = np.arange(100) * 0.02
    jerk_up = np.stack([0 * t, _smoothstep(t, 0.1, 0.3)], 1)  # the ball would fly straight up through the cup
    r = simulate("bic", [0.3, 0.05], pol.fit(jerk_up, kp=2.0), record=True)
    assert not r.success[0]
    assert np.all(r.ball[0, :, 1] <= r.ee[0, :, 1] + 1e-6)


# ------------------------------------------------------------------------------------ tasks & errors
def test_sample_tasks_ranges_and_seeding():
    for family in FAMILIES:
        a = sample_tasks(family, 50, np.random.default_rng(7))
        b = sample_tasks(family, 50, np.random.default_rng(7))
        np.testing.assert_array_equal(a, b)
        assert a.shape == (50, len(TASK_PARAM_NAMES[family]))
        validate_tasks(family, a)


@pytest.mark.parametrize(
    ("family", "params", "match"),
    [
        ("bic", [[-0.3, 0.05]], "string_length must be > 0"),
        ("cast", [[0.3, 0.0]], "ball_mass must be > 0"),
        ("bic", [[0.3, -1.0]], "ball_mass must be > 0"),
        ("reach", [[0.1, np.nan]], "goal_y must be finite"),
        ("throw", [[1.0, 0.0, 3.0]], "shape"),
        ("ball-in-cup", [[0.3, 0.05]], "valid families are: 'reach', 'throw', 'bic', 'cast'"),
    ],
)
def test_bad_task_parameters_raise_clear_errors(family, params, match):
    with pytest.raises(ValueError, match=match):
        validate_tasks(family, params)
    with pytest.raises(ValueError, match=match):
        simulate(family, params, np.zeros((12, 2)))


def test_bad_configs_and_shapes_raise():
    with pytest.raises(ValueError, match="valid ArmConfig fields are"):
        simulate("reach", [0, 0], np.zeros((12, 2)), config={"gama": 0.9})
    with pytest.raises(ValueError, match="gamma"):
        ArmConfig(gamma=1.5)
    with pytest.raises(ValueError, match="broadcast"):
        simulate("reach", np.zeros((3, 2)), np.zeros((2, 12, 2)))
    with pytest.raises(ValueError, match="does not match"):
        simulate("reach", [0, 0], np.zeros((12, 2)), policy=RBFPolicy(horizon=50))


# ---------------------------------------------------------------------------------------- batching
@pytest.mark.parametrize("family", FAMILIES)
def test_batched_simulation_equals_row_by_row(family):
    rng = np.random.default_rng(8)
    tasks = sample_tasks(family, 6, rng)
    W = _random_W(rng, 6)
    batch = simulate(family, tasks, W, config={"shaped": True})
    for i in range(6):
        one = simulate(family, tasks[i], W[i], config={"shaped": True})
        assert one.cost[0] == pytest.approx(batch.cost[i], rel=1e-12, abs=1e-12)
        assert one.task_cost[0] == pytest.approx(batch.task_cost[i], rel=1e-12, abs=1e-12)
        assert one.success[0] == batch.success[i]
    # broadcasting one policy over many tasks
    shared = simulate(family, tasks, W[0])
    np.testing.assert_allclose(shared.task_cost[2], simulate(family, tasks[2], W[0]).task_cost[0])


def test_shaping_only_changes_the_optimised_cost():
    rng = np.random.default_rng(9)
    tasks = sample_tasks("bic", 20, rng)
    W = _random_W(rng, 20)
    plain = simulate("bic", tasks, W)
    shaped = simulate("bic", tasks, W, config={"shaped": True})
    np.testing.assert_array_equal(plain.task_cost, shaped.task_cost)
    np.testing.assert_allclose(shaped.cost - shaped.task_cost, ArmConfig().shaping_weight * shaped.min_dist)


# -------------------------------------------------------------------------------------- bench & job
def test_bench_arm_reports_ratio_and_cma_generation():
    from thesis_repro.arm.bench import bench_arm

    r = bench_arm(n_rollouts=200, loop_rollouts=3, cma_generations=1, repeats=1)
    assert r["speedup"] == pytest.approx(r["vectorised_rollouts_per_s"] / r["loop_rollouts_per_s"])
    assert r["speedup"] > 1.0  # vectorised beats the per-policy loop even at B = 200
    assert r["cma_n_params"] == 24 and r["cma_popsize"] == 4 + int(3 * np.log(24))
    assert r["cma_generation_s"] > 0
    with pytest.raises(ValueError, match="valid families"):
        bench_arm(family="juggle")


def test_solve_task_job_returns_a_recorded_rollout(tmp_path):
    from thesis_repro.arm.learn import solve_task

    cfg = {
        "family": "bic",
        "task": [0.3, 0.05],
        "n_basis": 6,
        "generations": 2,
        "sigma": 0.3,
        "popsize": 4,
        "shaped": True,
        "seed": 0,
    }
    r = solve_task(cfg, tmp_path)
    assert r["W"].shape == (8, 2) and r["curve"].shape == (2,) and r["popsize"] == 4
    assert r["ee"].shape == (101, 2) and r["ball"].shape == (101, 2) and r["taut"].shape == (101,)
    again = simulate("bic", cfg["task"], r["W"])
    assert again.task_cost[0] == pytest.approx(r["cost"]) and bool(again.success[0]) == r["success"]


def test_reach_velocity_penalty_keeps_reach_learnable_and_slows_the_arm():
    """The chosen w_v (τ = √w_v = 0.2 s) penalises speed without making the goals unreachable in 2 s."""
    from thesis_repro.arm.learn import learn_independent

    tasks = sample_tasks("reach", 4, np.random.default_rng(0))
    W0 = np.zeros((4, 12, 2))
    W0[:, 10:] = 1.0
    peak = {}
    for w in (0.0, ArmConfig().reach_velocity_weight):
        cfg = {"reach_velocity_weight": w}
        W, _ = learn_independent("reach", tasks, W0, generations=150, sigma=0.1, config=cfg, seed=0)
        r = simulate("reach", tasks, W, config=cfg, record=True)
        assert r.success.all()
        peak[w] = np.linalg.norm(r.ee_vel, axis=-1).max(1).mean()
    assert peak[ArmConfig().reach_velocity_weight] < 0.8 * peak[0.0]
