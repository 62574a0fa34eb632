"""Failures a user can cause: one ``error:`` line (never a traceback) and a non-zero exit code; Ctrl-C exits
130 with "interrupted; rerun to resume"; a failed or interrupted run leaves the previous outputs intact and
no kernel files behind; ``runs --check`` and ``runs X.Y`` catch corrupt entries.

The notebook runs use a toy notebook (``fig-9.1``, seconds each) in a temporary notebooks folder.
"""

from __future__ import annotations

import asyncio
import errno
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
import types
from pathlib import Path

import pytest

from thesis_repro import figures
from thesis_repro.book import notebook_kernel, notebooks
from thesis_repro.cli.commands import INTERRUPTED, main
from thesis_repro.core import backends, paths
from thesis_repro.core.cache import Job, RunCache
from thesis_repro.runs import layer as runs
from thesis_repro.runs import shipped_checks

TOY = """# %% tags=["parameters"]
SCALE = "small"
MODE = "ok"
MARKER = ""

# %%
import time
from pathlib import Path

from thesis_repro.core import paths
from thesis_repro.claims import report

out = paths.figures_dir(SCALE) / "fig-9.1.png"
out.parent.mkdir(parents=True, exist_ok=True)
out.write_text(f"figure {MODE}")
print("saved", out)
report.report("fig-9.1", SCALE, [report.Verdict("9.1", "toy claim", report.NOT_JUDGED, MODE)], display=False)
if MODE == "fail":
    raise ValueError("the toy notebook failed on purpose")
if MODE == "slow":
    Path(MARKER).write_text("started")
    time.sleep(120)
"""

DRIVER = """import sys
from pathlib import Path

from thesis_repro.core import paths

paths.NOTEBOOKS = Path(sys.argv[1])
from thesis_repro.cli.commands import main

sys.exit(main(sys.argv[2:]))
"""


def error_lines(err: str) -> list[str]:
    """Non-empty stderr lines; asserts that none is a traceback."""
    assert "Traceback" not in err, err
    return [ln for ln in err.splitlines() if ln.strip()]


def assert_one_error(err: str, *needles: str) -> str:
    lines = error_lines(err)
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def toy(tmp_path, monkeypatch) -> Path:
    """A notebooks folder holding only the toy notebook ``fig-9.1``."""
    folder = tmp_path / "notebooks"
    folder.mkdir()
    (folder / "fig-9.1.py").write_text(TOY)
    monkeypatch.setattr(paths, "NOTEBOOKS", folder)
    return folder


def outputs(scale: str = "smoke") -> dict[str, bytes]:
    """The toy notebook's executed copy, figure and verdicts."""
    files = [notebooks.executed_path("9.1", scale), paths.figures_dir(scale) / "fig-9.1.png"]
    files.append(paths.figures_dir(scale) / "fig-9.1.verdicts.json")
    return {p.name: p.read_bytes() for p in files}


def leftovers() -> list[Path]:
    """Staging folders of the build (none may outlive a run)."""
    return sorted(paths.build_dir("smoke").parent.glob(".staging-*"))


# ---------------------------------------------------------------- notebook failures
def test_failed_notebook_is_one_line_and_leaves_the_previous_outputs_intact(toy, capsys):
    assert main(["figure", "9.1", "--scale", "smoke"]) == 0
    good = outputs()
    assert good["fig-9.1.png"] == b"figure ok"
    # the executed notebook names the figure where it is, not where the kernel wrote it (the staging folder)
    assert f"saved {paths.figures_dir('smoke') / 'fig-9.1.png'}" in good["fig-9.1.ipynb"].decode()
    assert ".staging-" not in good["fig-9.1.ipynb"].decode()
    capsys.readouterr()
    # the failing run writes its figure and verdicts before it raises: staged, never swapped in
    assert main(["figure", "9.1", "--scale", "smoke", "-p", "MODE", "fail"]) == 1
    line = assert_one_error(
        capsys.readouterr().err, "notebook fig-9.1 failed: ValueError: the toy notebook failed on purpose"
    )
    assert "PapermillExecutionError" not in line and "fig-9.1.failed.ipynb" in line
    assert outputs() == good
    failed = json.loads(notebooks.failed_path("9.1", "smoke").read_text())
    assert any(o.get("ename") == "ValueError" for c in failed["cells"] for o in c.get("outputs", []))
    assert leftovers() == []
    assert notebooks.is_current("9.1", "smoke")  # the good executed copy still serves the book
    # a later successful run removes the failed copy
    assert main(["figure", "9.1", "--scale", "smoke"]) == 0
    assert not notebooks.failed_path("9.1", "smoke").exists()


