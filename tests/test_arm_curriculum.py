"""Fig 5.6's curriculum stage as the thesis describes it: constructive MTL from scratch, then
Algorithm 5's alternation of s and L (σ0 = 0.01, §5.3.2) on every family learned from a pre-trained one."""

from __future__ import annotations

import numpy as np
import pytest

from thesis_repro.arm import curriculum, learn, sample_tasks, transfer


@pytest.fixture
def spy(monkeypatch):
    """Record every CMA-ES run: (x0 shape, sigma0, generations, x0, final x)."""
    calls = []
    real = learn.cma_lockstep

    def wrapped(evaluate, x0, sigma0, generations, **kw):
        res = real(evaluate, x0, sigma0, generations, **kw)
        calls.append({"shape": np.shape(x0), "sigma": sigma0, "gens": generations, "x0": np.array(x0), "x": res.x})
        return res

    monkeypatch.setattr(learn, "cma_lockstep", wrapped)
    return calls


def _model(P=3, D=8, K=2, seed=0):
    rng = np.random.default_rng(seed)
    W = np.tile(np.r_[np.zeros((D - 2, 2)), np.ones((2, 2))], (P, 1, 1)) + 0.05 * rng.normal(size=(P, D, 2))
    return transfer.hosvd(np.moveaxis(W, 0, 2), (4, 2, K))


def test_mtl_alternate_updates_s_then_L_each_phase_alone(spy):
    P, K = 3, 2
    t = _model(P=P, K=K)
    tasks = sample_tasks("reach", P, np.random.default_rng(1))
    s0 = t.factors[2] + 0.1
    res = learn.mtl_alternate("reach", tasks, t, s0, generations=7, phase_generations=3, popsize=5, seed=0)
    assert res.phases == ["s"] * 3 + ["L"] * 3 + ["s"]  # s first (Alg 5), the last phase truncated to the budget
    assert res.curve.shape == res.success.shape == (7,)
    n_theta = t.core.size + t.factors[0].size + t.factors[1].size
    # s-phase: one CMA-ES per task on its s_p (P, K); L-phase: one CMA-ES on L's factors (G, U1, U2) only
    assert [c["shape"] for c in spy] == [(P, K), (1, n_theta), (P, K)]
    assert [c["gens"] for c in spy] == [3, 3, 1]
    assert all(c["sigma"] == 0.01 for c in spy)  # σ0 of §5.3.2, every phase a fresh CMA-ES
    theta0 = np.concatenate([t.core.ravel(), t.factors[0].ravel(), t.factors[1].ravel()])
    np.testing.assert_array_equal(spy[0]["x0"], s0)  # phase 1 moves s from s0 ...
    np.testing.assert_array_equal(spy[1]["x0"][0], theta0)  # ... while L is untouched,
    np.testing.assert_array_equal(spy[2]["x0"], spy[0]["x"])  # phase 2 moves L while s is untouched
    np.testing.assert_array_equal(res.factors[2], spy[2]["x"])
    G, U1, U2 = learn._unpack(spy[1]["x"][0], [t.core.shape, t.factors[0].shape, t.factors[1].shape])
    np.testing.assert_allclose(res.W, np.einsum("ijk,di,aj,pk->pda", G, U1, U2, res.factors[2]))


def test_mtl_alternate_one_phase_leaves_L_as_extracted(spy):
    t = _model()
    tasks = sample_tasks("throw", 3, np.random.default_rng(2))
    res = learn.mtl_alternate("throw", tasks, t, t.factors[2], generations=2, phase_generations=5, popsize=4)
    assert res.phases == ["s", "s"]
    np.testing.assert_array_equal(res.core, t.core)  # L = G x1 U1 x2 U2 extracted and kept (fix L, update s)
    np.testing.assert_array_equal(res.factors[0], t.factors[0])
    np.testing.assert_array_equal(res.factors[1], t.factors[1])
    assert not np.array_equal(res.factors[2], t.factors[2])
    with pytest.raises(ValueError, match="s0 must have shape"):
        learn.mtl_alternate("throw", tasks, t, t.factors[2][:2], generations=2, phase_generations=1)


def test_curriculum_defaults_are_the_thesis_procedure():
    d = curriculum.CURRICULUM_DEFAULTS
    assert d["sigma"] == 0.01 and d["transfer"] == "alternate" and d["phase_generations"] >= 1
    assert curriculum.TRANSFERS == ("alternate", "joint")


@pytest.mark.parametrize("condition", curriculum.CONDITIONS)
def test_curriculum_job_alternates_after_the_scratch_stage(spy, condition):
    P, pop = 2, 4
    cfg = {"n_tasks": P, "pretrain_trials": 32, "bic_trials": 24, "popsize": pop, "ranks": [4, 2, 2], "seed": 0}
    cfg["phase_generations"] = 2
    out = curriculum.curriculum_job({**cfg, "condition": condition})
    D, K = 12, 2
    n_all = 4 * 2 * K + D * 4 + 2 * 2 + P * K  # G, U1, U2, U3: constructive MTL from scratch
    n_theta = n_all - P * K  # L's factors only
    shapes = [c["shape"] for c in spy]
    assert shapes[0] == (1, n_all)  # Reach (CL) or BIC pre-training (NC) from scratch: joint on all factors
    if condition == "CL":  # Throw (4 gens) then BIC (6 gens): alternation s, L, s, L, ...
        assert shapes[1:] == [(P, K), (1, n_theta)] + [(P, K), (1, n_theta), (P, K)]
    else:  # BIC after its own pre-training (8 gens): alternation, 6 gens
        assert shapes[1:] == [(P, K), (1, n_theta), (P, K)]
    assert all(c["sigma"] == 0.01 for c in spy)
    assert out["phases"].tolist() == ["s", "s", "L", "L", "s", "s"]
    assert out["curve"].shape == (6,) and out["trials"].tolist() == [4, 8, 12, 16, 20, 24]


def test_curriculum_joint_is_the_old_procedure(spy):
    cfg = {"n_tasks": 2, "pretrain_trials": 16, "bic_trials": 8, "popsize": 4, "ranks": [4, 2, 2], "seed": 0}
    out = curriculum.curriculum_job({**cfg, "condition": "CL", "transfer": "joint", "sigma": 0.05})
    assert [c["shape"] for c in spy] == [(1, 16 + 48 + 4 + 4)] * 3 and all(c["sigma"] == 0.05 for c in spy)
    assert "phases" not in out
    with pytest.raises(ValueError, match="'alternate', 'joint'"):
        curriculum.curriculum_job({**cfg, "condition": "CL", "transfer": "both"})
