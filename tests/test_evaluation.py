"""Chapter-3 evaluation protocol: Eq. 3.6 AUC, metrics, batched evaluator, cached jobs, score_model."""

from __future__ import annotations

import types
from pathlib import Path

import numpy as np
import pytest

from thesis_repro import evaluation as ev
from thesis_repro.core import job_kinds
from thesis_repro.core.cache import Job, RunCache
from thesis_repro.envs import make_env
from thesis_repro.evaluation import jobs as jobs_mod

#: one `make test` process runs this module (its module-scoped fixture is set up once)
pytestmark = pytest.mark.xdist_group("evaluation")

W = np.random.default_rng(0).normal(0.0, 0.3, size=(3, 11))


def linear(obs: np.ndarray) -> np.ndarray:
    """Deterministic linear-tanh policy computed row by row (bit-identical for any batch size)."""
    return np.tanh((obs[:, None, :] * W[None]).sum(axis=-1))


def falling(obs: np.ndarray) -> np.ndarray:
    return np.tile([1.0, -1.0, 1.0], (len(obs), 1))


def sequential(policy, env, perturbation, sigmas, n_rollouts, seed, max_steps):
    """The plain reference loop: one env, one episode at a time, batch-of-one policy calls."""
    returns = np.zeros((len(sigmas), n_rollouts))
    lengths = np.zeros((len(sigmas), n_rollouts), dtype=int)
    for c, s in enumerate(sigmas):
        for r, ts in enumerate(ev.test_seeds(seed, n_rollouts)):
            e = make_env(env, perturbation, s, max_episode_steps=max_steps)
            obs, _ = e.reset(seed=ts)
            done = False
            while not done:
                a = np.clip(policy(np.asarray(obs, dtype=np.float64)[None])[0], -1.0, 1.0)
                obs, rew, term, trunc, _ = e.step(a)
                returns[c, r] += rew
                lengths[c, r] += 1
                done = term or trunc or lengths[c, r] >= max_steps
            e.close()
    return returns, lengths


# --- metrics ---------------------------------------------------------------------------------------


def test_auc_matches_hand_computation():
    assert ev.auc([100.0, 80.0, 40.0], [0.0, 0.2, 0.4]) == pytest.approx(0.2 * 220)
    grid = np.array([[100.0, 80.0, 40.0], [10.0, 20.0, 30.0]])
    np.testing.assert_allclose(ev.auc(grid, [0.0, 0.2, 0.4]), [44.0, 12.0])
    np.testing.assert_allclose(ev.auc(grid.T, [0.0, 0.2, 0.4], axis=0), [44.0, 12.0])
    # linearity: AUC of the expected curve == mean of the per-rollout AUCs
    R = np.random.default_rng(1).normal(size=(4, 5, 7))
    s = np.linspace(0.1, 0.7, 7)
    np.testing.assert_allclose(ev.auc(R.mean(axis=1), s), ev.auc(R, s).mean(axis=1))


@pytest.mark.parametrize(
    "sigmas", [[0.0, 0.1, 0.3], [0.0], [], [0.2, 0.1, 0.0], [0.0, 0.0, 0.0], [-0.1, 0.0, 0.1], [[0.0, 0.1]]]
)
def test_auc_rejects_bad_grids(sigmas):
    with pytest.raises(ValueError):
        ev.auc(np.ones(max(len(sigmas), 1)), sigmas)


def test_auc_needs_one_return_per_sigma():
    with pytest.raises(ValueError, match="one entry per sigma"):
        ev.auc([1.0, 2.0], [0.0, 0.1, 0.2])


def test_expected_return_is_mean_over_rollouts():
    R = np.arange(12.0).reshape(2, 2, 3)
    np.testing.assert_allclose(ev.expected_return(R), R.mean(axis=-1))
    assert ev.expected_return([1.0, 2.0, 6.0]) == 3.0
    with pytest.raises(ValueError):
        ev.expected_return([])


def test_pareto_frontier_on_hand_made_points():
    train = [1.0, 2.0, 3.0, 2.5, 0.5, 3.0]
    test = [5.0, 4.0, 1.0, 2.0, 5.0, 0.5]
    # (0.5,5) dominated by (1,5); (3,0.5) by (3,1); the rest trade off
    assert ev.pareto_frontier(train, test).tolist() == [0, 1, 3, 2]
    assert ev.pareto_frontier([1.0, 1.0], [2.0, 2.0]).tolist() == [0, 1]  # ties dominate nobody
    assert ev.pareto_frontier([3.0], [1.0]).tolist() == [0]
    with pytest.raises(ValueError):
        ev.pareto_frontier([1.0, 2.0], [1.0])


