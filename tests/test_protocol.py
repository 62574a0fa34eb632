"""The training protocol: baselines ppo1's linear annealing, the thesis protocol as the only one, and
the invariant that a fresh clone's small figure never trains for hours."""

from __future__ import annotations

import numpy as np
import pytest
from stable_baselines3.common.callbacks import BaseCallback

from thesis_repro import figures
from thesis_repro.book import protocol
from thesis_repro.core import paths, scales
from thesis_repro.learners import train_config, train_job
from thesis_repro.learners.config import PROTOCOLS, THESIS_PROTOCOL_KEYS, iteration_steps
from thesis_repro.learners.train import Ppo1Linear

PPO = {"n_steps": 64, "n_envs": 2, "batch_size": 32, "n_epochs": 2}


class _Rates(BaseCallback):
    """The learning rate and clip range each iteration trained with (read at the next rollout start)."""

    def __init__(self) -> None:
        super().__init__()
        self.lrs: list[float] = []
        self.clips: list[float] = []

    def _on_rollout_start(self) -> None:
        if self.model._n_updates:
            self.lrs.append(self.model.policy.optimizer.param_groups[0]["lr"])
            self.clips.append(self.model.clip_range(self.model._current_progress_remaining))

    def _on_training_end(self) -> None:
        self._on_rollout_start()

    def _on_step(self) -> bool:
        return True


def test_linear_schedule_anneals_lr_and_clip_range_to_zero_over_the_runs_own_budget(tmp_path):
    cfg = train_config("ppo", "InvertedPendulum", 0, 640, protocol="thesis", max_episode_steps=50, **PPO)
    assert cfg["lr_schedule"] == "linear" and iteration_steps(cfg) == 128
    rates = _Rates()
    train_job(cfg, tmp_path, callback=rates)
    n = 640 // 128  # 5 iterations: ppo1's max(1 - t/T, 0) at t = 0, 128, ..., 512 env steps before each
    expected = [1 - i / n for i in range(n)]
    assert np.allclose(np.array(rates.lrs) / 3e-4, expected) and np.allclose(np.array(rates.clips) / 0.2, expected)
    assert rates.lrs[-1] == pytest.approx(3e-4 / n)  # the last iteration: ~0 for a long run (1/n of the start)


def test_constant_schedule_is_a_named_option(tmp_path):
    cfg = train_config("ppo", "InvertedPendulum", 0, 384, protocol="thesis", lr_schedule="constant", **PPO)
    rates = _Rates()
    train_job(cfg, tmp_path, callback=rates)
    assert rates.lrs == [3e-4] * 3 and rates.clips == [0.2] * 3
    with pytest.raises(ValueError, match="valid lr_schedules are"):
        train_config("ppo", "Hopper", 0, 1000, protocol="thesis", lr_schedule="cosine")


def test_ppo1_schedule_values():
    s = Ppo1Linear(1.0, offset=0.1)
    assert s(0.9) == 1.0 and s(0.0) == pytest.approx(0.1) and s(-0.5) == 0.0


def _flat(cfg: dict, prefix: str = "") -> set[str]:
    """The dotted paths of ``cfg``'s settings (``"sb3.x"`` is ``cfg["sb3"]["x"]``)."""
    out = set()
    for key, value in cfg.items():
        out.add(prefix + key)
        if isinstance(value, dict):
            out |= _flat(value, f"{prefix}{key}.")
    return out


def test_the_thesis_protocol_is_the_only_one_and_the_default():
    assert PROTOCOLS == ("thesis",)
    algos = ("ppo", "ppo-mdl", "ppo-maml-dg", "ppo-reptile-dg", "ppo-epopt", "ppo-arpl", "kl-avg", "trpo", "sac")
    for algo in algos:
        cfg = train_config(algo, "Hopper", 0, 1000)
        assert cfg == train_config(algo, "Hopper", 0, 1000, protocol="thesis")
        assert ("lr_schedule" in cfg) == (cfg["class"] not in ("TRPO", "SAC", "DDPG"))
        assert cfg.get("lr_schedule", "linear") == "linear"  # PPO's default anneals
    keys = {"ppo-epopt": "sb3.epopt_rank", "ppo-maml-dg": "sb3.domain_per_batch", "ppo-arpl": "arpl.delta"}
    for algo, key in keys.items():
        assert {key, "lr_schedule"} <= _flat(train_config(algo, "Hopper", 0, 1000)) & set(THESIS_PROTOCOL_KEYS)
    with pytest.raises(ValueError, match="valid protocols are: 'thesis'$"):
        train_config("ppo", "Hopper", 0, 1000, protocol="baselines")


