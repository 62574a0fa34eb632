"""Say it, or refuse (issue 43 item 4): a figure whose training runs are neither shipped nor cached refuses with one
line naming what would train and its cost, unless asked to train; local runs used over shipped ones are said."""

from __future__ import annotations

import pytest

from thesis_repro import figures, notebooks, paths, plan
from thesis_repro.__main__ import main
from thesis_repro.cache import Job, RunCache

TOY = [Job("square", {"x": x}) for x in (1, 2)]


@pytest.fixture
def toy_training(monkeypatch):
    """Figure 3.3's training runs replaced by two toy jobs (the kind ``square`` counted as training)."""
    monkeypatch.setattr(figures, "TRAINING_KINDS", ("square",))
    real = figures.jobs
    monkeypatch.setattr(figures, "jobs", lambda fid, scale, **kw: list(TOY) if fid == "3.3" else real(fid, scale, **kw))


def test_a_figure_without_its_shipped_runs_refuses_naming_the_cost(monkeypatch, capsys):
    ran = []
    monkeypatch.setattr(notebooks, "execute", lambda *a, **k: ran.append(a))
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", "/nonexistent")  # the shipped layer is missing
    assert main(["figure", "3.3", "--scale", "small"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: figure 3.3 at small would train "), err
    assert "env steps" in err[0] and "core-hours" in err[0] and "/nonexistent" in err[0] and "--train" in err[0]
    assert ran == []
    assert main(["figure", "3.3", "--scale", "small", "--train"]) == 0  # asked to train: it runs
    monkeypatch.setenv("THESIS_REPRO_RETRAIN", "1")
    assert main(["figure", "3.3", "--scale", "small"]) == 0  # RETRAIN=1 asks to train too
    assert [a[:2] for a in ran] == [("3.3", "small")] * 2


def test_local_runs_used_over_shipped_ones_are_said(toy_training, tmp_path, monkeypatch, capsys):
    layer = tmp_path / "layer"
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(layer))
    for job in TOY:
        RunCache(layer, reference=False).run(job)  # shipped
    assert plan.refuse_training("3.3", "small") == 0
    RunCache(paths.runs(), reference=False).run(TOY[0])  # and one of them also in the local cache
    assert plan.refuse_training("3.3", "small") == 1
    out = capsys.readouterr().out
    assert "figure 3.3: 1 of its 2 training runs come from the local cache" in out
    with pytest.raises(ValueError, match=r"would train 1 of its 2 runs"):
        monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(tmp_path / "empty"))
        for p in paths.runs().glob("square/*"):
            if TOY[1].key in p.name:
                raise AssertionError("only TOY[0] is local")
        plan.refuse_training("3.3", "small")
