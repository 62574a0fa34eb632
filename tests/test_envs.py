"""Chapter-3 environment model: noise statistics, factor writes/restores, seeding and argument checks."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from thesis_repro.envs import (
    ENVS,
    FACTORS,
    MIN_RATIO,
    PERTURBATIONS,
    WIND_SCALE,
    ActionNoise,
    DomainShift,
    EnvironmentNoise,
    ObservationNoise,
    SystematicShift,
    Wind,
    make_env,
    resolve_env,
    wrap_env,
)
from thesis_repro.envs.factors import BodyMass, WindForce


def _model_arrays(env) -> dict[str, np.ndarray]:
    m, d = env.unwrapped.model, env.unwrapped.data
    return {
        "body_mass": m.body_mass.copy(),
        "body_inertia": m.body_inertia.copy(),
        "geom_friction": m.geom_friction.copy(),
        "gravity": m.opt.gravity.copy(),
        "xfrc_applied": d.xfrc_applied.copy(),
    }


def _pristine(env_id: str) -> dict[str, np.ndarray]:
    env = gym.make(env_id)
    env.reset(seed=0)
    return _model_arrays(env)


def _rollout(env, n: int, seed: int, action=None) -> np.ndarray:
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for _ in range(n):
        a = np.zeros(env.action_space.shape) if action is None else action
        obs, _, term, trunc, _ = env.step(a)
        out.append(obs)
        if term or trunc:
            obs, _ = env.reset()
            out.append(obs)
    return np.array(out)


# --- registry ------------------------------------------------------------------------------------------


def test_envs_table_and_names():
    assert list(ENVS) == ["InvertedPendulum", "InvertedDoublePendulum", "Walker2d", "Hopper", "HalfCheetah"]
    assert all(v.endswith("-v5") for v in ENVS.values())
    assert resolve_env("Hopper") == resolve_env("Hopper-v5") == "Hopper-v5"
    with pytest.raises(ValueError, match="Walker2d"):
        resolve_env("Walker")
    with pytest.raises(ValueError, match="Hopper"):
        make_env("Hopper-v2")
    assert set(FACTORS["Walker2d"]) == set(FACTORS["Hopper"]) == {"body_mass", "wind", "friction", "gravity"}
    assert set(FACTORS["HalfCheetah"]) == {"body_mass", "friction", "gravity"}
    assert set(FACTORS["InvertedPendulum"]) == {"cart_mass", "pole_mass"}
    assert set(FACTORS["InvertedDoublePendulum"]) == {"cart_mass", "pole1_mass", "pole2_mass"}
    assert PERTURBATIONS == ("none", "obs", "act", "env", "dom")


@pytest.mark.parametrize("name", list(ENVS))
def test_every_env_every_perturbation_steps(name):
    for p in PERTURBATIONS:
        env = make_env(name, p, 0.1, max_episode_steps=3, seed=0)
        obs, info = env.reset(seed=1)
        assert env.observation_space.shape == obs.shape
        for _ in range(3):
            obs, r, term, trunc, info = env.step(env.action_space.sample())
            assert np.all(np.isfinite(obs)) and np.isfinite(r)
        assert trunc or term
        if p in ("env", "dom"):
            assert set(info["factors"]) == set(FACTORS[name])
        env.close()


# --- observation and action noise ----------------------------------------------------------------------


def test_observation_noise_std_matches_sigma():
    sigma = 0.3
    env = ObservationNoise(gym.make("Hopper-v5"), sigma)
    obs, _ = env.reset(seed=0)
    diffs = [obs - env.unwrapped._get_obs()]
    for _ in range(400):
        obs, _, term, trunc, _ = env.step(np.zeros(3))
        diffs.append(obs - env.unwrapped._get_obs())
        if term or trunc:
            obs, _ = env.reset()
            diffs.append(obs - env.unwrapped._get_obs())
    d = np.array(diffs).ravel()
    assert d.size > 4000
    assert abs(d.std() - sigma) < 0.05 * sigma
    assert abs(d.mean()) < 4 * sigma / np.sqrt(d.size)


def test_observation_noise_zero_sigma_is_identity():
    clean = _rollout(gym.make("Hopper-v5"), 50, seed=3)
    noisy = _rollout(ObservationNoise(gym.make("Hopper-v5"), 0.0), 50, seed=3)
    np.testing.assert_array_equal(clean, noisy)


def test_action_noise_reaches_simulator_with_sigma_and_is_clipped():
    sigma = 0.1
    env = ActionNoise(gym.make("Hopper-v5"), sigma)
    env.reset(seed=0)
    ctrl = []
    for _ in range(600):
        _, _, term, trunc, _ = env.step(np.zeros(3))
        ctrl.append(env.unwrapped.data.ctrl.copy())
        if term or trunc:
            env.reset()
    c = np.array(ctrl).ravel()
    assert abs(c.std() - sigma) < 0.1 * sigma
    assert abs(c.mean()) < 4 * sigma / np.sqrt(c.size)

    big = ActionNoise(gym.make("Hopper-v5"), 5.0)
    big.reset(seed=0)
    seen = []
    for _ in range(50):
        big.step(np.full(3, 0.9))
        seen.append(big.unwrapped.data.ctrl.copy())
    seen = np.array(seen)
    assert seen.max() == 1.0 and seen.min() == -1.0  # clipped to Box(-1, 1)


# --- factors: writes, restores, mj_name2id ---------------------------------------------------------------


def test_systematic_shift_writes_stated_amounts_and_restores_exactly():
    pristine = _pristine("Walker2d-v5")
    env = SystematicShift(gym.make("Walker2d-v5"), {"body_mass": 1.5, "friction": 2.0, "gravity": 0.5, "wind": 1.0})
    _, info = env.reset(seed=0)
    assert info["factors"] == {"body_mass": 1.5, "friction": 2.0, "gravity": 0.5, "wind": 1.0}
    now = _model_arrays(env)
    np.testing.assert_allclose(now["body_mass"][1:], 1.5 * pristine["body_mass"][1:])
    np.testing.assert_allclose(now["body_inertia"][1:], 1.5 * pristine["body_inertia"][1:])
    assert now["body_mass"][0] == 0.0
    np.testing.assert_allclose(now["geom_friction"][:, 0], 2.0 * pristine["geom_friction"][:, 0])
    np.testing.assert_array_equal(now["geom_friction"][:, 1:], pristine["geom_friction"][:, 1:])
    np.testing.assert_allclose(now["gravity"], [0.0, 0.0, -9.81 * 0.5])
    torso = mujoco.mj_name2id(env.unwrapped.model, mujoco.mjtObj.mjOBJ_BODY, "torso")
    total = pristine["body_mass"].sum()
    assert now["xfrc_applied"][torso, 0] == pytest.approx(1.0 * total)  # ξ = 1 m/s² on the default mass
    assert np.count_nonzero(now["xfrc_applied"]) == 1
    for _ in range(5):
        env.step(np.zeros(6))
    assert env.unwrapped.data.xfrc_applied[torso, 0] == pytest.approx(total)
    env.reset()  # mj_resetData zeroes xfrc_applied; the wrapper re-applies it, model edits stay
    assert env.unwrapped.data.xfrc_applied[torso, 0] == pytest.approx(total)
    np.testing.assert_allclose(env.unwrapped.model.body_mass[1:], 1.5 * pristine["body_mass"][1:])
    env.close()
    after = _model_arrays(env)
    for key in ("body_mass", "body_inertia", "geom_friction", "gravity"):
        np.testing.assert_array_equal(after[key], pristine[key], err_msg=key)
    assert not after["xfrc_applied"].any()


def test_pendulum_masses_change_only_their_body():
    pristine = _pristine("InvertedDoublePendulum-v5")
    env = SystematicShift(gym.make("InvertedDoublePendulum-v5"), {"pole2_mass": 2.0, "cart_mass": 0.5})
    env.reset(seed=0)
    m = env.unwrapped.model
    ids = {n: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in ("cart", "pole", "pole2")}
    assert m.body_mass[ids["pole2"]] == pytest.approx(2.0 * pristine["body_mass"][ids["pole2"]])
    assert m.body_mass[ids["cart"]] == pytest.approx(0.5 * pristine["body_mass"][ids["cart"]])
    assert m.body_mass[ids["pole"]] == pristine["body_mass"][ids["pole"]]
    env.close()
    np.testing.assert_array_equal(m.body_mass, pristine["body_mass"])


def test_wind_changes_trajectory_and_gravity_changes_dynamics():
    base = _rollout(gym.make("Hopper-v5"), 30, seed=0)
    windy = _rollout(SystematicShift(gym.make("Hopper-v5"), {"wind": 2.0}), 30, seed=0)
    np.testing.assert_array_equal(base[0], windy[0])
    assert np.abs(base - windy).max() > 1e-2
    # +x wind accelerates the torso forward: x-velocity (obs index 5) larger than without wind
    assert windy[1:, 5].mean() > base[1:, 5].mean()
    light = _rollout(SystematicShift(gym.make("Hopper-v5"), {"gravity": 0.5}), 30, seed=0)
    assert np.abs(base - light).max() > 1e-2


def test_missing_body_name_is_caught():
    env = gym.make("Hopper-v5")
    assert mujoco.mj_name2id(env.unwrapped.model, mujoco.mjtObj.mjOBJ_BODY, "cart") == -1
    with pytest.raises(ValueError, match="not in the MuJoCo model.*torso"):
        BodyMass("cart_mass", bodies=("cart",)).bind(env)
    with pytest.raises(ValueError, match="not in the MuJoCo model"):
        WindForce("wind", body="nope").bind(env)


def test_nested_factor_wrappers_share_defaults():
    pristine = _pristine("Hopper-v5")
    env = EnvironmentNoise(SystematicShift(gym.make("Hopper-v5"), {"body_mass": 1.5}), 0.3, ["friction"])
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.zeros(3))
    np.testing.assert_allclose(env.unwrapped.model.body_mass[1:], 1.5 * pristine["body_mass"][1:])
    assert not np.allclose(env.unwrapped.model.geom_friction[:, 0], pristine["geom_friction"][:, 0])
    env.close()
    np.testing.assert_array_equal(env.unwrapped.model.body_mass, pristine["body_mass"])
    np.testing.assert_array_equal(env.unwrapped.model.geom_friction, pristine["geom_friction"])


# --- environment noise vs domain shift ------------------------------------------------------------------


def test_environment_noise_resamples_every_step_with_sigma():
    sigma = 0.2
    env = EnvironmentNoise(gym.make("Walker2d-v5"), sigma)
    _, info = env.reset(seed=0)
    assert info["factors"] == {"body_mass": 1.0, "wind": 0.0, "friction": 1.0, "gravity": 1.0}
    pristine = _pristine("Walker2d-v5")
    vals, grav = [], []
    for _ in range(400):
        _, _, term, trunc, info = env.step(np.zeros(6))
        vals.append([info["factors"][k] for k in ("body_mass", "wind", "friction", "gravity")])
        grav.append(env.unwrapped.model.opt.gravity[2] / pristine["gravity"][2])
        if term or trunc:
            env.reset()
    v = np.array(vals)
    assert np.all(np.diff(v, axis=0) != 0)  # every factor changes at every step
    np.testing.assert_allclose(v[:, 3], grav)  # info reports what the model holds
    rel = v[:, [0, 2, 3]]
    assert abs(rel.mean() - 1.0) < 0.03 and abs(rel.std() - sigma) < 0.02
    assert abs(v[:, 1].std() / WIND_SCALE - sigma) < 0.03
    env.close()


def test_environment_noise_zero_sigma_is_identity():
    clean = _rollout(gym.make("Hopper-v5"), 60, seed=2)
    noisy = _rollout(EnvironmentNoise(gym.make("Hopper-v5"), 0.0), 60, seed=2)
    np.testing.assert_array_equal(clean, noisy)


def test_ratios_are_clipped_positive():
    env = EnvironmentNoise(gym.make("HalfCheetah-v5"), 5.0)
    env.reset(seed=0)
    low = []
    for _ in range(50):
        _, _, _, _, info = env.step(np.zeros(6))
        low.append(min(info["factors"].values()))
        assert env.unwrapped.model.body_mass[1:].min() > 0
    assert min(low) == MIN_RATIO


def test_domain_shift_once_per_episode():
    env = DomainShift(gym.make("Hopper-v5", max_episode_steps=20), 0.3)
    per_episode = []
    for ep in range(4):
        _, info = env.reset(seed=ep if ep == 0 else None)
        first = info["factors"]
        mass = env.unwrapped.model.body_mass.copy()
        done = False
        while not done:
            _, _, term, trunc, info = env.step(np.zeros(3))
            assert info["factors"] == first
            np.testing.assert_array_equal(env.unwrapped.model.body_mass, mass)
            done = term or trunc
        per_episode.append(tuple(first.values()))
    assert len(set(per_episode)) == 4


def test_wind_wrapper_uniform_once_per_episode():
    env = Wind(gym.make("Walker2d-v5", max_episode_steps=5), -2.5, 2.5)
    xis = []
    torso = mujoco.mj_name2id(env.unwrapped.model, mujoco.mjtObj.mjOBJ_BODY, "torso")
    total = env.unwrapped.model.body_mass.sum()
    for ep in range(200):
        _, info = env.reset(seed=0 if ep == 0 else None)
        xi = info["factors"]["wind"]
        assert env.unwrapped.data.xfrc_applied[torso, 0] == pytest.approx(xi * total)
        _, _, _, _, info = env.step(np.zeros(6))
        assert info["factors"]["wind"] == xi
        xis.append(xi)
    xis = np.array(xis)
    assert xis.min() >= -2.5 and xis.max() <= 2.5
    assert abs(xis.std() - 5.0 / np.sqrt(12)) < 0.2
    with pytest.raises(ValueError, match="wind"):
        Wind(gym.make("HalfCheetah-v5"), -1, 1)
    with pytest.raises(ValueError, match="low must be <= high"):
        Wind(gym.make("Hopper-v5"), 1, -1)


# --- seeding --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("perturbation", PERTURBATIONS)
def test_same_seed_same_trajectory(perturbation):
    a = _rollout(make_env("Hopper", perturbation, 0.2), 80, seed=7)
    b = _rollout(make_env("Hopper", perturbation, 0.2), 80, seed=7)
    np.testing.assert_array_equal(a, b)
    if perturbation != "none":
        c = _rollout(make_env("Hopper", perturbation, 0.2), 80, seed=8)
        assert a.shape != c.shape or not np.array_equal(a, c)


def test_noise_draws_leave_initial_states_alone():
    """Wrappers own their generator, so every σ starts episodes from the same states (common random numbers)."""
    starts = {}
    for p in ("none", "act", "env", "dom"):
        env = make_env("Hopper", p, 0.5, max_episode_steps=10)
        env.reset(seed=11)
        for _ in range(10):
            env.step(np.zeros(3))
        starts[p] = env.reset()[0]  # second episode, unseeded reset
    for p in ("act", "env", "dom"):
        np.testing.assert_array_equal(starts[p], starts["none"])


# --- argument checks ------------------------------------------------------------------------------------


def test_bad_arguments_raise_clear_errors():
    with pytest.raises(ValueError, match="'obs'"):
        make_env("Hopper", "noise", 0.1)
    with pytest.raises(ValueError, match=">= 0"):
        make_env("Hopper", "obs", -0.1)
    for cls in (ObservationNoise, ActionNoise, EnvironmentNoise, DomainShift):
        with pytest.raises(ValueError, match=">= 0"):
            cls(gym.make("Hopper-v5"), -1.0)
    with pytest.raises(ValueError, match="'body_mass'"):
        make_env("Hopper", "env", 0.1, factors=["mass"])
    with pytest.raises(ValueError, match="'cart_mass'"):
        EnvironmentNoise(gym.make("InvertedPendulum-v5"), 0.1, ["wind"])
    with pytest.raises(ValueError, match="only apply"):
        make_env("Hopper", "obs", 0.1, factors=["wind"])
    with pytest.raises(ValueError, match="> 0"):
        SystematicShift(gym.make("Hopper-v5"), {"body_mass": 0.0})
    with pytest.raises(ValueError, match="'gravity'"):
        SystematicShift(gym.make("HalfCheetah-v5"), {"wind": 1.0})
    with pytest.raises(ValueError, match="non-empty"):
        SystematicShift(gym.make("Hopper-v5"), {})
    with pytest.raises(ValueError, match="'body_mass' is set by both 'ratios' and 'dom'"):
        make_env("Hopper", "dom", 0.1, ratios={"body_mass": 1.2})
    with pytest.raises(ValueError, match="'wind' is set by both 'wind' and 'env'"):
        make_env("Hopper", "env", 0.1, wind=(-1.0, 1.0))
    with pytest.raises(ValueError, match="low, high"):
        make_env("Hopper", wind=1.0)
    with pytest.raises(ValueError, match="max_episode_steps"):
        make_env("Hopper", max_episode_steps=0)
    with pytest.raises(ValueError, match="seed"):
        make_env("Hopper", seed=-1)


def test_make_env_options():
    env = make_env("Hopper-v5", "env", 0.2, factors=["wind"], ratios={"body_mass": 1.2}, max_episode_steps=4)
    _, info = env.reset(seed=0)
    assert set(info["factors"]) == {"wind"}
    steps = 0
    done = False
    while not done:
        _, _, term, trunc, info = env.step(np.zeros(3))
        steps += 1
        done = term or trunc
    assert steps == 4 and trunc
    pristine = _pristine("Hopper-v5")
    np.testing.assert_allclose(env.unwrapped.model.body_mass[1:], 1.2 * pristine["body_mass"][1:])
    env.close()
    np.testing.assert_array_equal(env.unwrapped.model.body_mass, pristine["body_mass"])


def test_wrap_env_and_chapter4_options():
    raw = gym.make("Hopper-v5")
    assert wrap_env(raw) is raw
    assert isinstance(wrap_env(raw, "dom", 0.1, ["wind"]), DomainShift)
    env = make_env("Walker2d", "obs", 0.1, wind=(0.5, 0.5), env_kwargs={"ctrl_cost_weight": 1.0}, seed=0)
    assert env.unwrapped._ctrl_cost_weight == 1.0
    _, info = env.env.reset(seed=1)  # the Wind wrapper sits under the observation noise
    assert info["factors"] == {"wind": 0.5}


def test_domain_shift_statistics_match_sigma():
    sigma = 0.25
    env = DomainShift(gym.make("Walker2d-v5"), sigma)
    draws = []
    for ep in range(400):
        _, info = env.reset(seed=5 if ep == 0 else None)
        draws.append([info["factors"][k] for k in ("body_mass", "wind", "friction", "gravity")])
    d = np.array(draws)
    rel = d[:, [0, 2, 3]]
    assert abs(rel.mean() - 1.0) < 0.03 and abs(rel.std() - sigma) < 0.02
    assert abs(d[:, 1].mean()) < 0.1 * WIND_SCALE * sigma * 3 and abs(d[:, 1].std() / WIND_SCALE - sigma) < 0.03
    assert abs(np.corrcoef(d.T)[np.triu_indices(4, 1)]).max() < 0.2  # one independent ε per factor