def test_every_shipped_ppo_run_anneals_or_names_its_schedule():
    """A shipped PPO-family run anneals linearly, or trains another named schedule of the lr-schedule study."""
    import json

    from thesis_repro.learners.config import LR_SCHEDULES
    from thesis_repro.runs.study import lr_schedule_jobs

    study = {j.key for j in lr_schedule_jobs()}
    checked = 0
    for path in sorted((paths.ROOT / "data" / "reference" / "train").iterdir()):
        meta = json.loads((path / "config.json").read_text())
        cfg = meta["config"]
        if cfg.get("class") in ("TRPO", "SAC", "DDPG"):  # no learning-rate schedule
            continue
        checked += 1
        assert cfg.get("lr_schedule") in LR_SCHEDULES, f"{path.name}: no named lr_schedule"
        assert cfg["lr_schedule"] == "linear" or meta["key"] in study, f"{path.name}: {cfg['lr_schedule']}"
    assert checked


def test_each_scale_states_its_seeds_and_rollouts_once():
    """`defaults` of scales.yaml give each scale's seeds and rollouts; a figure block of `small` restates neither
    (Fig 3.2 counts 3 like the rest), but for an item raised to the confirmatory seed count once its fresh seeds
    are shipped, and the caller's explicit override is the last word."""
    from thesis_repro.runs.needs import CONFIRMATORY_SEEDS

    table = scales._table()
    assert (table["defaults"]["small"]["train_seeds"], table["defaults"]["small"]["test_rollouts"]) == (3, 10)
    assert set(table) == {"scales", "defaults", "figures"}
    for fid in scales.figures():
        block = table["figures"][fid]["small"] or {}
        assert "test_rollouts" not in block and block.get("train_seeds", CONFIRMATORY_SEEDS) == CONFIRMATORY_SEEDS, fid
    assert scales.figure_settings("3.3", "small", train_seeds=5)["train_seeds"] == 5
    s = scales.figure_settings("table-3.5", "small", protocol="thesis")
    assert (s["protocol"], s["test_rollouts"]) == ("thesis", 10)


def test_a_fresh_clones_small_figures_train_nothing(tmp_path, monkeypatch):
    """The thesis protocol's invariant while runs change: every training run of every small figure is shipped (a fresh
    clone, i.e. an empty local cache, evaluates and plots only)."""
    from thesis_repro.core import paths
    from thesis_repro.core.cache import RunCache

    monkeypatch.setenv("THESIS_REPRO_DATA", str(tmp_path))
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(paths.ROOT / "data" / "reference"))
    monkeypatch.delenv("THESIS_REPRO_RETRAIN", raising=False)
    cache = RunCache()
    jobs = {j.key: j for fid in figures.ids() for j in figures.jobs(fid, "small") if j.kind == "train"}
    missing = sorted(j.label for j in jobs.values() if cache.state(j) != "shipped")
    assert not missing, f"small training runs neither shipped nor cached: {missing}"


def test_small_has_3_seeds_10_rollouts_and_every_learner():
    """The seed regeneration's evidence at small: 3 training seeds (6 for an item whose fresh seeds are shipped) x 10
    test rollouts for every chapter 3-4 item, no learner skipped; chapter 5 keeps its own seeds."""
    small = {fid: scales.figure_settings(fid, "small") for fid in scales.figures()}
    assert {s["protocol"] for s in small.values()} == {"thesis"}
    for s in small.values():
        assert s["train_seeds"] in (3, 6), s["figure"]
        assert (s["test_rollouts"], s.get("skip_algos", [])) == (10, []), s["figure"]
    assert scales.figure_settings("5.6", "small")["seeds"] in ([0, 1, 2], list(range(10)))  # 10 once shipped
    assert scales.figure_settings("3.3", "full")["train_seeds"] == 12


def test_the_generator_can_take_one_seed_first():
    """`--seeds 0` plans seed 0 only; `--seeds 0 1 2` plans the three seeds, seed by seed."""
    from thesis_repro.runs import generator

    planned = generator.job_queue("small", ["3.3"], seeds=[0], algos=["ppo"])
    assert {p.job.config["seed"] for p in planned} == {0} and {p.job.config["algorithm"] for p in planned} == {"ppo"}
    every = generator.job_queue("small", ["3.3"], seeds=[0, 1, 2], algos=["ppo"])
    assert len(every) == 3 * len(planned)
    assert [p.job.config["seed"] for p in every] == sorted(p.job.config["seed"] for p in every)