def test_correlation_sign_on_constructed_data():
    rng = np.random.default_rng(3)
    x = rng.normal(size=30)
    r_neg, p_neg = ev.correlation(x, -2.0 * x + 0.1 * rng.normal(size=30))
    r_pos, _ = ev.correlation(x, 3.0 * x + 0.1 * rng.normal(size=30))
    assert r_neg < -0.95 and p_neg < 1e-6 and r_pos > 0.95
    with pytest.raises(ValueError):
        ev.correlation([1.0, 2.0], [2.0, 1.0])
    with pytest.raises(ValueError):
        ev.correlation([1.0, 2.0, 3.0], [1.0, 1.0, 1.0])


# --- testing seeds ----------------------------------------------------------------------------------


def test_testing_seeds_are_fixed_distinct_and_never_training_seeds():
    s = ev.test_seeds(0, 20)
    assert s == ev.test_seeds(0, 20) and s[:5] == ev.test_seeds(0, 5)
    assert len(set(s)) == 20
    assert not set(s) & set(range(100_000))  # training seeds are small integers
    assert min(s) >= 2**32
    assert not set(s) & set(ev.test_seeds(1, 20))
    with pytest.raises(ValueError):
        ev.test_seeds(0, 0)
    with pytest.raises(ValueError):
        ev.test_seeds(-1, 3)


# --- batched evaluator ------------------------------------------------------------------------------


@pytest.mark.parametrize("perturbation", ["obs", "act", "dom"])
def test_batched_equals_sequential_loop(perturbation):
    sigmas, n, steps = [0.0, 0.3], 3, 40
    out = ev.evaluate(
        linear, "Hopper", perturbation, sigmas, n, seed=7, max_episode_steps=steps, n_envs=4, return_lengths=True
    )
    ref_r, ref_l = sequential(linear, "Hopper", perturbation, sigmas, n, 7, steps)
    np.testing.assert_array_equal(out.returns, ref_r)
    np.testing.assert_array_equal(out.lengths, ref_l)
    assert out.returns.shape == (2, 3)
    # noise actually acts (σ > 0 differs from σ = 0), and the result does not depend on n_envs
    assert not np.array_equal(out.returns[0], out.returns[1])
    one = ev.evaluate(linear, "Hopper", perturbation, sigmas, n, seed=7, max_episode_steps=steps, n_envs=1)
    np.testing.assert_array_equal(one, out.returns)


def test_at_sigma_zero_every_test_is_the_nominal_env():
    """Table 3.3(b)'s σ_te = 0 rows: Obs, Act, Env and Dom at σ = 0 run exactly the unperturbed task, so a
    row-wise policy gets bit-identical returns from all four and from ``none``. (The kit's torch policies are
    not row-wise: a batch of 1-2 rows rounds differently from a larger one on some CPUs, so their σ = 0 rows can
    differ by the batch's composition, amplified by the dynamics; see ``BatchedEvaluator``.)"""
    kw = {"seed": 3, "max_episode_steps": 60, "n_envs": 4}
    none = ev.evaluate(linear, "Hopper", "none", [0.0], 4, **kw)
    for perturbation in ("obs", "act", "env", "dom"):
        np.testing.assert_array_equal(ev.evaluate(linear, "Hopper", perturbation, [0.0, 0.5], 4, **kw)[:1], none)


def test_masking_of_early_terminations():
    out = ev.evaluate(falling, "Hopper", "none", [0.0], 3, max_episode_steps=200, n_envs=2, return_lengths=True)
    ref_r, ref_l = sequential(falling, "Hopper", "none", [0.0], 3, 0, 200)
    assert np.all(out.lengths < 200) and np.all(out.lengths > 0)
    np.testing.assert_array_equal(out.lengths, ref_l)
    np.testing.assert_array_equal(out.returns, ref_r)
    # mixing falling and surviving episodes in one batch: each keeps its own length and return
    zero = lambda obs: np.zeros((len(obs), 3))  # noqa: E731  (keeps Hopper up for > 100 steps)
    mixed = ev.BatchedEvaluator(zero, lambda **c: make_env(**c), n_envs=3, max_episode_steps=60)
    conds = [{"env": "Hopper", "perturbation": "act", "sigma": s} for s in (0.0, 2.0)]
    got = mixed.run(conds, ev.test_seeds(0, 2))
    assert got.lengths.shape == (2, 2) and np.all(got.lengths[0] == 60) and np.all(got.lengths[1] < 60)
    ref_r, ref_l = sequential(zero, "Hopper", "act", [0.0, 2.0], 2, 0, 60)
    np.testing.assert_array_equal(got.lengths, ref_l)
    np.testing.assert_array_equal(got.returns, ref_r)


