"""Your agent under the thesis's protocol: score_model with CIs on the book grid, beside the shipped
learners, the `score` / `train` / `enjoy` commands and their one-line errors, and the README's example."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from thesis_repro.book import agent, clips
from thesis_repro.cli.commands import main
from thesis_repro.evaluation import score as sc

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tiny_models():
    """Two untrained PPO models on Hopper (two "training seeds"); they fall within tens of steps."""
    from stable_baselines3 import PPO

    return [PPO("MlpPolicy", "Hopper-v5", n_steps=64, batch_size=32, seed=s, device="cpu") for s in (0, 1)]


def test_book_grid_is_the_pages_grid():
    from thesis_repro.figures import ch3_tables

    for scale in ("smoke", "small"):
        s, g = ch3_tables.checked_settings("3.4", scale), sc.book_grid(scale)
        assert g["sigmas"] == [float(x) for x in s["sigmas"]]
        assert g["n_rollouts"] == s["test_rollouts"] and g["tests"] == list(s["tests"])


def test_score_model_at_smoke_scale_gives_aucs_with_the_ledgers_cis(tiny_models):
    from thesis_repro.claims.stats import _mean_ci

    scores = sc.score_model(tiny_models, "Hopper", "smoke", progress=False)
    g = sc.book_grid("smoke")
    assert scores.tests == g["tests"] and list(scores.sigmas) == g["sigmas"] and scores.n_models == 2
    assert scores.returns["obs"].shape == (2, len(g["sigmas"]), g["n_rollouts"])
    table = scores.table()
    assert list(table["test"]) == g["tests"] and set(table["n_seeds"]) == {2}
    for row in table.itertuples():  # per model the AUC of its mean curve; the t-interval of claims.stats over them
        r = scores.returns[row.test]
        per_model = np.array([sum(np.diff(scores.sigmas)[0] * r[i].mean(axis=1)) for i in range(2)])
        m, lo, hi = _mean_ci(per_model, 0.95)
        assert (row.seed_mean, row.ci_lo, row.ci_hi) == pytest.approx((m, lo, hi))
    assert "95 % CI of the mean across 2 training seeds" in str(scores)


def test_score_model_bad_input_is_one_line(tiny_models):
    cases = [
        (lambda: sc.score_model(tiny_models[0], "Hoper"), "valid envs are"),
        (lambda: sc.score_model(tiny_models[0], "Hopper", "medium"), "valid scales are"),
        (lambda: sc.score_model([], "Hopper"), "at least one model"),
        (lambda: sc.score_model(tiny_models[0], "Walker2d", "smoke"), "policy does not fit task 'Walker2d'"),
        (lambda: sc.score_model(tiny_models, "Hopper", vecnormalize=[None]), "one per model"),
    ]
    for call, expected in cases:
        with pytest.raises(ValueError) as err:
            call()
        assert expected in str(err.value) and "\n" not in str(err.value)


def test_compare_with_shipped_puts_the_agent_beside_every_shipped_learner(tiny_models, shipped):
    """An untrained agent on the small book grid (one test type: it falls within ~100 steps) beside the shipped
    Hopper learners."""
    scores = sc.score_model(tiny_models[0], "Hopper", "small", tests=["obs"], progress=False)
    cmp = agent.compare_with_shipped(scores, "Hopper")
    methods = list(dict.fromkeys(cmp.table["method"]))
    assert methods[0] == "your agent" and {"ppo", "trpo", "sac", "ppo-mdl"} <= set(methods)
    assert set(cmp.table["test"]) == {"obs"}
    ppo = cmp.table[(cmp.table["method"] == "ppo") & (cmp.table["test"] == "obs")].iloc[0]
    assert ppo.n_seeds >= 2 and ppo.ci_lo <= ppo.seed_mean <= ppo.ci_hi  # shipped seeds: a CI
    ours = cmp.table[cmp.table["method"] == "your agent"]
    assert (ours["seed_mean"] < ppo.seed_mean).all()  # an untrained agent is far below a trained PPO
    assert cmp.figure.axes and "your agent" in str(cmp)
    with pytest.raises(ValueError, match="book at scale 'small' uses"):
        agent.compare_with_shipped(sc.score_model(tiny_models[0], "Hopper", "small", n_rollouts=2, tests=["obs"]))
    smoke = sc.score_model(tiny_models[0], "Hopper", "smoke", tests=["obs"], progress=False)
    with pytest.raises(ValueError, match="no shipped or cached chapter-3 evaluations of Hopper at scale 'smoke'"):
        agent.compare_with_shipped(smoke, cache=agent.RunCache(root=Path("/nonexistent"), reference=False))


def test_score_command_from_sb3_zips(tiny_models, tmp_path, capsys):
    zips = []
    for i, m in enumerate(tiny_models):
        m.save(tmp_path / f"seed{i}.zip")
        zips.append(str(tmp_path / f"seed{i}.zip"))
    assert main(["score", *zips, "--task", "Hopper", "--scale", "smoke", "--no-compare"]) == 0
    out = capsys.readouterr().out
    assert "your agent on Hopper (scale smoke" in out and "(seeds: 2)" in out


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["score", "missing.zip", "--task", "Hopper"], "error: no such model file: 'missing.zip'"),
        (["score", "README.md", "--task", "Hopper"], "error: 'README.md' is not an SB3 model .zip"),
        (["score", "README.md", "--task", "Hoper"], "error: unknown env 'Hoper'"),
        (["score", "README.md", "--task", "Hopper", "--scale", "big"], "error: unknown scale 'big'"),
        (["train", "ppo2", "Hopper"], "error: unknown learner 'ppo2'; valid learners are: 'ppo'"),
        (["train", "ppo", "Hopper", "--seed", "-1"], "error: argument --seed: invalid value '-1'"),
        (["enjoy", "ppo", "Hopper", "--test", "wind"], "error: unknown test type 'wind'"),
        (["enjoy", "ppo", "Hopper", "--video", "out.avi"], "error: video must end in .mp4 or .gif"),
        (["clips", "--scale", "big"], "error: unknown scale 'big'"),
    ],
)
def test_agent_commands_give_one_line_errors(argv, expected, capsys, monkeypatch):
    monkeypatch.chdir(ROOT)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(expected), err


def test_train_runs_one_job_through_the_cache(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("THESIS_REPRO_DATA", str(tmp_path / "runs"))
    job = agent.training_job("ppo", "InvertedPendulum", 0, "smoke")
    from thesis_repro import figures

    assert job in figures.training_jobs("table-3.4", "smoke")  # the book's own job (same key)
    assert main(["train", "ppo", "InvertedPendulum", "--seed", "0", "--scale", "smoke"]) == 0
    assert "computed" in capsys.readouterr().out
    assert main(["train", "ppo", "InvertedPendulum", "--seed", "0", "--scale", "smoke"]) == 0
    assert "cached" in capsys.readouterr().out


def test_enjoy_renders_a_cached_policy_to_a_video(tmp_path, monkeypatch, capsys):
    pytest.importorskip("imageio_ffmpeg", reason="the [video] extra (make venv installs it)")
    monkeypatch.setenv("THESIS_REPRO_DATA", str(tmp_path / "runs"))
    assert main(["enjoy", "ppo", "InvertedPendulum", "--scale", "smoke"]) == 2
    assert "train ppo InvertedPendulum --seed 0 --scale smoke" in capsys.readouterr().err
    agent.train_run("ppo", "InvertedPendulum", 0, "smoke")
    video = tmp_path / "out.mp4"
    argv = ["enjoy", "ppo", "InvertedPendulum", "--scale", "smoke", "--test", "obs", "--sigma", "0.4"]
    assert main([*argv, "--video", str(video), "--max-steps", "20"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"return [0-9.]+ in \d+ steps \(cached run\); video: ", out), out
    import imageio.v2 as imageio

    frames = imageio.mimread(video)
    assert 2 <= len(frames) <= 21 and frames[0].ndim == 3


def test_version_flag(capsys):
    assert main(["--version"]) == 0
    assert re.fullmatch(r"thesis_repro \d+\.\d+\.\d+\S*\n", capsys.readouterr().out)


def readme_example() -> str:
    """The README's "your own agent" example if the README has one (the first python block after a heading
    naming "own agent"), else :data:`thesis_repro.book.agent.README_EXAMPLE`."""
    text = (ROOT / "README.md").read_text()
    m = re.search(r"^#+ .*own agent.*$\n(?:.*\n)*?```python\n(.*?)```", text, re.M | re.I)
    return m.group(1) if m else agent.README_EXAMPLE


def test_the_readme_example_runs_as_written(capsys, shipped):
    code = readme_example()
    assert len(code.strip().splitlines()) <= 5
    exec(compile(code, "README.md", "exec"), {})
    out = capsys.readouterr().out
    assert re.search(r"your agent on \w+ \(scale small", out) and "ppo" in out


def test_enjoy_without_the_video_extra_is_one_line(monkeypatch, capsys):
    import sys

    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # as if the [video] extra were not installed
    assert main(["enjoy", "ppo", "InvertedPendulum", "--scale", "smoke", "--video", "x.mp4"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: writing .mp4 videos needs imageio_ffmpeg: pip install"), err


def test_score_command_puts_a_zip_beside_the_shipped_learners(tmp_path, shipped, capsys):
    from stable_baselines3 import PPO

    PPO("MlpPolicy", "InvertedPendulum-v5", n_steps=64, batch_size=32, seed=0, device="cpu").save(tmp_path / "m.zip")
    png = tmp_path / "cmp.png"
    argv = ["score", str(tmp_path / "m.zip"), "--task", "InvertedPendulum", "--scale", "small", "--figure", str(png)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "testing AUC, 95 % CI of the mean across" in out and re.search(r"^ppo +\S", out, re.M), out
    assert png.stat().st_size > 0


# ---------------------------------------------------------------- the guide page "Score your own agent"
GUIDE = "guide-score-agent"


def test_the_guide_page_is_a_book_page_the_claims_ledger_ignores(tmp_path):
    import yaml

    from thesis_repro.book import builder as book
    from thesis_repro.book import notebooks
    from thesis_repro.claims import registry

    assert GUIDE in notebooks.notebook_ids(guides=True) and GUIDE not in notebooks.notebook_ids()
    assert notebooks.notebook_ids(guides=True)[-1] == GUIDE  # after every thesis page: it reads their runs
    assert notebooks.check_notebook(GUIDE) == GUIDE and notebooks.page_id(GUIDE) == GUIDE
    assert notebooks.source(GUIDE).name == f"{GUIDE}.py" and notebooks.page_chapter(GUIDE) == "guide"
    assert notebooks.parameter_names(GUIDE) == ["SCALE", "TASK", "SEEDS", "TIMESTEPS"]
    assert GUIDE not in book.claims() and not registry.page_claims(GUIDE)  # no thesis claim, no verdict
    (tmp_path / "chapter-3.md").write_text("# Chapter 3\n")
    (tmp_path / "kit.md").write_text("# Kit\n")
    toc = yaml.safe_load(book.write_toc(["3.3", GUIDE], tmp_path).read_text())
    files = [c["file"] for c in toc["chapters"]]
    assert files == ["chapter-3", GUIDE, "kit"] and toc["chapters"][0]["sections"] == [{"file": "executed/fig-3.3"}]


def test_a_guide_page_shows_its_code_and_no_thesis_block():
    from thesis_repro.book import builder as book

    nb = {
        "cells": [
            {"cell_type": "markdown", "metadata": {}, "source": "# Score your own agent\nintro"},
            {"cell_type": "code", "metadata": {"tags": ["parameters"]}, "source": "SCALE = 'small'", "outputs": []},
            {"cell_type": "code", "metadata": {"tags": ["injected-parameters"]}, "source": "", "outputs": []},
            {
                "cell_type": "code",
                "metadata": {},
                "source": "print(scores)",
                "outputs": [
                    {"output_type": "stream", "name": "stderr", "text": "score: 50%|#####| 1/2\n"},
                    {"output_type": "stream", "name": "stdout", "text": "your agent on X\n"},
                ],
            },
        ],
        "metadata": {},
    }
    page = book.prepare_guide(nb, GUIDE, "smoke")
    text = json.dumps(page)
    assert "parameters" not in text and "hide-input" not in text and "in the thesis" not in text
    assert [c["source"][:20] for c in page["cells"][:3]] == ["# Score your own age", "Executed at scale **", "intro"]
    assert page["cells"][-1]["outputs"] == [{"output_type": "stream", "name": "stdout", "text": "your agent on X\n"}]


def test_guide_settings_and_their_bad_input():
    g = agent.guide_settings("small", "Hopper")
    assert g["gym_id"] == "Hopper-v5" and not g["compute_missing"] and "none trained" in g["note"]
    assert agent.guide_settings("smoke", timesteps=128)["timesteps"] == 128
    for call, expected in [
        (lambda: agent.guide_settings("big"), "unknown scale 'big'"),
        (lambda: agent.guide_settings("smoke", "Hoper"), "unknown env 'Hoper'"),
        (lambda: agent.guide_settings("smoke", timesteps=0), "timesteps must be an integer >= 1"),
    ]:
        with pytest.raises(ValueError, match=expected) as err:
            call()
        assert "\n" not in str(err.value)


# ---------------------------------------------------------------- the chapter-3 landing page's clips
def test_clips_are_rendered_once_and_placed_on_the_chapter_3_page(tmp_path, capsys):
    pytest.importorskip("imageio", reason="the [video] extra (make venv installs it)")
    import imageio.v2 as imageio

    task = clips.CLIPS["task"]
    agent.train_run("ppo", task, 0, "smoke")  # seconds; the other basic learners stay untrained
    assert main(["clips", "--scale", "smoke"]) == 0
    out = capsys.readouterr().out
    assert f"ppo on {task}" in out and "no clip: not trained (python -m thesis_repro train trpo" in out, out
    doc = clips.current_clips("smoke")
    assert doc is not None and [c["algo"] for c in doc["clips"]] == list(clips.CLIPS["learners"])
    ppo = doc["clips"][0]
    gif = clips.clips_dir("smoke") / ppo["file"]
    frames = imageio.mimread(gif)
    steps, every = clips.CLIP_STEPS["smoke"]
    assert 1 <= len(frames) <= steps // every + 1 and frames[0].shape[:2] == (clips.CLIPS["size"],) * 2
    assert 1 <= ppo["length"] <= steps and ppo["source"] in ("computed", "cached")
    before = gif.stat().st_mtime_ns
    assert clips.make_clips("smoke") == doc and gif.stat().st_mtime_ns == before  # up to date: not rendered again
    root = tmp_path / "book"
    root.mkdir()
    (root / "chapter-3.md").write_text("# Chapter 3\n")
    section = clips.book_clips(root, "smoke")
    page = (root / "chapter-3.md").read_text()
    assert page.endswith(section) and "](clips/ppo.gif)" in section and (root / "clips" / "ppo.gif").is_file()
    assert re.search(r"return -?\d+, (over the first|episode ended after) \d+ steps", section), section
    assert "not trained at scale smoke: `python -m thesis_repro train sac" in section
    agent.train_run("sac", task, 0, "smoke")
    assert clips.current_clips("smoke") is None  # a learner's run landed: the clips are stale


def test_clips_that_cannot_be_rendered_are_one_line_on_the_page(tmp_path, monkeypatch):
    import subprocess

    calls = []

    def failing(cmd, **kw):
        calls.append(kw["env"]["MUJOCO_GL"])
        return subprocess.CompletedProcess(cmd, 1, "", "Traceback ...\nerror: cannot initialize EGL\n")

    (tmp_path / "chapter-3.md").write_text("# Chapter 3\n")
    monkeypatch.setattr(clips.subprocess, "run", failing)
    section = clips.book_clips(tmp_path, "smoke")  # no basic learner trained at smoke: nothing to render
    assert not calls and "not trained at scale smoke: `python -m thesis_repro train ppo" in section
    monkeypatch.setenv("MUJOCO_GL", "egl")
    monkeypatch.setattr(clips, "current_clips", lambda scale, cache=None: None)  # stale, and a run to render:
    monkeypatch.setattr(clips.RunCache, "state", lambda self, job, verify=False: "shipped")
    (tmp_path / "chapter-3.md").write_text("# Chapter 3\n")
    section = clips.book_clips(tmp_path, "smoke")
    assert calls == ["egl", "osmesa"]  # EGL first, then the software fallback
    lines = [ln for ln in section.splitlines() if ln.strip()]
    assert len(lines) == 2 and lines[1].startswith("No clips in this build: rendering them failed"), lines
    assert "MUJOCO_GL=egl: error: cannot initialize EGL; MUJOCO_GL=osmesa failed too" in lines[1]
    assert "make clips SCALE=smoke" in lines[1]
