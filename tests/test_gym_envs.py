"""The perturbation environments as Gymnasium citizens: Gymnasium's full ``check_env`` on every wrapper
and every registered id, recreation from ``env.spec``, factor wrappers on any MuJoCo env, one-line errors, quiet."""

from __future__ import annotations

import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from thesis_repro.envs import (
    CONTEXT_IDS,
    ENV_IDS,
    ENVS,
    TESTS,
    ActionNoise,
    DomainShift,
    EnvironmentNoise,
    ObservationNoise,
    SystematicShift,
    Wind,
    env_id,
    make_env,
)

#: What check_env says about the tasks themselves (advice, not failures): a wrapper is applied, MuJoCo's observation
#: spaces are unbounded, InvertedPendulum's actions span [-3, 3].
EXPECTED = ("is different from the unwrapped version", "observation space m", "symmetric and normalized space")


def full_check(env: gym.Env, render: bool = True) -> None:
    """Gymnasium's check_env with nothing skipped (``render=False``: all but its render check, which opens MuJoCo's
    offscreen renderer three times, 1.5 s); any warning beyond :data:`EXPECTED` fails."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env, skip_render_check=not render)
    other = [str(w.message) for w in caught if not any(e in str(w.message) for e in EXPECTED)]
    assert not other, other


def test_ids_cover_five_tasks_times_four_tests():
    assert len(ENV_IDS) == len(set(ENV_IDS)) == 20
    assert set(ENV_IDS) <= set(gym.registry)
    assert env_id("Hopper", "obs") == "thesis_repro/Hopper-obs-v0"
    assert TESTS == ("obs", "act", "env", "dom")
    with pytest.raises(ValueError, match="valid test types are: 'obs'"):
        env_id("Hopper", "wind")


#: The ids whose check renders: every task once and every test type once (a diagonal of the task x test grid). A
#: wrapper's render only hands on to its task's, so the other ids skip the render check and nothing goes unrendered.
RENDERED = {env_id(task, TESTS[i % len(TESTS)]) for i, task in enumerate(ENVS)}


def test_the_rendered_ids_cover_every_task_and_every_test_type():
    assert {i.split("/")[1].split("-")[0] for i in RENDERED} == set(ENVS)
    assert {i.split("-")[1] for i in RENDERED} == set(TESTS)


@pytest.mark.parametrize("name", ENV_IDS)
def test_every_registered_id_passes_the_full_env_checker(name):
    env = gym.make(name, sigma=0.2, seed=0)
    full_check(env, render=name in RENDERED)
    env.close()


@pytest.mark.parametrize(
    ("name", "kwargs", "factors"),
    [
        ("thesis_repro/Hopper-wind-v0", {"wind": (-2.0, 2.0)}, ["wind"]),
        ("thesis_repro/Walker2d-wind-v0", {}, ["wind"]),  # chapter 4's Fig 4.1 (a) range by default
        ("thesis_repro/Walker2d-fixed-v0", {"ratios": {"friction": 0.5, "wind": 1.0}}, ["friction", "wind"]),
        ("thesis_repro/HalfCheetah-fixed-v0", {"ratios": {"body_mass": 1.2}, "c_a": 0.1}, ["body_mass"]),
    ],
)
def test_context_ids_pass_the_full_env_checker(name, kwargs, factors):
    """Wind and fixed-factor tasks as registered ids (as CARL registers contexts)."""
    assert name in CONTEXT_IDS and name in gym.registry
    env = gym.make(name, seed=0, **kwargs)
    full_check(env)
    got = env.reset(seed=1)[1]["factors"]
    assert sorted(got) == sorted(factors)
    if "ratios" in kwargs:
        assert got == kwargs["ratios"]
    low, high = kwargs.get("wind", (-0.5, 0.5))
    assert "wind" not in got or "ratios" in kwargs or low <= got["wind"] <= high
    env.close()


def test_context_ids_bad_input_is_one_line():
    assert len(CONTEXT_IDS) == 7  # wind on Walker2d and Hopper, fixed factors on all five tasks
    with pytest.raises(ValueError, match="^the wind ids take wind=\\(low, high\\); fixed factor values go to"):
        gym.make("thesis_repro/Hopper-wind-v0", ratios={"body_mass": 1.5})
    with pytest.raises(ValueError, match="valid factors of InvertedPendulum are: .cart_mass., .pole_mass.$"):
        gym.make("thesis_repro/InvertedPendulum-fixed-v0", ratios={"wind": 1.0})


@pytest.mark.parametrize(
    "build",
    [
        lambda: SystematicShift(make_env("Hopper"), {"body_mass": 1.2, "wind": -1.0}),
        lambda: Wind(make_env("Walker2d"), -0.5, 0.5),
        lambda: DomainShift(gym.make("Ant-v5"), 0.2),  # a MuJoCo env outside the five tasks
    ],
    ids=["SystematicShift", "Wind", "DomainShift-Ant"],
)
def test_the_other_wrappers_pass_the_full_env_checker(build):
    full_check(build())


@pytest.mark.parametrize("task", list(ENVS))
def test_make_env_of_every_task_recreates_from_its_spec(task):
    """check_env's close check recreates the env from ``env.spec``: the same wrappers and arguments, the same
    transitions (every wrapper records its constructor arguments)."""
    for i, test in enumerate(TESTS):
        env = make_env(task, test, 0.3, factors=None, max_episode_steps=20)
        again = env.spec.make()
        assert [type(w).__name__ for w in _chain(again)] == [type(w).__name__ for w in _chain(env)]
        a, b = _steps(env, seed=i), _steps(again, seed=i)
        np.testing.assert_array_equal(a, b)


def _chain(env: gym.Env) -> list[gym.Env]:
    out = [env]
    while hasattr(out[-1], "env"):
        out.append(out[-1].env)
    return out


def _steps(env: gym.Env, seed: int, n: int = 5) -> np.ndarray:
    obs, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    rows = [obs]
    for _ in range(n):
        obs, *_ = env.step(env.action_space.sample())
        rows.append(obs)
    return np.array(rows)


def test_registered_id_is_make_env_with_sigma_and_seed():
    """gymnasium.make(id, sigma=, seed=) gives make_env's transitions (same wrappers, same random streams)."""
    ours = make_env("Hopper", "dom", 0.3, seed=3)
    theirs = gym.make("thesis_repro/Hopper-dom-v0", sigma=0.3, seed=3)
    np.testing.assert_array_equal(_steps(ours, seed=5), _steps(theirs, seed=5))
    assert theirs.spec.kwargs["sigma"] == 0.3 and theirs.spec.kwargs["seed"] == 3


