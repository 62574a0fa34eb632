"""``train`` and ``enjoy`` for real use: a budget of your own (``--timesteps``), the cost before training, progress
with an ETA, a refusal naming the cost for a run neither shipped nor cached, tasks matched case-insensitively with
a "did you mean", the fast rendering options, any SB3 zip, and ``--human`` refused in one line without a display."""

from __future__ import annotations

import pytest

from thesis_repro.book import agent
from thesis_repro.cli.commands import main


def test_an_unshipped_run_names_its_cost_and_asks_for_train(monkeypatch, capsys):
    monkeypatch.setenv("COLUMNS", "80")
    assert main(["train", "ppo", "hopper", "--seed", "9"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("error: ppo on Hopper (seed 9, scale small) is neither shipped nor cached: training it")
    assert "2,000,000 env steps, about " in err[0] and "pass --train" in err[0] and "--timesteps N" in err[0]


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["train", "ppo", "hoper"], "error: unknown env 'hoper'; did you mean 'Hopper'? valid envs are: "),
        (["train", "ppo", "Hopper", "--timesteps", "0"], "error: argument --timesteps: invalid value '0'"),
        (["enjoy", "ppo", "walker", "--scale", "smoke"], "error: unknown env 'walker'; did you mean 'Walker2d'?"),
        (["enjoy", "ppo", "Hopper", "--size", "8", "--video", "x.gif"], "error: size must be an integer >= 16"),
        (["enjoy", "missing.zip", "Hopper"], "error: no such model file: 'missing.zip'"),
    ],
)
def test_bad_input_is_one_line(argv, expected, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(expected), err


def test_tasks_and_learners_match_case_insensitively():
    assert agent.training_job("PPO", "invertedpendulum", 0, "smoke") == agent.training_job(
        "ppo", "InvertedPendulum", 0, "smoke"
    )
    assert agent.match_task("HALFCHEETAH-V5") == "HalfCheetah"


def test_train_with_a_budget_prints_its_cost_then_progress_with_an_eta(monkeypatch, capsys):
    monkeypatch.setenv("COLUMNS", "80")
    argv = ["train", "PPO", "invertedpendulum", "--timesteps", "512", "--scale", "smoke"]
    assert main(argv) == 0
    got = capsys.readouterr()
    out, err = got.out.splitlines(), got.err.splitlines()
    assert out[0].startswith("ppo on InvertedPendulum (seed 0, scale smoke, 512 steps): neither shipped nor")
    text = got.out.replace("\n  ", " ")  # lines wrapped at 80 columns, joined again
    assert "512 env steps, about" in text and "computed, training return" in text
    assert err[0].startswith("train ppo on InvertedPendulum: ") and "ETA ?" in err[0]
    assert err[-1].startswith("train ppo on InvertedPendulum: 512/512 env steps (100%)") and err[-1].endswith("done")
    assert all(len(line) <= 80 for line in got.out.splitlines() + err[:-1] if not line.startswith("/"))
    job = agent.training_job("ppo", "InvertedPendulum", 0, "smoke", timesteps=512)
    assert job.config["timesteps"] == 512 and job != agent.training_job("ppo", "InvertedPendulum", 0, "smoke")
    assert main(argv) == 0  # now cached: no cost, no progress
    got = capsys.readouterr()
    assert "smoke, 512 steps): cached" in got.out.replace("\n  ", " ") and got.err == ""


def test_enjoy_renders_any_sb3_zip_fast_with_progress(tmp_path, capsys):
    pytest.importorskip("imageio", reason="the [video] extra (make venv installs it)")
    from stable_baselines3 import PPO

    PPO("MlpPolicy", "InvertedPendulum-v5", n_steps=64, batch_size=32, seed=0, device="cpu").save(tmp_path / "m.zip")
    video = tmp_path / "m.gif"
    argv = ["enjoy", str(tmp_path / "m.zip"), "invertedpendulum", "--video", str(video)]
    assert main([*argv, "--lean", "--size", "64", "--every", "2", "--max-steps", "40"]) == 0
    got = capsys.readouterr()
    assert "(SB3 zip m.zip); video:" in got.out.replace("\n  ", " ")
    assert got.err.splitlines()[-1].startswith("enjoy m.zip on InvertedPendulum: ")
    assert got.err.splitlines()[-1].endswith("done")
    import imageio.v2 as imageio

    frames = imageio.mimread(video)
    assert frames[0].shape[:2] == (64, 64) and len(frames) <= 21


def test_human_rendering_without_a_display_is_refused_in_one_line(monkeypatch, tmp_path, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["enjoy", "ppo", "Hopper", "--human"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [
        "error: render_mode 'human' needs a display (no DISPLAY or WAYLAND_DISPLAY here); render offscreen "
        "with render_mode='rgb_array'"
    ]