#: What a fresh clone's `make book SCALE=small` may evaluate on the fly (env steps, upper bound): small's 1,347
#: evaluations (10 rollouts, 3 seeds) are shipped (`KINDS=evaluate`), so it evaluates (almost) nothing.
FRESH_CLONE_EVAL_STEPS = 10_000_000


def test_a_fresh_clones_small_book_evaluates_little(tmp_path, monkeypatch):
    """The seed regeneration: every small evaluation is shipped, so a fresh clone's book loads rather than evaluates
    for hours;
    no more than :data:`FRESH_CLONE_EVAL_STEPS`."""
    from thesis_repro.core import paths
    from thesis_repro.runs import costs as plan
    from thesis_repro.runs import throughput

    monkeypatch.setenv("THESIS_REPRO_DATA", str(tmp_path))
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(paths.ROOT / "data" / "reference"))
    _, book = plan.plan_book("small", cores=2, rates=throughput.Rates(dict(throughput.DEFAULT_RATES), {}), missing=True)
    assert book.n_train == 0
    evaluation = sum(ln.work for ln in book.other if ln.family == "evaluate")
    assert evaluation <= FRESH_CLONE_EVAL_STEPS, (
        f"a fresh clone's small book would evaluate {evaluation:,.0f} env steps on the fly; ship the evaluations "
        "(`make reference-runs SCALE=small KINDS=evaluate`)"
    )


def test_a_seed_past_the_confirmatory_target_is_stale(tmp_path):
    """The scale's own seeds are current; the confirmatory replication's (3-5 here) are current for
    `check_shipped` before the scale table counts them; a seed past that target is stale."""
    from thesis_repro.core import scales
    from thesis_repro.runs import generator, shipped_checks

    # an item with a learner grid the scale table still reads at 3 seeds (the confirmatory replication raises them
    # one by one): a chapter-3 table first (cheapest to plan), else a figure (it leaves chapter 4's at 3)
    at_three = sorted(
        (
            f
            for f in scales.figures()
            if scales.figure_settings(f, "small").get("train_seeds") == 3
            and "algos" in scales.figure_settings(f, "small")
            and not f.startswith(("5.", "analysis-"))
        ),
        key=lambda f: not f.startswith("table-3."),
    )
    if not at_three:
        pytest.skip("every chapter 3-4 item reads its fresh seeds at small")
    item, algo = at_three[0], scales.figure_settings(at_three[0], "small")["algos"][-1]
    within = generator.job_queue("small", [item], seeds=[2], algos=[algo])
    fresh = generator.job_queue("small", [item], seeds=[5], algos=[algo])
    beyond = generator.job_queue("small", [item], seeds=[6], algos=[algo])
    assert within and fresh and beyond
    current = shipped_checks.current_keys("small", figure_ids=[item])
    assert {p.job.key for p in within} <= current
    assert not {p.job.key for p in fresh} & current
    for p in (*fresh, *beyond):  # entry folders named as `export` names them (a folder no job binds to)
        (tmp_path / "entries" / f"{p.job.label}__{p.job.key}").mkdir(parents=True)
    stale = {s.key for s in shipped_checks.check_shipped("small", tmp_path)}
    assert stale == {p.job.key for p in beyond}


@pytest.mark.parametrize(
    ("name", "seeds", "words"),
    [
        ("three", 3, "items_with_seeds"),
        ("six", 6, "items_with_seeds"),
        ("arm-ten", 10, "arm_items_with_seeds"),
    ],
)
def test_book_names_exactly_the_items_at_each_seed_count(name: str, seeds: int, words: str):
    """The book page on shipped runs lists the chapter 3-4 items at 3 seeds and those at 6 (fresh seeds shipped),
    and chapter 5's at 10; the scale table decides which."""
    text = (paths.ROOT / "book" / "runs.md").read_text()
    block = text.split(f"<!-- {name}-seeds:begin -->")[1].split(f"<!-- {name}-seeds:end -->")[0]
    assert block == getattr(protocol, words)(seeds, "small"), (
        f"book/runs.md's {name}-seeds list is stale: paste `python -c \"from thesis_repro.book import protocol; "
        f'print(protocol.{words}({seeds}))"`'
    )