def test_an_unknown_notebook_parameter_is_an_error(toy, capsys):
    assert main(["figure", "9.1", "--scale", "smoke", "-p", "NOSUCH", "1"]) == 2
    assert_one_error(capsys.readouterr().err, "unknown parameter 'NOSUCH' of notebook fig-9.1", "MODE, MARKER")
    assert not (paths.figures_dir("smoke") / "fig-9.1.png").exists()  # nothing ran


def test_a_scale_parameter_cannot_override_the_scale(toy, capsys, monkeypatch):
    ran = []
    monkeypatch.setattr(notebooks, "execute_notebook", lambda *a, **k: ran.append(a))
    assert main(["figure", "9.1", "--scale", "smoke", "-p", "SCALE", "full"]) == 2
    assert_one_error(capsys.readouterr().err, "SCALE='full'", "'smoke'", "--scale")
    assert ran == []
    assert main(["figure", "9.1", "--scale", "smoke", "-p", "SCALE", "smoke", "-p", "SEEDS", "2"]) == 0
    assert ran == [("9.1", "smoke", {"SEEDS": 2})]
    monkeypatch.undo()
    with pytest.raises(ValueError, match="differs from the scale"):
        notebooks.execute_notebook("3.3", "smoke", {"SCALE": "small"})


# ---------------------------------------------------------------- interrupts and kills
def start_slow_run(tmp_path: Path, toy: Path) -> tuple[subprocess.Popen, dict[str, str], Path]:
    """The CLI running the toy notebook in its slow mode (a subprocess with a private temp folder); returns
    once the notebook's cell is running."""
    driver, marker, private_tmp = tmp_path / "driver.py", tmp_path / "started", tmp_path / "tmp"
    driver.write_text(DRIVER)
    private_tmp.mkdir(exist_ok=True)
    env = {**os.environ, "TMPDIR": str(private_tmp), "PYTHONUNBUFFERED": "1"}
    cmd = [sys.executable, str(driver), str(toy), "figure", "9.1", "--scale", "smoke"]
    proc = subprocess.Popen(
        [*cmd, "-p", "MODE", "slow", "-p", "MARKER", str(marker)],
        env=env,
        cwd=paths.ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.time() + 60
    while not marker.exists():
        if proc.poll() is not None or time.time() > deadline:
            proc.kill()
            pytest.fail(f"the slow toy run did not start: {proc.communicate()}")
        time.sleep(0.1)
    return proc, env, private_tmp


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_interrupt_exits_cleanly_and_keeps_the_previous_outputs(toy, tmp_path, capsys, sig, code):
    assert main(["figure", "9.1", "--scale", "smoke"]) == 0
    good = outputs()
    proc, _, private_tmp = start_slow_run(tmp_path, toy)
    assert sorted(p.name for p in private_tmp.glob("thesis-repro-kernel-*"))  # the kernel's files exist
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert error_lines(err) == [INTERRUPTED]
    assert outputs() == good
    assert leftovers() == []
    assert sorted(private_tmp.iterdir()) == [], "kernel connection or socket files left behind"


def descendants(pid: int) -> list[int]:
    """Live descendants of ``pid`` (Linux ``/proc``): a figure's kernel runs in a session of its own, and its
    pool's workers in the kernel's."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z":
            children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    found, todo = [], [pid]
    while todo:
        kids = children.get(todo.pop(), [])
        found += kids
        todo += kids
    return found


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


PROGRESS = re.compile(r"it/s\]|s/it\]|\d%\|")


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_interrupting_a_real_figure_in_its_pool_is_one_line(tmp_path, sig, code):
    """Fig 3.3 at smoke scale with its training in a pool of 2 workers (the path of every figure at ``small``),
    interrupted while the pool trains: the right code, the notebook's progress bars and then one line on its
    own, no traceback nor asyncio's "Task exception was never retrieved ... BrokenProcessPool"; no kernel or
    worker outlives the run."""
    folder = tmp_path / "notebooks"
    folder.mkdir()
    text = paths.notebook("fig-3.3").read_text()
    line = 'settings = figures.settings("3.3", SCALE)'
    assert line in text
    (folder / "fig-3.3.py").write_text(text.replace(line, line[:-1] + ", n_jobs=2)"))  # smoke runs in-process
    driver, log = tmp_path / "driver.py", tmp_path / "stderr"
    driver.write_text(DRIVER)
    private_tmp = tmp_path / "tmp"
    private_tmp.mkdir()
    env = {**os.environ, "TMPDIR": str(private_tmp), "PYTHONUNBUFFERED": "1"}
    with log.open("w") as err_file:
        proc = subprocess.Popen(
            [sys.executable, str(driver), str(folder), "figure", "3.3", "--scale", "smoke"],
            env=env,
            cwd=paths.ROOT,
            stdout=subprocess.DEVNULL,
            stderr=err_file,
            text=True,
        )
    try:
        deadline = time.time() + 300  # a kernel and two workers importing torch, on a busy machine
        while len(descendants(proc.pid)) < 4 or "train (" not in log.read_text():  # kernel, 2 workers (+ tracker)
            if proc.poll() is not None or time.time() > deadline:
                pytest.fail(f"the figure's pool did not start: exit {proc.poll()}, stderr {log.read_text()[-2000:]}")
            time.sleep(0.1)
        family = descendants(proc.pid)
        proc.send_signal(sig)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = log.read_text()
    assert proc.returncode == code, err[-3000:]
    assert err.endswith(f"\n{INTERRUPTED}\n"), err[-3000:]  # on a line of its own
    lines = [ln for ln in err.replace("\r", "\n").splitlines() if ln.strip()]
    assert lines[-1] == INTERRUPTED
    assert [ln for ln in lines[:-1] if not PROGRESS.search(ln)] == [], err[-3000:]  # nothing but progress bars
    deadline = time.time() + 30
    while any(_alive(p) for p in family) and time.time() < deadline:
        time.sleep(0.2)
    survivors = [p for p in family if _alive(p)]
    for p in survivors:
        os.kill(p, signal.SIGKILL)
    assert survivors == [], "a kernel or worker outlived the interrupted figure"


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_an_interrupted_run_kills_its_kernel_instead_of_asking_it_to_shut_down(monkeypatch, sig):
    """The interrupt passes through nbclient's cleanup before the command line's: that cleanup used to ask the
    busy kernel to shut down, which ended its pool's workers itself (the cell then raised BrokenProcessPool)
    and, exiting, wrote asyncio's "Task was destroyed but it is pending!" onto the shared terminal."""
    from jupyter_client import AsyncKernelManager

    from thesis_repro.cli.commands import _signals_as_interrupts

    async def polite(*args, **kwargs):
        pytest.fail("the interrupted kernel was asked to shut down")

    killed = []
    monkeypatch.setattr(AsyncKernelManager, "_async_shutdown_kernel", polite)
    monkeypatch.setattr(notebook_kernel.QuietKernelManager, "kill_now", lambda self, grace=2.0: killed.append(self))
    km = notebook_kernel.QuietKernelManager()
    with pytest.raises(KeyboardInterrupt), _signals_as_interrupts(), notebook_kernel.noting_interrupts():
        try:
            os.kill(os.getpid(), sig)
            time.sleep(5)  # not reached
        finally:
            asyncio.run(km.shutdown_kernel())  # what nbclient's setup_kernel does on the interrupt's way out
    assert killed == [km]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler and notebook_kernel._INTERRUPTED == []


def test_a_killed_kernel_says_nothing_more(capfd):
    """The kernel's stderr reaches ours through a relay, until this process kills the kernel: what its dying
    family writes then (the pool's resource tracker warns of the semaphores it cleans up) is dropped."""
    km = notebook_kernel.QuietKernelManager()
    read, write = os.pipe()
    relay = threading.Thread(target=km._relay, args=(read,))
    relay.start()
    os.write(write, b"a kernel's own line\n")
    deadline = time.time() + 10
    while "a kernel's own line" not in capfd.readouterr().err:
        assert time.time() < deadline, "the kernel's stderr was not relayed"
        time.sleep(0.05)
    km.kill_now()
    os.write(write, b"resource_tracker: There appear to be 5 leaked semaphore objects\n")
    os.close(write)
    relay.join(10)
    assert not relay.is_alive() and capfd.readouterr().err == ""


def test_kernel_files_of_a_killed_run_are_removed_by_the_next_run(toy, tmp_path, monkeypatch):
    assert main(["figure", "9.1", "--scale", "smoke"]) == 0
    good = outputs()
    proc, _, private_tmp = start_slow_run(tmp_path, toy)
    proc.kill()  # SIGKILL: nothing of the CLI's own cleanup can run
    proc.communicate(timeout=60)
    stale = sorted(p.name for p in private_tmp.glob("thesis-repro-kernel-*"))
    assert f"thesis-repro-kernel-{proc.pid}-1.json" in stale
    assert leftovers(), "the killed run's staging folder should still be there"
    assert outputs() == good
    monkeypatch.setattr(tempfile, "tempdir", str(private_tmp))
    removed = notebooks.clean_stale(paths.build_dir("smoke").parent)  # what the next execute_notebook() does first
    assert len(removed) == len(stale) + 1
    assert sorted(private_tmp.glob("thesis-repro-kernel-*")) == [] and leftovers() == []


SLEEPY = """import os
import time
from pathlib import Path


def sleepy(config, workdir):
    (Path(config["marker"]) / str(os.getpid())).write_text("")
    time.sleep(300)
    return {"ok": 1}
"""

REF_DRIVER = """import faulthandler
import signal
import sys

from thesis_repro import figures
from thesis_repro.core import job_kinds
from thesis_repro.core.cache import Job

job_kinds.register("sleepy", "sleepy_jobs:sleepy")

if __name__ == "__main__":
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # the test's dump of every thread if it hangs
    figures.FIGURES.clear()
    figures.TRAINING_KINDS = ("sleepy",)
    grid = [Job("sleepy", {"seed": i, "marker": sys.argv[1]}) for i in range(3)]
    figures.register_figure("9.1", "toy", kinds=["sleepy"], settings_id="_example")(lambda scale: grid)
    from thesis_repro.cli.commands import main

    sys.exit(main(["reference-runs", "--scale", "smoke", "--kind", "sleepy", "--jobs", "2", "--figures", "9.1"]))
"""


def session_processes(sid: int) -> list[int]:
    """Pids of the live processes of session ``sid`` (Linux ``/proc``)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[3]) == sid and fields[0] != "Z":
            found.append(int(stat.parent.name))
    return found


def test_a_ctrl_c_while_workers_spawn_is_deferred_not_lost():
    """The generator holds SIGINT while it spawns workers (so they start deaf to it). A Ctrl-C in that window
    used to vanish (it was ignored) and leave the generator waiting on its runs (CI after stop 34); now it is raised
    by the window's end at the latest."""
    with pytest.raises(KeyboardInterrupt):
        with backends.interrupts_held():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
        time.sleep(5)  # not reached
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, set())


