"""Protocol studies (:mod:`thesis_repro.runs.study`): the Reptile-DG outer-step study's learner, configs and jobs.

Alg 2 writes the outer update as "Adam optimiser π ← π + β(π' − π)"; the kit's Table 3.7 runs read it as one
Adam step of lr β on the gradient π − π'. The study compares that with Nichol et al.'s outer step
π ← π + ε_t(π' − π) (``meta_step_size`` ε, annealed as the lr), whose runs must not change any shipped key."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

from thesis_repro.learners import meta, train_config
from thesis_repro.learners import train as lt
from thesis_repro.runs import study

th.set_num_threads(1)

TINY = dict(n_envs=2, n_steps=64, batch_size=32, max_episode_steps=20, n_epochs=2, perturbation="dom", sigma=0.2)


def _model(timesteps: int, **kw):
    cfg = train_config("ppo-reptile-dg", "Hopper", 0, timesteps, protocol="thesis", **{**TINY, **kw})
    return lt.build_model(cfg, lt._wrap(cfg, lt.make_train_venv(cfg), None))


def _flat(model) -> th.Tensor:
    return th.cat([p.detach().flatten() for p in model.policy.parameters()])


@pytest.mark.parametrize("eps", [1.0, 0.25])
def test_the_interpolating_outer_step_moves_pi_by_eps_t_towards_the_adapted_policy(eps):
    """4 iterations of 2 domains x 64 steps in a 512-step run: ε_t = ε x lr(t)/lr(0) with ppo1's linear
    schedule (t = steps before the iteration), i.e. ε x [1, 3/4, 1/2, 1/4], and each outer step lands π at
    π + ε_t(π' − π) exactly."""
    model = _model(512, meta_step_size=eps)
    seen = []
    orig = meta.reptile_interpolate

    def spy(module, adapted, e):
        before = th.cat([p.detach().flatten() for p in module.parameters()]).clone()
        target = th.cat([adapted[n].detach().flatten() for n, _ in module.named_parameters()])
        orig(module, adapted, e)
        seen.append((e, before, target, th.cat([p.detach().flatten() for p in module.parameters()]).clone()))

    meta.reptile_interpolate = spy
    try:
        model.learn(512)
    finally:
        meta.reptile_interpolate = orig
    assert [e for e, *_ in seen] == pytest.approx([eps, 0.75 * eps, 0.5 * eps, 0.25 * eps])
    for e, before, target, after in seen:
        assert th.allclose(after, before + e * (target - before), atol=1e-6)
        assert not th.allclose(after, before)
    assert th.equal(seen[-1][3], _flat(model))


def test_alg2_as_written_keeps_adam_and_the_option_keeps_shipped_keys():
    model = _model(256)
    assert model.meta_step_size is None  # Alg 2: one Adam step (lr beta) on pi - pi'
    base = train_config("ppo-reptile-dg", "Hopper", 0, 1000, protocol="thesis")
    assert "meta_step_size" not in base["sb3"]
    assert train_config("ppo-reptile-dg", "Hopper", 0, 1000, protocol="thesis", meta_step_size=None) == base
    with pytest.raises(ValueError, match="meta_step_size must be a number > 0"):
        train_config("ppo-reptile-dg", "Hopper", 0, 1000, meta_step_size=0.0)
    with pytest.raises(ValueError, match="unknown hyperparameter of 'ppo-maml-dg' 'meta_step_size'"):
        train_config("ppo-maml-dg", "Hopper", 0, 1000, meta_step_size=1.0)


def test_the_alg2_runs_of_the_study_are_table_3_7s_runs():
    from thesis_repro.runs.needs import seed_jobs

    spec = study.SPECS["reptile-outer-step"]
    table = {j.key for j in seed_jobs("table-3.7", "small", seeds=[0, 1, 2]) if j.kind == "train"}
    jobs = study.study_jobs("reptile-outer-step")
    assert len(jobs) == len(spec.envs) * len(spec.seeds) * 2
    alg2 = [j for j in jobs if spec.value(j) is None]
    assert alg2 and {j.key for j in alg2} <= table  # shared: never trained twice
    assert not {j.key for j in jobs if spec.value(j) == 1.0} & table
    # every study's runs are known to the shipped-layer check and to `budgets --spread`
    assert {j.key for j in jobs} <= {j.key for j in study.study_jobs()}


def test_study_effects_read_a_none_setting_and_unknown_names_are_one_line_errors():
    spec = study.SPECS["reptile-outer-step"]
    rows = {
        ("InvertedPendulum", 1.0): np.array([[900.0, 950], [950.0, 990], [1000.0, 1000]]),
        ("InvertedPendulum", None): np.array([[20.0, 30], [25.0, 40], [30.0, 45]]),
        ("InvertedDoublePendulum", None): np.array([[150.0, 200], [160.0, 210]]),  # no eps runs: no effect
    }
    effects = study.schedule_effects(rows, spec)
    assert list(effects) == ["InvertedPendulum"]
    e = effects["InvertedPendulum"]
    assert e.difference == pytest.approx(925.0) and not e.within_spread and e.n == (3, 3)
    with pytest.raises(
        ValueError, match="unknown protocol study 'reptile'; valid: lr-schedule, reptile-outer-step, maml-outer-update"
    ):
        study.sensitivity("reptile")
    with pytest.raises(ValueError, match="unknown protocol study"):
        study.study_jobs("reptile")


def test_the_kit_runs_of_the_maml_study_are_table_3_7s_and_step_is_alg_1_read_literally():
    from thesis_repro.runs.needs import seed_jobs

    spec = study.SPECS["maml-outer-update"]
    table = {j.key for j in seed_jobs("table-3.7", "small", seeds=[0, 1, 2]) if j.kind == "train"}
    jobs = study.study_jobs("maml-outer-update")
    assert len(jobs) == len(spec.seeds) * 2 and {spec.value(j) for j in jobs} == {"step", "ppo"}
    assert {j.key for j in jobs if spec.value(j) == "ppo"} <= table  # the kit's runs: never trained twice
    assert not {j.key for j in jobs if spec.value(j) == "step"} & table
    base = train_config("ppo-maml-dg", "InvertedPendulum", 0, 200_000, protocol="thesis")
    assert base["sb3"]["meta_update"] == "ppo"  # the kit's default reading, which the thesis-protocol runs use


@pytest.mark.parametrize("name", ["reptile-outer-step", "maml-outer-update"])
def test_the_registry_declares_the_meta_learning_studies_on_table_3_7s_claim(name):
    from thesis_repro.claims import registry

    assert {s.id for s in registry.specs() if name in s.sensitivity} == {"3.7-maml-reptile"}


#: The block of each study shown on the book page ``book/learners.md`` (its marker); the page names the command.
STUDY_BLOCKS = {"reptile-outer-step": "reptile-study", "maml-outer-update": "maml-study"}


@pytest.mark.parametrize(("name", "marker"), STUDY_BLOCKS.items())
def test_book_study_block_is_the_summary_of_the_shipped_runs(monkeypatch, name, marker):
    from thesis_repro.core import paths
    from thesis_repro.runs import budgets

    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(paths.ROOT / "data" / "reference"))  # the real shipped layer
    text = (paths.ROOT / "book" / "learners.md").read_text()
    assert f"python -m thesis_repro.runs.study {name} [--summary]" in text
    block = text.split(f"<!-- {marker}:begin -->")[1].split(f"<!-- {marker}:end -->")[0].strip()
    spec = study.SPECS[name]
    expected = study.study_table(spec.jobs(), budgets.shipped_cache(), spec).strip()
    stale = f"book/learners.md {marker} block is stale: paste `python -m thesis_repro.runs.study {name} --summary`"
    assert block == expected, stale
