"""Shared fixtures: every test gets its own empty run cache and build folder."""

from __future__ import annotations

import os

import pytest

import thesis_repro  # noqa: F401 - sets the pinned numerics before any test imports torch


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "retrains: retrains a shipped run and compares it (a minute or more); `make test` runs it, CI's retrain, "
        "and `make test-verify` runs it alone",
    )


@pytest.fixture
def shipped(monkeypatch):
    """The real shipped layer (data/reference: runs, claims snapshot, calibration) instead of the empty one each test
    gets, as a fresh clone reads it; skips where no evaluation is shipped."""
    from thesis_repro.core import paths

    layer = paths.ROOT / "data" / "reference"
    if not (layer / "evaluate").is_dir():
        pytest.skip("no shipped evaluations (data/reference/evaluate)")
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(layer))
    return layer


#: The xdist group of every test that reads :func:`snapshot_ledger`: one process judges it once for all of them.
SNAPSHOT_LEDGER_GROUP = "snapshot-ledger"


@pytest.fixture(scope="session")
def snapshot_ledger(tmp_path_factory) -> tuple:
    """Every claim judged from the real shipped snapshot with its shipped calibration, as a fresh clone's
    ``claims --scale small`` judges it (:func:`thesis_repro.claims.results.snapshot_ledger`): half a minute of
    judging, done once per pytest process for every test that reads it (they share the xdist group
    :data:`SNAPSHOT_LEDGER_GROUP`). Read-only: a tuple of the ledger's rows."""
    from thesis_repro.claims import results
    from thesis_repro.core import paths

    layer = paths.ROOT / "data" / "reference"
    if not (layer / "evaluate").is_dir():
        pytest.skip("no shipped evaluations (data/reference/evaluate)")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("THESIS_REPRO_REFERENCE", str(layer))
        mp.setenv("THESIS_REPRO_DATA", str(tmp_path_factory.mktemp("snapshot-ledger-runs")))
        mp.delenv("THESIS_REPRO_RETRAIN", raising=False)
        return tuple(results.snapshot_ledger("small"))


@pytest.fixture(scope="session", autouse=True)
def _shared_stamps(tmp_path_factory):
    """One folder of computed module hashes for the whole session (``make test`` names it for every worker and
    subprocess): each test's fresh build folder would otherwise hash the kit's modules again. The entries are
    content-addressed, so sharing them changes no stamp."""
    from thesis_repro.core import stamps

    if os.environ.get(stamps.STAMPS_ENV):
        yield
        return
    os.environ[stamps.STAMPS_ENV] = str(tmp_path_factory.mktemp("stamps"))
    yield
    os.environ.pop(stamps.STAMPS_ENV, None)


@pytest.fixture(autouse=True)
def _isolated_dirs(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("THESIS_REPRO_DATA", str(tmp_path_factory.mktemp("runs")))
    monkeypatch.setenv("THESIS_REPRO_BUILD", str(tmp_path_factory.mktemp("build")))
    # the shipped layer is the real data/reference only where a test asks for it (tests/test_shipped.py)
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(tmp_path_factory.mktemp("reference")))
    monkeypatch.delenv("THESIS_REPRO_RETRAIN", raising=False)
    # SB3's default logger makes an SB3-<timestamp> folder in the system temp dir per learn(); keep them in pytest's
    monkeypatch.setenv("SB3_LOGDIR", str(tmp_path_factory.mktemp("sb3-log")))
    # pytest-xdist's workers set COLUMNS=80: each test starts without it, its output not a terminal's (lines whole,
    # thesis_repro.core.terminal); the tests of the terminal's width set COLUMNS themselves
    monkeypatch.delenv("COLUMNS", raising=False)


@pytest.fixture(autouse=True)
def _default_sigint():
    """Each test starts and ends with Python's own Ctrl-C handling. A test that leaves SIGINT ignored in this
    process hands SIG_IGN to every subprocess started later (ignored signals survive exec), and the Ctrl-C tests
    of tests/test_faults.py then wait in vain: in a full run SIGINT was found ignored after the tests before them."""
    import signal

    signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, signal.default_int_handler)


#: Work that takes minutes, longest first (`make test`'s --durations): `pytest -n 2 --dist loadgroup
#: --no-loadscope-reorder` hands the two processes work in collection order, so these start at once instead of
#: last (a long test started late is the run's tail). An xdist group is named as such, a test by its node id prefix.
LONGEST_FIRST: tuple[str, ...] = (
    "group:smoke",  # the smoke notebooks and the smoke book in Chromium (minutes)
    "group:claims-seeds",  # every claim judged three times
    "tests/test_claims_snapshot.py::test_the_snapshot_judges_every_claim_exactly_as_the_build_it_was_shipped_from",
    "group:" + SNAPSHOT_LEDGER_GROUP,
    "tests/test_install.py::test_a_built_wheel_scores_against_the_checkouts_shipped_runs",
    "tests/test_shipped.py::test_cheapest_shipped_run_retrains_to_the_same_policy",
    "tests/test_budget_study.py::test_an_interrupted_study_run_resumes_to_the_same_snapshots",
    "tests/test_claims.py::test_null_calibration",
    "group:ray",
    "tests/test_faults.py::test_interrupting_a_real_figure_in_its_pool_is_one_line",
    "tests/test_quiet.py::test_a_smoke_figure_run_is_quiet_and_leaves_no_litter",
    "group:evaluation",
    "tests/test_verify.py",
)


def _groups(item: pytest.Item) -> set[str]:
    return {str(m.args[0] if m.args else m.kwargs.get("name", "default")) for m in item.iter_markers("xdist_group")}


def _rank(item: pytest.Item) -> int:
    groups = _groups(item)
    for i, key in enumerate(LONGEST_FIRST):
        if key.startswith("group:") and groups == {key[6:]}:
            return i
        if not key.startswith("group:") and item.nodeid.split("@")[0].startswith(key):
            return i
    return len(LONGEST_FIRST)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Run :data:`LONGEST_FIRST` first (stable: everything else keeps its order)."""
    items.sort(key=_rank)