@pytest.mark.parametrize("cls", [ObservationNoise, ActionNoise, EnvironmentNoise, DomainShift])
def test_recorded_arguments_are_the_validated_ones(cls):
    env = cls(make_env("Hopper"), 0.25)
    assert env._saved_kwargs["sigma"] == 0.25
    assert env.spec.additional_wrappers[-1].name == cls.__name__


def test_factor_wrappers_work_on_any_mujoco_env_with_the_bodies_they_scale():
    env = DomainShift(gym.make("Ant-v5"), 0.3)
    _, info = env.reset(seed=0)
    assert sorted(info["factors"]) == ["body_mass", "friction", "gravity"]
    env = EnvironmentNoise(gym.make("Swimmer-v5"), 0.3, ["body_mass", "wind"])  # Swimmer has a torso
    env.reset(seed=0)
    assert sorted(env.step(env.action_space.sample())[-1]["factors"]) == ["body_mass", "wind"]


@pytest.mark.parametrize(
    ("build", "expected"),
    [
        (lambda: DomainShift(gym.make("Pendulum-v1"), 0.2), "DomainShift needs a MuJoCo env"),
        (lambda: EnvironmentNoise(gym.make("CartPole-v1"), 0.2), "but CartPole-v1 is not one"),
        (lambda: Wind(gym.make("Reacher-v5"), -1, 1), "factor 'wind' needs body 'torso', which the MuJoCo model"),
        (lambda: DomainShift(gym.make("Ant-v5"), 0.2, ["pole2_mass"]), "needs body 'pole2'"),
        (lambda: DomainShift(gym.make("Ant-v5"), 0.2, ["mass"]), "valid factors are: "),
        (lambda: DomainShift(make_env("HalfCheetah"), 0.2, ["wind"]), "valid factors of HalfCheetah are"),
        (lambda: ObservationNoise("Hopper-v5", 0.1), "ObservationNoise wraps a gymnasium.Env, got str"),
        (lambda: ObservationNoise(make_env("Hopper"), -1), "observation noise sigma must be"),
        (lambda: Wind(make_env("Hopper"), 1.0, -1.0), "wind low must be <= high"),
        (lambda: SystematicShift(make_env("Hopper"), {}), "ratios must be a non-empty dict"),
        (lambda: DomainShift(make_env("Hopper"), 0.2, 3), "factors must be factor names or None"),
        (lambda: gym.make("thesis_repro/Hopper-obs-v0", sigma=-0.1), "must be a finite number >= 0"),
    ],
)
def test_bad_wrapper_input_is_one_line_naming_what_is_missing(build, expected):
    with pytest.raises(ValueError) as err:
        build()
    assert expected in str(err.value)
    assert "\n" not in str(err.value)


def test_no_mujoco_warning_reaches_the_user(tmp_path):
    """Building and stepping every registered id (HalfCheetah and Walker2d included) prints nothing."""
    code = (
        "import gymnasium as gym\n"
        "import thesis_repro.envs\n"
        "for name in thesis_repro.envs.ENV_IDS:\n"
        "    env = gym.make(name, sigma=0.1, seed=0)\n"
        "    env.reset()\n"
        "    env.step(env.action_space.sample())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, check=True)
    assert out.stdout + out.stderr == ""
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()
