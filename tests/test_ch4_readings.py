"""Readings of chapter 4's aggregation step (``thesis_repro.mdl.readings``): each trains, keeps its guarantee, and a
bad id is a one-line error; the log-σ argument; the ``stop_at`` run setting and the pilot summary's table."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from thesis_repro.learners import train_config, train_job
from thesis_repro.learners.train import Ppo1Linear
from thesis_repro.mdl import aggregate as agg
from thesis_repro.mdl import exact, readings
from thesis_repro.runs import pilots

SHORT = dict(
    n_envs=2,
    n_steps=128,
    batch_size=64,
    n_epochs=2,
    max_episode_steps=100,
    wind=[-0.5, 0.5],
    net_arch={"pi": [16, 16], "vf": [16, 16]},
)


def problem(dtype: torch.dtype = torch.float32, n: int = 3, scale: float = 0.1):
    """A tiny MLP Gaussian policy, states, θ_old and N sub-policies around it."""
    pol = agg.GaussianPolicy(3, 2, hidden=(5, 4), seed=0, log_std_init=-0.5).to(dtype)
    view = agg.PolicyView(pol)
    states = torch.randn(24, 3, generator=torch.Generator().manual_seed(0), dtype=dtype)
    t0 = view.get_flat()
    gens = [torch.Generator().manual_seed(i + 1) for i in range(n)]
    return view, states, t0, [t0 + scale * torch.randn(t0.shape, generator=g, dtype=dtype) for g in gens]


def log_std_part(view: agg.PolicyView, theta: torch.Tensor) -> torch.Tensor:
    return view.params(theta)["log_std"]


def test_fisher_diagonal_in_closed_form_is_the_dense_fisher_diagonal():
    view, states, _, thetas = problem(torch.float64)
    fp = agg.FisherProducts(view, thetas, states)
    assert fp.closed_form
    dense = torch.stack([torch.diagonal(agg.fisher_matrix(view, t, states)) for t in thetas])
    assert torch.allclose(fp.diagonal(), dense, atol=1e-12, rtol=1e-10)


def test_diagonal_fisher_aggregate_is_a_per_parameter_convex_combination():
    view, states, _, thetas = problem()
    new = readings.kl_diag(view, thetas, states)
    stack = torch.stack(thetas)
    assert ((new >= stack.min(0).values - 1e-6) & (new <= stack.max(0).values + 1e-6)).all()
    same = readings.kl_diag(view, [thetas[0]] * 3, states)
    assert torch.allclose(same, thetas[0], atol=1e-6)


def test_log_std_of_eq_4_11_is_params_avg_exactly():
    """A state-independent log σ has the Fisher block 2·1 in every sub-policy and no cross term with the mean's
    parameters (I = J_μᵀΣ⁻¹J_μ + 2 J_ℓᵀJ_ℓ), so Eq 4.10/4.11 leaves log σ at the sub-policies' plain mean for
    any damping; the exact Eq 4.7 minimiser (moment matching) does not."""
    view, states, t0, thetas = problem(torch.float64, n=4, scale=0.3)
    assert view.names[0] == "log_std" and view.sizes[0] == 2  # θ = (log σ, mean net): log σ is θ[:2]
    for t in thetas:  # the log σ block of every I(θ_i) is 2·1, with no cross term to the mean's parameters
        fim = agg.fisher_matrix(view, t, states)
        assert torch.equal(fim[:2, :2], 2.0 * torch.eye(2, dtype=torch.float64))
        assert torch.count_nonzero(fim[:2, 2:]) == 0 and torch.count_nonzero(fim[2:, :2]) == 0
    mean_ls = log_std_part(view, torch.stack(thetas).mean(0))
    for damping in (0.0, 0.1, 10.0):
        dense = agg.kl_avg_dense(view, thetas, states, damping=damping)
        assert torch.allclose(log_std_part(view, dense), mean_ls, atol=1e-12, rtol=0)
        cg = agg.kl_avg(view, thetas, states, t0, cg_iters=10, damping=damping)  # the kit's 10 CG iterations
        assert torch.allclose(log_std_part(view, cg), mean_ls, atol=1e-12, rtol=0)
    assert torch.allclose(log_std_part(view, readings.kl_diag(view, thetas, states)), mean_ls, atol=1e-12, rtol=0)
    ls = agg.kl_avg(view, thetas, states, t0, cg_iters=10, damping=0.1, line_search=True)
    assert torch.allclose(log_std_part(view, ls), mean_ls, atol=1e-12, rtol=0)
    moved = exact.kl_exact(view, thetas, states, iters=10)
    assert (log_std_part(view, moved) - mean_ls).abs().max() > 1e-3  # moment matching widens σ


def test_trust_region_keeps_the_aggregate_within_the_sub_policies_kl_to_theta_old():
    view, states, t0, thetas = problem(scale=0.3)
    info: dict = {}
    new = readings.kl_trust_region(view, thetas, states, t0, kl_bound=1e-3, info=info)
    assert 0.0 <= info["step_fraction"] < 1.0 and info["kl_bound"] == 1e-3
    assert float(agg.mean_kl(view, t0, new, states)) <= 1e-3
    target = agg.kl_avg(view, thetas, states, t0)
    assert torch.allclose(new, t0 + info["step_fraction"] * (target - t0), atol=1e-6)
    loose: dict = {}
    assert torch.allclose(readings.kl_trust_region(view, thetas, states, t0, kl_bound=1e9, info=loose), target)
    assert loose["step_fraction"] == 1.0


@pytest.mark.parametrize("algo", readings.reading_ids())
def test_each_reading_trains_stably_on_a_short_run(algo, tmp_path):
    cfg = train_config(algo, "Hopper", 0, 2048, **SHORT)
    res = train_job(cfg, tmp_path)
    assert res["timesteps_done"] == 2048 and res["n_episodes"] > 0
    for key in ("curve_return", "curve_entropy", "curve_eq47", "curve_eq47_params_avg"):
        assert np.isfinite(res[key]).all(), key
    assert (res["curve_eq47"] < 1.0).all()  # no collapse: the literal reading's reaches 1e2-1e3 nats
    if algo == "kl-avg-ls":  # the line search's guarantee, at every iteration
        assert (res["curve_eq47"] <= res["curve_eq47_params_avg"]).all()
        assert np.isin(res["curve_step_fraction"], agg.LINE_SEARCH_FRACTIONS).all()
    if algo in ("kl-avg-tr", "kl-avg-trpo"):
        assert (res["curve_kl_old"] <= res["curve_kl_bound"] + 1e-9).all()
        assert ((res["curve_step_fraction"] >= 0) & (res["curve_step_fraction"] <= 1)).all()
    if algo in ("kl-avg-trpo",):
        assert (res["curve_kl_bound"] == cfg["sb3"]["kl_bound"]).all()
    if algo not in ("kl-avg", "kl-exact"):
        assert (res["curve_kl_params_avg"] >= -1e-6).all()  # a KL, to float32 rounding


def test_bad_reading_ids_are_one_line_errors_naming_the_valid_choices():
    with pytest.raises(ValueError, match=r"valid algorithms are: .*'kl-avg-ls'.*'kl-avg-tr'.*'kl-diag'") as err:
        train_config("kl-avg-linesearch", "Walker2d", 0, 100)
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match=r"valid aggregates are: .*'kl_diag'"):
        train_config("kl-avg", "Walker2d", 0, 100, aggregate="kl_diagonal")
    with pytest.raises(ValueError, match="trust_region is a step rule"):
        train_config("kl-avg-tr", "Walker2d", 0, 100, line_search=True)
    with pytest.raises(ValueError, match="valid hyperparameters of 'kl-avg' are: .*'stop_at'"):
        train_config("kl-avg", "Walker2d", 0, 100, trust_region=True)
    with pytest.raises(ValueError, match="kl_bound must be"):
        train_config("kl-avg-trpo", "Walker2d", 0, 100, kl_bound=-1.0)
    with pytest.raises(ValueError, match=r"valid learners of pilot set 'ch4-readings' are: .*'kl-avg-tr'"):
        pilots.pilot_configs("ch4-readings", 1000, ["kl-avg-xx"])
    assert pilots.main(["nope"]) == 2


def test_stop_at_trains_the_start_of_the_longer_run(tmp_path):
    full = train_config("kl-avg-ls", "Hopper", 0, 512, **SHORT)
    assert "stop_at" not in full  # absent unless set: every existing config (and run key) stays as it was
    assert train_config("kl-avg-ls", "Hopper", 0, 512, stop_at=None, **SHORT) == full
    cfg = train_config("kl-avg-ls", "Hopper", 0, 512, stop_at=256, **SHORT)
    with pytest.raises(ValueError, match="stop_at must be an integer in"):
        train_config("kl-avg-ls", "Hopper", 0, 512, stop_at=512, **SHORT)
    assert train_job(cfg, tmp_path)["timesteps_done"] == 256
    # the schedule of the first half of a 4-iteration run: SB3's progress over 2 iterations, mapped onto 4
    whole, half = Ppo1Linear(1.0, 0.25), Ppo1Linear(1.0, 0.25, horizon=0.5)
    assert [half(p) for p in (0.5, 0.0)] == pytest.approx([whole(p) for p in (0.75, 0.5)])


def test_pilot_table_reads_a_summary():
    n = 12
    series = {
        "timesteps": list(range(1, n + 1)),
        "return": [10.0 * i for i in range(n)],
        "entropy": [1.0] * n,
        "eq47": [1.0] * n,
        "eq47_params_avg": [2.0] * n,
        "step_fraction_mean": [0.0] * n,
    }
    prov = {"timesteps": n, "wall_time": 60.0}
    doc = {"pilots": [{"algo": "kl-avg-ls", "series": series, "provenance": prov}]}
    row = pilots.pilot_table(doc).iloc[0]
    assert row["trains"] == "yes" and row["reduces to params_avg"]
    assert row["Eq 4.7 vs params_avg (median)"] == -0.5 and row["final return"] == 110.0


def test_the_readings_page_is_a_section_of_chapter_4_in_the_contents(tmp_path):
    import yaml

    from thesis_repro.book import builder as book

    for name in ["intro", "chapter-3", "chapter-4", "chapter-4-readings"]:
        (tmp_path / f"{name}.md").write_text(f"# {name}\n")
    toc = yaml.safe_load(book.write_toc([], tmp_path).read_text())
    assert [c["file"] for c in toc["chapters"]] == ["chapter-3", "chapter-4"]
    assert toc["chapters"][1]["sections"] == [{"file": "chapter-4-readings"}]


def test_the_readings_page_is_rendered_from_the_pilot_summary(monkeypatch):
    """The shipped page is what the shipped summary renders to: no number on it is typed in."""
    from thesis_repro.core import paths

    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(paths.ROOT / "data" / "reference"))  # the shipped summary
    page = paths.BOOK / pilots.PAGES["ch4-readings"]
    doc = pilots.load_summary("ch4-readings")
    assert page.read_text() == pilots.render_page("ch4-readings", doc)
    assert {p["algo"] for p in doc["pilots"]} <= set(pilots.PILOTS["ch4-readings"][4])
    for p in doc["pilots"]:  # provenance: the commit, the seed and the env steps of each pilot
        assert p["provenance"]["git_commit"] and p["provenance"]["seed"] == 0
        assert p["provenance"]["timesteps"] >= p["config"]["stop_at"]
    assert pilots.summary_path("ch4-readings").stat().st_size < 200_000


def test_a_reading_listed_on_some_items_stays_in_the_grid_until_every_item_lists_it():
    """An item lists a reading once its runs are shipped; a reading some item does not list yet stays in the grid
    (the generator skips what is shipped), while one every item lists (kl-exact; kl-avg-trpo and kl-avg-once, their
    runs all shipped) is no grid learner: the grid is done and makes no jobs."""
    import json

    from thesis_repro import figures
    from thesis_repro.core import paths

    doc = json.loads((paths.ROOT / "data" / "reference" / "pilots" / "ch4-readings.json").read_text())  # shipped
    algos = pilots.grid_algos(doc)
    listed = set.intersection(*(set(figures.get(f).settings("small")["algos"]) for f in pilots.GRID_ITEMS))
    assert "kl-exact" in listed and "kl-exact" not in algos
    assert not set(algos) & listed
    assert {"kl-avg-trpo", "kl-avg-once"} <= listed and algos == []
    assert pilots.readings_grid_jobs("small", algos) == []
    assert pilots.readings_grid_jobs("small", ["kl-avg-trpo"])  # a listed reading's jobs, all shipped


def _entropy_runs(final: dict[str, list[float]], alpha: dict[str, float]) -> tuple:
    """A runs table and curves frame: per algo and seed, 6 iterations of return 100 ending at ``final`` entropy."""
    import pandas as pd

    runs, parts = [], []
    for algo, ents in final.items():
        for seed, e in enumerate(ents):
            result = {"curve_step_fraction": [alpha[algo]] * 6} if algo in alpha else {}
            runs.append({"algo": algo, "seed": seed, "result": result})
            parts.append(
                pd.DataFrame(
                    {"algo": algo, "seed": seed, "iteration": range(1, 7), "return": 100.0, "entropy": [8.5] * 5 + [e]}
                )
            )
    return pd.DataFrame(runs), pd.concat(parts, ignore_index=True)


def test_the_log_sigma_check_tests_only_full_step_fisher_readings_against_params_avg():
    from thesis_repro.figures import entropy

    final = {
        "params_avg": [6.6, 6.7, 6.8],
        "kl_avg_once": [6.5, 6.7, 6.9],  # same σ rule, full steps: the interval covers 0
        "kl_diag": [7.6, 7.7, 7.8],  # same σ rule, full steps, 1 nat higher: the argument fails
        "kl_avg_trpo": [8.6, 8.7, 8.8],  # α < 1: allowed to move
        "kl_exact": [8.0, 8.1, 8.2],
    }
    runs, curves = _entropy_runs(final, {"kl_avg_once": 1.0, "kl_diag": 1.0, "kl_avg_trpo": 0.4})
    table = entropy.log_sigma_check(runs, curves)
    assert table.loc["kl_avg_once", "argument"] == "same: yes"
    assert table.loc["kl_diag", "argument"] == "same: NO"
    assert table.loc["kl_avg_trpo", "argument"] == table.loc["kl_exact", "argument"] == "moves"
    assert table.loc["params_avg", "argument"] == "-"
    assert table.loc["kl_avg_trpo", "mean α"] == "0.40"
    line = entropy.check_line(table)
    assert "kl_diag keeps params_avg's log σ with a full step" in line and "NOT consistent" in line


def test_the_log_sigma_check_leaves_out_diverged_runs_and_says_so():
    import pandas as pd

    from thesis_repro.figures import entropy

    runs, curves = _entropy_runs({"params_avg": [6.6, 6.7], "kl_avg": [float("nan"), float("nan")]}, {})
    div = pd.DataFrame({"algo": ["kl_avg"] * 2, "seed": [0, 1], "diverged": True})
    table = entropy.log_sigma_check(runs, curves, div)
    assert table.loc["kl_avg", "argument"] == "diverged, not judged"
    assert table.loc["kl_avg", "seeds"] == "0 (2 diverged)"
    assert "kl_avg: every run diverged in training, not judged." in entropy.check_line(table)
