"""The kit inside a researcher's own project: a lean core (the book stack is the ``[book]`` extra), no
process-wide rendering setting on import, and a built wheel, installed into a fresh venv without the clone,
that scores a model against the checkout's shipped runs or says in one line where they are expected.

The wheel test does not resolve dependencies: its venv reuses this venv's installed packages (one ``.pth``
line) less the book stack, so it checks the wheel's contents, its console script and the
lean import graph, not what pip would pick beside a project pinned to other versions.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
import sysconfig
import tomllib
from pathlib import Path

import pytest

import thesis_repro

ROOT = Path(thesis_repro.__file__).resolve().parents[1]
#: The book stack: what a lean install must not pull in (the ``[book]`` extra has it).
BOOK_STACK = ("papermill", "jupytext", "nbclient", "ipykernel", "jupyter-book", "jupyter_book", "jupyter-client")
#: Import names (and distribution folders) left out of the wheel's venv, as if the ``[book]`` extra were not
#: installed.
HIDDEN = ("papermill", "jupytext", "nbclient", "ipykernel", "jupyter_book", "jupyter_client", "nbformat")


def _requirement_name(req: str) -> str:
    return re.split(r"[\[<>=!~;\s]", req, maxsplit=1)[0].lower()


def test_the_core_dependencies_leave_the_book_stack_to_an_extra():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    core = {_requirement_name(r) for r in project["dependencies"]}
    assert not core & set(BOOK_STACK), f"the book stack belongs in the [book] extra: {sorted(core & set(BOOK_STACK))}"
    book = {_requirement_name(r) for r in project["optional-dependencies"]["book"]}
    assert {"papermill", "jupytext", "ipykernel", "jupyter-book"} <= book
    floating = {_requirement_name(r): r for r in project["dependencies"]}
    assert floating["torch"].startswith("torch>=2") and "<3" in floating["torch"]  # any torch 2.x
    assert ">=1" in floating["gymnasium"] and "<2" in floating["gymnasium"]  # any gymnasium 1.x
    makefile = (ROOT / "Makefile").read_text()
    assert '-e ".[dev,video,book]"' in makefile  # make venv (and so make test, make book) installs the book


def test_import_sets_no_mujoco_gl_and_rendering_sets_it():
    code = (
        "import os; os.environ.pop('MUJOCO_GL', None)\n"
        "import thesis_repro, thesis_repro.envs, thesis_repro.book.agent, thesis_repro.book.clips\n"
        "print(os.environ.get('MUJOCO_GL'))\n"
        "from thesis_repro.envs import prepare_render\n"
        "prepare_render('rgb_array'); print(os.environ.get('MUJOCO_GL'))\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["None", "egl"]


def test_human_rendering_without_a_display_is_one_line(monkeypatch):
    import gymnasium as gym

    import thesis_repro.envs  # noqa: F401 - registers the ids

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(ValueError, match=r"^render_mode 'human' needs a display .*render_mode='rgb_array'$"):
        gym.make("thesis_repro/Hopper-obs-v0", sigma=0.1, render_mode="human")


def test_a_kit_outside_its_clone_keeps_runs_in_the_user_cache(monkeypatch, tmp_path):
    from thesis_repro.core import paths

    monkeypatch.setattr(paths, "ROOT", tmp_path / "site-packages")
    monkeypatch.delenv("THESIS_REPRO_DATA")
    monkeypatch.delenv("THESIS_REPRO_BUILD")
    monkeypatch.delenv("THESIS_REPRO_REFERENCE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert not paths.in_clone()
    assert paths.runs_dir() == tmp_path / "cache" / "thesis_repro" / "runs"
    assert paths.build_dir("small") == tmp_path / "cache" / "thesis_repro" / "build" / "small"
    assert paths.reference_note() == (
        "no shipped runs in this install (pip installs the code alone): clone the kit and set "
        "THESIS_REPRO_REFERENCE=<clone>/data/reference"
    )


def _venv_with_the_wheel(tmp: Path) -> Path:
    """Build the wheel from a copy of the package (nothing written into the checkout), install it into a fresh
    venv with pip ``--no-deps``, then let that venv see this venv's packages, the book stack left out."""
    src = tmp / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        (src / name).write_bytes((ROOT / name).read_bytes())
    subprocess.run(["cp", "-r", str(ROOT / "thesis_repro"), str(src)], check=True)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    wheel = [*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", str(tmp / "dist"), str(src)]
    subprocess.run(wheel, check=True, capture_output=True)
    (whl,) = (tmp / "dist").glob("thesis_repro-*.whl")
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    py = venv / "bin" / "python"
    subprocess.run([*pip, "--python", str(py), "install", "--no-deps", "--no-index", str(whl)], check=True)
    site = Path(
        subprocess.check_output(
            [str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], text=True
        ).strip()
    )
    # this venv's packages, less the book stack and the clone's own install (its editable finder), as links in a
    # folder that one .pth line puts after the wheel's site-packages
    deps = tmp / "dependencies"
    deps.mkdir()
    for entry in Path(sysconfig.get_paths()["purelib"]).iterdir():
        if not entry.name.lower().startswith((*HIDDEN, "thesis_repro", "__editable__")):
            (deps / entry.name).symlink_to(entry)
    (site / "zz_dependencies.pth").write_text(f"{deps}\n")
    return venv


def test_a_built_wheel_scores_against_the_checkouts_shipped_runs(tmp_path):
    layer = ROOT / "data" / "reference"
    if not (layer / "evaluate").is_dir():
        pytest.skip("no shipped evaluations (data/reference/evaluate)")
    if importlib.util.find_spec("setuptools") is None:
        pytest.skip("no setuptools in this venv to build the wheel offline (--no-build-isolation)")
    from stable_baselines3 import PPO

    venv = _venv_with_the_wheel(tmp_path)
    work = tmp_path / "elsewhere"  # outside the checkout: nothing of the clone on the path
    work.mkdir()
    PPO("MlpPolicy", "InvertedPendulum-v5", n_steps=64, batch_size=32, seed=0, device="cpu").save(work / "model.zip")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("THESIS_REPRO_", "PYTHONPATH", "MUJOCO_GL"))}
    env.update(XDG_CACHE_HOME=str(tmp_path / "cache"), COLUMNS="80")
    cli = [str(venv / "bin" / "thesis-repro")]

    def run(*args: str, **extra: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([*cli, *args], capture_output=True, text=True, cwd=work, env={**env, **extra})

    imported = subprocess.run(
        [str(venv / "bin" / "python"), "-c", "import thesis_repro, os; print(thesis_repro.__file__)"],
        capture_output=True,
        text=True,
        cwd=work,
        env=env,
    )
    assert str(venv) in imported.stdout, imported.stdout + imported.stderr  # the wheel's copy, not the clone's

    score = ["score", "model.zip", "--task", "InvertedPendulum", "--scale", "small"]
    missing = run(*score)
    assert missing.returncode == 2 and missing.stdout == ""
    assert missing.stderr == (
        "error: no shipped runs in this install (pip installs the code alone): clone the kit and set "
        "THESIS_REPRO_REFERENCE=<clone>/data/reference (or score with --no-compare)\n"
    )
    done = run(*score, THESIS_REPRO_REFERENCE=str(layer))
    assert done.returncode == 0, done.stderr
    assert "your agent" in done.stdout and "ppo " in done.stdout and "sac " in done.stdout
    assert all(len(line) <= 80 for line in done.stdout.splitlines())

    listed = run("list")
    assert listed.returncode == 0 and "table-3.4" in listed.stdout
    assert "notebooks: none in this install" in listed.stdout
    figure = run("figure", "3.3", "--scale", "small")
    assert figure.returncode == 1
    assert figure.stderr.startswith("error: executing notebooks needs the book extra (papermill")
    assert len(figure.stderr.splitlines()) == 1