def _raised_at_the_windows_end(sig: int, raised: type[BaseException]) -> None:
    """``sig`` sent to this process inside :func:`backends.interrupts_held` raises ``raised`` at the block's end,
    not inside it."""
    reached = False
    with pytest.raises(raised):
        with backends.interrupts_held():
            os.kill(os.getpid(), sig)
            time.sleep(0.2)
            reached = True
        time.sleep(5)  # not reached
    assert reached


def test_a_ctrl_c_another_thread_takes_still_waits_for_the_spawn_window_to_end():
    """With a pool's manager thread alive, a Ctrl-C is delivered to that thread (the spawning one blocks it), and
    Python used to raise it in the main thread at once, inside the window: between starting a worker and handing
    it its job (the worker then printed "EOFError: Ran out of input", seen in CI). It waits for the end."""
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)  # does not block SIGINT, as the pool's threads do not
    other.start()
    try:
        _raised_at_the_windows_end(signal.SIGINT, KeyboardInterrupt)
    finally:
        stop.set()
        other.join()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_sigterm_in_the_spawn_window_waits_for_its_end():
    """SIGTERM, which the command line raises as `Terminated`, is held by the same window as Ctrl-C."""

    class Ended(Exception):
        pass

    def end(signum, _frame):
        raise Ended(signum)

    before = signal.signal(signal.SIGTERM, end)
    try:
        _raised_at_the_windows_end(signal.SIGTERM, Ended)
        assert signal.getsignal(signal.SIGTERM) is end
    finally:
        signal.signal(signal.SIGTERM, before)