def test_one_policy_forward_per_step():
    calls = []

    def counting(obs):
        calls.append(len(obs))
        return np.zeros((len(obs), 3))

    out = ev.evaluate(counting, "Hopper", "none", [0.0], 8, max_episode_steps=25, n_envs=8, return_lengths=True)
    assert np.all(out.lengths == 25) and calls == [8] * 25


def test_systematic_shift_grid():
    zero = lambda obs: np.zeros((len(obs), 3))  # noqa: E731
    R = ev.evaluate_shift(zero, "Hopper", [{"body_mass": 1.0}, {"body_mass": 1.5}], 2, max_episode_steps=100)
    base = ev.evaluate(zero, "Hopper", "none", [0.0], 2, max_episode_steps=100)
    assert R.shape == (2, 2)
    np.testing.assert_array_equal(R[0], base[0])  # ratio 1 is the training domain
    assert not np.array_equal(R[1], base[0])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"sigmas": [-0.1, 0.0]}, "sigma"),
        ({"perturbation": "wind"}, "valid perturbations"),
        ({"n_rollouts": 0}, "n_rollouts"),
        ({"n_envs": 0}, "n_envs"),
        ({"sigmas": []}, "sigmas"),
        ({"max_episode_steps": 0}, "max_episode_steps"),
    ],
)
def test_bad_arguments_raise(kwargs, match):
    args = {"perturbation": "obs", "sigmas": [0.0, 0.1], "n_rollouts": 2, "n_envs": 2, "max_episode_steps": 5}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        ev.evaluate(linear, "Hopper", args.pop("perturbation"), args.pop("sigmas"), args.pop("n_rollouts"), **args)


def test_policy_with_wrong_batch_raises():
    with pytest.raises(ValueError, match="actions"):
        ev.evaluate(lambda o: np.zeros((1, 3)), "Hopper", "none", [0.0], 4, max_episode_steps=5, n_envs=4)


