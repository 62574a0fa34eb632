"""Shared fixtures: every test gets its own empty run cache and build folder."""

from __future__ import annotations

import pytest

import thesis_repro  # noqa: F401 - sets MUJOCO_GL before any test imports mujoco


@pytest.fixture(autouse=True)
def _isolated_dirs(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("THESIS_REPRO_DATA", str(tmp_path_factory.mktemp("runs")))
    monkeypatch.setenv("THESIS_REPRO_BUILD", str(tmp_path_factory.mktemp("build")))
    # the shipped layer is the real data/reference only where a test asks for it (tests/test_shipped.py)
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(tmp_path_factory.mktemp("reference")))
    monkeypatch.delenv("THESIS_REPRO_RETRAIN", raising=False)
    # SB3's default logger makes an SB3-<timestamp> folder in the system temp dir per learn(); keep them in pytest's
    monkeypatch.setenv("SB3_LOGDIR", str(tmp_path_factory.mktemp("sb3-log")))


@pytest.fixture(autouse=True)
def _default_sigint():
    """Each test starts and ends with Python's own Ctrl-C handling. A test that leaves SIGINT ignored in this
    process hands SIG_IGN to every subprocess started later (ignored signals survive exec), and the Ctrl-C tests
    of tests/test_faults.py then wait in vain: in a full run SIGINT was found ignored after the tests before them."""
    import signal

    signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, signal.default_int_handler)