def test_ctrl_c_stops_a_parallel_reference_run_at_once(tmp_path):
    """`make reference-runs JOBS=2`, Ctrl-C while its workers start: the terminal interrupts the whole process
    group; the workers print nothing and are ended, no queued run starts, and the generator exits 130 at once
    (leaving its pool's ``with`` block used to wait for every running and queued run to finish)."""
    (tmp_path / "sleepy_jobs.py").write_text(SLEEPY)
    (tmp_path / "drive_ref.py").write_text(REF_DRIVER)
    marker, log = tmp_path / "started", tmp_path / "stdout"
    marker.mkdir()
    env = {**os.environ, "PYTHONPATH": str(tmp_path), "THESIS_REPRO_REFERENCE": str(tmp_path / "layer")}
    with log.open("w") as out:
        proc = subprocess.Popen(
            [sys.executable, str(tmp_path / "drive_ref.py"), str(marker)],
            env={**env, "PYTHONUNBUFFERED": "1"},
            cwd=paths.ROOT,
            start_new_session=True,
            stdout=out,
            stderr=subprocess.PIPE,
            text=True,
        )
    deadline = time.time() + 120
    while "running 3 jobs, 2 at a time" not in log.read_text():  # the workers are starting
        if proc.poll() is not None or time.time() > deadline:
            os.killpg(proc.pid, signal.SIGKILL)
            pytest.fail(f"the generator did not start its workers: {proc.communicate()}")
        time.sleep(0.05)
    deadline = time.time() + 60  # the line is printed as the pool starts: its workers may still be spawning
    while len(session_processes(proc.pid)) < 3 and time.time() < deadline:
        time.sleep(0.05)
    assert len(session_processes(proc.pid)) >= 3  # the generator and its two workers
    os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C in a terminal does
    try:  # "at once": well inside the 300 s the sleepy runs would take (60 s leaves room for a loaded machine)
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.kill(proc.pid, signal.SIGUSR1)  # every thread's stack to stderr (faulthandler), then kill
        time.sleep(1)
        os.killpg(proc.pid, signal.SIGKILL)
        _, err = proc.communicate()
        pytest.fail(f"the generator did not stop after Ctrl-C; its log:\n{log.read_text()}\nits stderr:\n{err}")
    assert proc.returncode == 130, err
    assert error_lines(err) == [INTERRUPTED]
    deadline = time.time() + 10
    while session_processes(proc.pid) and time.time() < deadline:
        time.sleep(0.1)
    assert session_processes(proc.pid) == [], "workers outlived the generator"
    assert list(marker.iterdir()) == [], "a run started after Ctrl-C"