# --- SB3 scoring ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny_ppo():
    from stable_baselines3 import PPO

    model = PPO("MlpPolicy", "Hopper-v5", n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    return model.learn(128)


def test_sb3_policy_matches_predict(tiny_ppo):
    obs = np.random.default_rng(0).normal(size=(5, 11))
    np.testing.assert_allclose(ev.sb3_policy(tiny_ppo)(obs), tiny_ppo.predict(obs, deterministic=True)[0])
    with pytest.raises(TypeError):
        ev.sb3_policy(object())


def test_sb3_policy_matches_predict_for_squashed_sac():
    from stable_baselines3 import SAC

    sac = SAC("MlpPolicy", "Pendulum-v1", seed=0, device="cpu", learning_starts=0, buffer_size=100)
    obs = np.random.default_rng(1).normal(size=(4, 3))
    got = ev.sb3_policy(sac)(obs)
    np.testing.assert_allclose(got, sac.predict(obs, deterministic=True)[0], rtol=1e-6)
    assert got.shape == (4, 1) and np.all(np.abs(got) <= 2.0)


def test_score_model_shapes_and_auc(tiny_ppo):
    sig = [0.0, 0.2]
    scores = ev.score_model(tiny_ppo, "Hopper", tests=("obs", "dom"), sigmas=sig, n_rollouts=2, max_episode_steps=20)
    assert scores.tests == ["obs", "dom"]
    for r in scores.returns.values():
        assert r.shape == (1, 2, 2)  # (models, sigmas, rollouts)
    area = scores.auc()
    assert area["obs"] == pytest.approx(0.2 * scores.returns["obs"][0].mean(axis=1).sum())
    assert ev.summarise(scores) == area
    with pytest.raises(ValueError, match="valid test types"):
        ev.score_model(tiny_ppo, "Hopper", tests=("noise",), sigmas=sig)
    with pytest.raises(ValueError, match="uniform"):
        ev.score_model(tiny_ppo, "Hopper", sigmas=[0.0, 0.1, 0.5])
    assert len(ev.default_sigmas()) >= 2


# --- cached jobs with a stand-in learner ------------------------------------------------------------


def fake_train_job(config: dict, workdir: Path) -> dict:
    """Stand-in for thesis_repro.learners:train_job: a 'trained' linear policy scaled by the seed."""
    np.save(workdir / "out" / "w.npy", W * (1 + config["seed"]))
    return {"train_return": 100.0 + config["seed"]}


@pytest.fixture
def fake_learners(monkeypatch):
    def load_policy(result, snapshot=None):
        w = np.load(result.out / "w.npy")
        return lambda obs: np.tanh((obs[:, None, :] * w[None]).sum(axis=-1))

    def train_config(algo, env, seed, timesteps, **overrides):
        return {"algo": algo, "env": env, "seed": seed, "timesteps": timesteps, **overrides}

    stub = types.SimpleNamespace(load_policy=load_policy, train_config=train_config)
    monkeypatch.setattr(jobs_mod, "load_policy", load_policy)
    monkeypatch.setattr(jobs_mod, "train_config", train_config)
    monkeypatch.setitem(job_kinds.KINDS, "fake-train", "tests.test_evaluation:fake_train_job")
    monkeypatch.setitem(job_kinds.PATHS, "tests.test_evaluation:fake_train_job", "fake-train")
    monkeypatch.setattr(jobs_mod, "TRAIN_KIND", "fake-train")
    monkeypatch.setenv("THESIS_REPRO_JOBS", "1")
    return stub


def test_evaluate_job_through_the_cache(fake_learners):
    cfg = {
        "train": fake_learners.train_config("PPO", "Hopper", 0, 1000),
        "test": {"perturbation": "obs", "sigmas": [0.0, 0.1], "n_rollouts": 2, "seed": 3, "max_episode_steps": 15},
    }
    res = RunCache().run(Job("thesis_repro.evaluation:evaluate_job", cfg))
    assert res["returns"].shape == (2, 2) and res["train_return"] == 100.0
    direct = ev.evaluate(linear, "Hopper", "obs", [0.0, 0.1], 2, seed=3, max_episode_steps=15)
    np.testing.assert_array_equal(res["returns"], direct)
    assert res["auc"] == pytest.approx(ev.auc(direct.mean(axis=1), [0.0, 0.1]))
    assert RunCache().run(Job("thesis_repro.evaluation:evaluate_job", cfg)).from_cache
    with pytest.raises(ValueError, match="exactly one"):
        ev.check_test({"perturbation": "obs"})


def test_benchmark_jobs_stack_seeds_tasks_algos(fake_learners):
    tests = ["obs", {"name": "mass", "perturbation": "none", "ratios": [{"body_mass": 0.8}, {"body_mass": 1.2}]}]
    bench = ev.benchmark_jobs(
        ["PPO", "PPO-16"], ["Hopper"], [0, 1, 2], 1000, tests, sigmas=[0.0, 0.2], n_rollouts=2, max_episode_steps=10
    )
    assert len(bench.train_jobs) == 6 and len(bench.eval_jobs["obs"]) == 6
    res = bench.run(n_jobs=1, progress=False)
    assert res.returns["obs"].shape == (3, 1, 2, 2, 2)
    assert res.returns["mass"].shape == (3, 1, 2, 2, 2)
    assert res.auc["obs"].shape == (3, 1, 2) and "mass" not in res.auc
    np.testing.assert_array_equal(res.train_return[:, 0, 0], [100.0, 101.0, 102.0])
    assert res.by_algo(res.auc["obs"])["PPO-16"].shape == (3, 1)
    df = res.frame("obs")
    assert len(df) == res.returns["obs"].size and set(df["sigma"]) == {0.0, 0.2}
    row = df[(df.seed == 2) & (df.algo == "PPO-16") & (df.sigma == 0.2) & (df.rollout == 1)]
    assert row["return"].item() == res.returns["obs"][2, 0, 1, 1, 1]
    assert len(res.frame("mass")) == res.returns["mass"].size
    af = res.auc_frame()
    assert len(af) == 6 and af.loc[(af.seed == 1) & (af.algo == "PPO"), "train_return"].item() == 101.0
    with pytest.raises(ValueError, match="sigmas"):
        ev.benchmark_jobs(["PPO"], ["Hopper"], [0], 1000, ["obs"])


def test_evaluate_job_with_the_real_learner():
    from thesis_repro.learners import load_policy, train_config

    tc = train_config("ppo", "Hopper", 0, 256, n_envs=1, n_steps=128, batch_size=64, n_epochs=1)
    test = {"perturbation": "act", "sigmas": [0.0, 0.1], "n_rollouts": 2, "max_episode_steps": 25}
    res = RunCache().run(Job("thesis_repro.evaluation:evaluate_job", {"train": tc, "test": test}))
    policy = load_policy(RunCache().run(Job("thesis_repro.learners:train_job", tc)))
    direct = ev.evaluate(policy, "Hopper", "act", [0.0, 0.1], 2, max_episode_steps=25)
    np.testing.assert_allclose(res["returns"], direct)
    assert res["lengths"].max() <= 25 and res["auc"] == pytest.approx(0.1 * direct.mean(axis=1).sum())


# --- make bench ------------------------------------------------------------------------------------


def test_bench_registry_reports_missing_and_rejects_unknown(monkeypatch, capsys):
    from thesis_repro.core import bench

    monkeypatch.setitem(bench.BENCHMARKS, "ghost", "thesis_repro.no_such_module:bench_ghost")
    assert bench.benchmark_function("ghost") is None
    assert bench.run_benchmarks(["ghost"]) == {}
    assert "MISSING" in capsys.readouterr().out
    with pytest.raises(ValueError, match="valid benchmarks"):
        bench.run_benchmarks(["nope"])
    with pytest.raises(ValueError, match="module:function"):
        bench.register_benchmark("x", "no_colon")


def test_make_bench_lists_and_rejects_an_unknown_benchmark_in_one_line(capsys):
    from thesis_repro.cli.commands import main

    assert main(["bench", "--list"]) == 0
    assert "evaluation     thesis_repro.evaluation.bench:bench_evaluation" in capsys.readouterr().out
    assert main(["bench", "nope"]) == 2
    err = capsys.readouterr().err
    assert (
        err.startswith("error: unknown benchmark 'nope'; valid benchmarks are: 'evaluation'") and err.count("\n") == 1
    )


def test_bench_evaluation_reports_all_rates(capsys):
    from thesis_repro.evaluation.bench import bench_evaluation

    out = bench_evaluation(seconds=0.02, n_envs=2, horizon=10, rounds=1)
    assert {"batched_steps_per_s", "predict_steps_per_s", "raw_steps_per_s", "a_over_b", "a_over_c"} <= set(out)
    assert all(v > 0 for v in out.values())
    assert out["a_over_c"] == pytest.approx(out["batched_steps_per_s"] / out["raw_steps_per_s"])
    assert "a/c" in capsys.readouterr().out


def test_sb3_policy_applies_vecnormalize(tiny_ppo):
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    vn = VecNormalize(DummyVecEnv([lambda: make_env("Hopper")]), norm_reward=False)
    vn.obs_rms.mean = np.linspace(-1.0, 1.0, 11)
    vn.obs_rms.var = np.linspace(0.5, 2.0, 11)
    obs = np.random.default_rng(2).normal(size=(3, 11))
    want = tiny_ppo.predict(vn.normalize_obs(obs), deterministic=True)[0]
    np.testing.assert_allclose(ev.sb3_policy(tiny_ppo, vn)(obs), want)
    assert not np.allclose(ev.sb3_policy(tiny_ppo)(obs), want)
    with pytest.raises(TypeError, match="VecNormalize"):
        ev.sb3_policy(tiny_ppo, vecnormalize=object())


# --- clear errors at the public API -----------------------------------------------------------------


def test_score_model_names_the_task_and_both_shapes_for_a_foreign_model():
    """An InvertedPendulum model scored on Hopper: one line naming the task and the shapes (not torch's error)."""
    from stable_baselines3 import PPO

    pendulum = PPO("MlpPolicy", "InvertedPendulum-v5", n_steps=64, batch_size=32, seed=0, device="cpu")
    with pytest.raises(ValueError) as err:
        ev.score_model(pendulum, "Hopper", tests=("obs",), sigmas=[0.0, 0.1], n_rollouts=1, max_episode_steps=5)
    msg = str(err.value)
    assert "\n" not in msg
    assert "task 'Hopper'" in msg and "observations of shape (4,)" in msg and "actions of shape (1,)" in msg
    assert "observations of shape (11,) and actions of shape (3,)" in msg


def test_evaluate_names_the_task_when_the_policy_fails_on_its_observations():
    import torch

    net = torch.nn.Linear(4, 1)  # an InvertedPendulum-sized policy

    def pendulum_policy(obs):
        return net(torch.as_tensor(obs, dtype=torch.float32).reshape(-1, 4)).detach().numpy()

    with pytest.raises(ValueError, match=r"policy failed on task 'Hopper'.s observations \(batch of shape \(11,\)"):
        ev.evaluate(pendulum_policy, "Hopper", "none", [0.0], 2, max_episode_steps=5, n_envs=2)


def test_evaluate_rejects_actions_of_the_wrong_shape():
    with pytest.raises(ValueError, match=r"task 'Hopper'.*actions of shape \(1,\).*actions of shape \(3,\)"):
        ev.evaluate(lambda o: np.zeros((len(o), 1)), "Hopper", "none", [0.0], 2, max_episode_steps=5, n_envs=2)
    with pytest.raises(ValueError, match=r"task 'InvertedPendulum'.*actions of shape \(\).*actions of shape \(1,\)"):
        ev.evaluate(lambda o: np.zeros(len(o)), "InvertedPendulum", "none", [0.0], 1, max_episode_steps=3)


def _bad_calls():
    from thesis_repro import figures
    from thesis_repro.book import notebooks
    from thesis_repro.core import scales
    from thesis_repro.learners import train_config

    return {
        "figure id": (lambda: notebooks.check_notebook("3.99"), "valid figures are: '3.2'"),
        "figure jobs": (lambda: figures.jobs("3.99", "smoke"), "valid figures are"),
        "scale": (lambda: scales.figure_settings("3.3", "medium"), "valid scales are: 'smoke', 'small', 'full'"),
        "algo": (lambda: train_config("ppo2", "Hopper", 0, 1000), "valid algorithms are: 'ppo'"),
        "env": (lambda: make_env("Hoper"), "valid envs are: 'InvertedPendulum'"),
        "perturbation": (lambda: make_env("Hopper", "wind", 0.1), "valid perturbations are: 'none', 'obs'"),
        "eval perturbation": (lambda: ev.evaluate(linear, "Hopper", "noise", [0.0], 1), "valid perturbations are"),
        "test name": (lambda: ev.score_model(object(), "Hopper", tests=("noise",)), "valid test types are"),
        "eval env": (lambda: ev.evaluate(linear, "Hoper", "obs", [0.0], 1), "valid envs are"),
    }


@pytest.mark.parametrize("case", list(_bad_calls()))
def test_public_entry_points_give_one_line_naming_the_valid_choices(case):
    call, expected = _bad_calls()[case]
    with pytest.raises(ValueError) as err:
        call()
    assert expected in str(err.value)
    assert "\n" not in str(err.value)


def test_cli_reports_bad_input_in_one_line(capsys):
    from thesis_repro.cli.commands import main

    assert main(["figure", "3.99", "--scale", "smoke"]) == 2
    assert main(["figure", "3.3", "--scale", "medium"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0].startswith("error: unknown figure '3.99'; valid figures are: '3.2'")
    assert err[1] == "error: unknown scale 'medium'; valid scales are: 'smoke', 'small', 'full'"


@pytest.mark.parametrize(
    ("var", "value", "expected"),
    [
        ("THESIS_REPRO_RETRAIN", "maybe", "error: RETRAIN / THESIS_REPRO_RETRAIN: unknown value 'maybe'; valid values"),
        ("THESIS_REPRO_BACKEND", "slurm", "error: THESIS_REPRO_BACKEND: unknown backend 'slurm'; valid backends are"),
    ],
)
def test_cli_rejects_bad_make_variables_before_any_notebook_runs(var, value, expected, monkeypatch, capsys):
    # make figure-3.3 RETRAIN=maybe / BACKEND=slurm: one line, exit 2, no kernel started (else a traceback in it)
    from thesis_repro.book import notebooks
    from thesis_repro.cli.commands import main

    monkeypatch.setenv(var, value)
    monkeypatch.setattr(notebooks, "execute_notebook", lambda *a, **k: pytest.fail("a notebook ran"))
    assert main(["figure", "3.3", "--scale", "smoke"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(expected)
