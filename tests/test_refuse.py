"""Say it, or refuse: a figure whose training runs are neither shipped nor cached refuses with one
line naming what would train and its cost, unless asked to train; local runs used over shipped ones are said."""

from __future__ import annotations

import dataclasses

import pytest

from thesis_repro import figures
from thesis_repro.book import notebooks
from thesis_repro.cli.commands import main
from thesis_repro.core import paths
from thesis_repro.core.cache import Job, RunCache
from thesis_repro.runs import costs as plan

TOY = [Job("square", {"x": x}) for x in (1, 2)]


@pytest.fixture
def toy_training(monkeypatch):
    """Figure 3.3's training runs replaced by two toy jobs (the kind ``square`` counted as training)."""
    monkeypatch.setattr(figures, "TRAINING_KINDS", ("square",))
    real = figures.jobs
    monkeypatch.setattr(figures, "jobs", lambda fid, scale, **kw: list(TOY) if fid == "3.3" else real(fid, scale, **kw))


def test_a_figure_without_its_shipped_runs_refuses_naming_the_cost(monkeypatch, capsys):
    ran = []
    monkeypatch.setattr(notebooks, "execute_notebook", lambda *a, **k: ran.append(a))
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
    RunCache(paths.runs_dir(), reference=False).run(TOY[0])  # and one of them also in the local cache
    assert plan.refuse_training("3.3", "small") == 1
    out = capsys.readouterr().out
    assert "figure 3.3: 1 of its 2 training runs come from the local cache" in out
    with pytest.raises(ValueError, match=r"would train 1 of its 2 runs"):
        monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(tmp_path / "empty"))
        for p in paths.runs_dir().glob("square/*"):
            if TOY[1].key in p.name:
                raise AssertionError("only TOY[0] is local")
        plan.refuse_training("3.3", "small")


def test_local_runs_used_over_shipped_ones_are_named_in_the_verdicts_evidence(toy_training, tmp_path, monkeypatch):
    """The page's meta counts its runs read from the local run cache (those replacing a shipped copy too), and
    every verdict judged from that page's numbers says how many in its evidence."""
    from thesis_repro.book import pages
    from thesis_repro.claims import ledger, page_verdicts, registry, report, store
    from thesis_repro.claims import synthetic as S

    monkeypatch.setitem(figures.FIGURES, "3.3", dataclasses.replace(figures.get("3.3"), grid=lambda s: list(TOY)))
    settings = figures.settings("3.3", "small")
    layer = tmp_path / "layer"
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(layer))
    for job in TOY:
        RunCache(layer, reference=False).run(job)  # both shipped
    assert pages.local_runs("3.3", settings) is None
    RunCache(paths.runs_dir(), reference=False).run(TOY[0])  # one also local: it replaces the shipped copy
    use = pages.local_runs("3.3", settings)
    assert use == {"local": 1, "replacing_shipped": 1, "of": 2, "noun": "training runs"}

    frames = S.frames_for("correlation", 3, 0)
    text = "fig-3.3 used 1 of its 2 training runs from the local run cache, not the shipped layer (1 in place of a"
    vs = page_verdicts.judge_page("fig-3.3", "small", frames, {"local_runs": use}, display=False)
    assert vs and all(text in v.evidence for v in vs if v.status != report.VISUAL)
    row = ledger.judge(registry.spec("3.3-negative-correlation"), "small", with_null=False)
    assert row.local_runs == {"fig-3.3": use} and row.as_dict()["local_runs"] == {"fig-3.3": use}
    assert ledger.judge(registry.spec("3.3-not-valid-metric"), "small", with_null=False).local_runs == {"fig-3.3": use}
    # no local run: nothing said, and the saved meta stays as before (the shipped snapshot's bytes do not change)
    page_verdicts.judge_page("fig-3.3", "small", frames, {}, display=False)
    assert "local_runs" not in store.load_page("fig-3.3", "small")["meta"]
    assert all("local run cache" not in v.evidence for v in page_verdicts.verdicts("fig-3.3", "small"))