def test_keyboard_interrupt_anywhere_is_one_line_and_code_130(monkeypatch, capsys):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(notebooks, "execute_notebook", interrupted)
    assert main(["figure", "3.3", "--scale", "smoke"]) == 130
    err = capsys.readouterr().err
    assert error_lines(err) == [INTERRUPTED]
    assert err.endswith(f"\n{INTERRUPTED}\n")  # on its own line, even after a progress bar's unfinished one


# ---------------------------------------------------------------- folders and settings
def _must_not_run(*args, **kwargs):
    pytest.fail("the command ran although its settings are invalid")


def test_build_path_that_is_a_file(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(notebooks, "execute_notebook", _must_not_run)
    (tmp_path / "a-file").write_text("")
    monkeypatch.setenv("THESIS_REPRO_BUILD", str(tmp_path / "a-file"))
    assert main(["figure", "3.3", "--scale", "smoke"]) == 1
    assert_one_error(capsys.readouterr().err, str(tmp_path / "a-file"), "THESIS_REPRO_BUILD", "cannot be written")


def _read_only_folder(tmp_path: Path) -> Path:
    """A folder this process cannot write to (chmod; as root, which ignores modes, a read-only filesystem)."""
    folder = tmp_path / "read-only"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        (folder / "probe").write_text("")
    except OSError:
        return folder / "runs"
    (folder / "probe").unlink()
    candidate = Path("/sys/thesis-repro-test-runs")  # sysfs: read-only, also for root
    try:
        candidate.mkdir()
    except OSError:
        return candidate
    candidate.rmdir()
    pytest.skip("no unwritable folder available")


@pytest.mark.parametrize("setting", ["THESIS_REPRO_DATA", "THESIS_REPRO_BUILD"])
def test_unwritable_data_or_build_folder(monkeypatch, tmp_path, capsys, setting):
    monkeypatch.setattr(notebooks, "execute_notebook", _must_not_run)
    folder = _read_only_folder(tmp_path)
    monkeypatch.setenv(setting, str(folder))
    try:
        assert main(["figure", "3.3", "--scale", "smoke"]) == 1
    finally:
        (tmp_path / "read-only").chmod(0o700)
    assert_one_error(capsys.readouterr().err, str(folder), setting, "cannot be written")


def test_full_disk(monkeypatch, capsys):
    full = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def no_space(fd):
        raise full

    monkeypatch.setattr(notebooks, "execute_notebook", _must_not_run)
    with monkeypatch.context() as m:
        m.setattr(os, "fsync", no_space)  # the write probe of the run cache hits a full disk
        assert main(["figure", "3.3", "--scale", "smoke"]) == 1
    assert_one_error(capsys.readouterr().err, str(paths.runs_dir()), "THESIS_REPRO_DATA", "No space left on device")
    # a full disk while the notebook's outputs are written
    target = notebooks.executed_path("3.3", "smoke")

    def writes_fail(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(target))

    monkeypatch.setattr(notebooks, "execute_notebook", writes_fail)
    assert main(["figure", "3.3", "--scale", "smoke"]) == 1
    assert_one_error(capsys.readouterr().err, f"{target} (the build folder, THESIS_REPRO_BUILD): No space left")


def test_a_full_disk_during_a_commit_names_the_entry(monkeypatch, capsys):
    from thesis_repro.cli.commands import _guarded
    from thesis_repro.core import cache as cache_mod

    def no_space(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # as a write() reports it: no file name

    monkeypatch.setattr(cache_mod, "write_manifest", no_space)
    runs_dir = paths.runs_dir()
    assert _guarded(lambda: RunCache(runs_dir, reference=False).run(Job("square", {"x": 3}))) == 1
    line = assert_one_error(capsys.readouterr().err, str(runs_dir), "(the run cache, THESIS_REPRO_DATA)", "No space")
    assert "/.tmp-" in line and "Errno" not in line


@pytest.mark.parametrize("value", ["x", "0", "-2", "1.5", ""])
def test_bad_thesis_repro_jobs(monkeypatch, capsys, value):
    monkeypatch.setattr(notebooks, "execute_notebook", _must_not_run)
    monkeypatch.setenv("THESIS_REPRO_JOBS", value)
    assert main(["figure", "3.3", "--scale", "smoke"]) == 2
    assert_one_error(capsys.readouterr().err, "THESIS_REPRO_JOBS", repr(value), "valid values are integers >= 1")


@pytest.mark.parametrize("value", ["0", "-1", "two"])
def test_bad_jobs_argument(monkeypatch, capsys, value):
    monkeypatch.setattr(notebooks, "execute_notebook", _must_not_run)
    assert main(["figure", "3.3", "--scale", "smoke", "--jobs", value]) == 2
    assert_one_error(capsys.readouterr().err, "--jobs", repr(value), "valid values are integers >= 1")
    assert main(["plan", "3.3", "--cores", value]) == 2
    assert_one_error(capsys.readouterr().err, "--cores", "integers >= 1")


def test_usage_errors_are_one_line(capsys):
    assert main([]) == 2
    assert_one_error(capsys.readouterr().err, "required")
    assert main(["figure", "9.99", "--scale", "smoke"]) == 2
    assert_one_error(capsys.readouterr().err, "unknown figure '9.99'")
    assert main(["figure", "3.3", "--scale", "huge"]) == 2
    assert_one_error(capsys.readouterr().err, "unknown scale 'huge'")


def test_cli_subprocess_bad_jobs_is_one_line(tmp_path):
    """The real command line (what `make figure-3.3 JOBS=0` runs)."""
    cmd = [sys.executable, "-m", "thesis_repro", "figure", "3.3", "--scale", "smoke", "--jobs", "0"]
    out = subprocess.run(cmd, cwd=paths.ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert_one_error(out.stderr, "--jobs")


def test_a_closed_output_pipe_is_no_error():
    """`python -m thesis_repro runs all | head`: the reader goes away; nothing on stderr."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "thesis_repro", "list"], cwd=paths.ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    proc.stdout.close()  # before the command writes anything
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) != 0
    assert error_lines(err) == []


# ---------------------------------------------------------------- verifiable listings
@pytest.fixture
def square_figure(monkeypatch):
    """A figure whose only run is the cache's toy job ``square`` (x=3)."""
    monkeypatch.setattr(figures, "FIGURES", {})
    monkeypatch.setattr(figures, "TRAINING_KINDS", ("square",))
    job = Job("square", {"x": 3})
    figures.register_figure("9.1", "toy figure", kinds=["square"], settings_id="_example")(lambda scale: [job])
    return job


def test_runs_check_catches_a_corrupt_local_entry(square_figure, capsys):
    entry = RunCache(reference=False).run(square_figure).path
    assert main(["runs", "--check", "--scale", "smoke"]) == 0
    assert "1 local runs" in capsys.readouterr().out
    (entry / "result.json").write_text(json.dumps({"y": 10}))
    assert main(["runs", "--check", "--scale", "smoke"]) == 1
    out = capsys.readouterr().out
    assert f"corrupt local run {entry}: files differ from the manifest: result.json" in out
    assert "1 local runs" in out and "1 corrupt" in out
    assert shipped_checks.verify_local() == {entry: "files differ from the manifest: result.json"}


def test_runs_listing_shows_corrupt_local_and_shipped_entries(square_figure, capsys, monkeypatch, tmp_path):
    entry = RunCache(reference=False).run(square_figure).path
    assert runs.job_row(square_figure, RunCache())["state"] == "cached"
    (entry / "result.json").write_text(json.dumps({"y": 10}))
    assert main(["runs", "9.1", "--scale", "smoke"]) == 0
    out = capsys.readouterr().out
    assert "fig-9.1 (smoke): 1 training run: 0 shipped, 0 cached, 1 to compute (1 corrupt, will be recomputed)" in out
    assert [r["state"] for r in runs.run_rows("9.1", "smoke")] == ["corrupt"]
    # the same in the shipped layer
    layer = tmp_path / "layer"
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(layer))
    shipped = runs.export(RunCache(tmp_path / "fresh", reference=False).run(square_figure), layer).path
    monkeypatch.setenv("THESIS_REPRO_DATA", str(tmp_path / "empty"))
    assert [r["state"] for r in runs.run_rows("9.1", "smoke")] == ["shipped"]
    (shipped / "config.json").write_text("{}")
    assert main(["runs", "9.1", "--scale", "smoke", "--json"]) == 0
    assert [r["state"] for r in json.loads(capsys.readouterr().out)["runs"]] == ["corrupt"]


# ---------------------------------------------------------------- the claims ledger
def test_claims_subcommand(monkeypatch, capsys):
    # not importable: a package without the module (the real one may already be imported by other tests)
    hidden = types.ModuleType("thesis_repro.claims")
    hidden.__path__ = []  # a package, whose cli submodule cannot be imported
    monkeypatch.setitem(sys.modules, "thesis_repro.claims", hidden)
    monkeypatch.setitem(sys.modules, "thesis_repro.claims.cli", None)
    assert main(["claims", "list"]) == 1
    assert_one_error(capsys.readouterr().err, "the claims ledger is not available")
    seen = []
    fake = types.ModuleType("thesis_repro.claims.cli")
    fake.main = lambda argv: seen.append(argv) or 3
    package = types.ModuleType("thesis_repro.claims")
    package.cli = fake
    monkeypatch.setitem(sys.modules, "thesis_repro.claims", package)
    monkeypatch.setitem(sys.modules, "thesis_repro.claims.cli", fake)
    assert main(["claims", "show", "--scale", "small"]) == 3
    assert seen == [["show", "--scale", "small"]]


@pytest.mark.parametrize(
    ("data", "says"),
    [
        (b"claims:\n  - id: a\n    text: [unclosed\n", "claims.yaml:4: not valid YAML"),
        (b"claims:\n  - id: a\n    text: caf\xe9\n", "claims.yaml:3: not UTF-8 (byte 0xe9"),
    ],
)
def test_a_malformed_claims_registry_is_one_line_naming_file_and_line(monkeypatch, tmp_path, capsys, data, says):
    (tmp_path / "claims.yaml").write_bytes(data)
    monkeypatch.setattr(paths, "THESIS_DATA", tmp_path)
    assert main(["claims", "--scale", "small"]) == 2
    assert_one_error(capsys.readouterr().err, str(tmp_path / "claims.yaml").rsplit("/", 1)[0], says)


def test_an_error_after_a_progress_bar_starts_on_its_own_line_without_terminal_codes(capsys):
    """A notebook that fails under a half-drawn progress bar: the `error:` line is not glued onto the bar, and
    terminal colour codes in the message (torch's) are dropped."""
    from thesis_repro.cli.commands import _guarded, main

    def fails() -> int:
        notebook_kernel.TRACKED_STDERR.write("\revaluate obs:   0%|          | 0/1")
        raise RuntimeError("refusing policy.pth: \x1b[1monly if you trust it\x1b[0m")

    assert _guarded(fails) == 1
    err = capsys.readouterr().err
    assert err.endswith("0/1\nerror: refusing policy.pth: only if you trust it\n"), err
    assert not notebook_kernel.line_open()  # the error line ended it
    notebook_kernel.TRACKED_STDERR.write("\rtrain:  50%|#####     | 1/2")
    assert notebook_kernel.line_open()
    capsys.readouterr()
    assert main(["figure", "3.3", "--scale", "medium"]) == 2  # a new command: a bar of an earlier one is not its
    assert capsys.readouterr().err.startswith("error: unknown scale 'medium'")
