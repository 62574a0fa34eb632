"""The Jupyter kernel a notebook runs in: quiet, killed with its run, and its stderr relayed.

:class:`QuietKernelManager` starts the kernel on IPC sockets in the temp folder (no unencrypted-TCP warning),
its stderr on a pipe that this process copies to its own; an interrupted run (:func:`noting_interrupts`) kills
the kernel and the kernel's workers at once instead of asking the busy kernel to shut down, and drops what the
dying family writes. :func:`kill_kernels` ends what is left on an interrupt and at exit. :data:`TRACKED_STDERR`
is this process's stderr as papermill writes a notebook's progress bars onto it (:func:`line_open`: a bar still
holds the last line, so an error line starts a new one). :mod:`thesis_repro.book.notebooks` executes notebooks in it.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from jupyter_client import AsyncKernelManager

#: Prefix of every kernel file in the temp folder: ``thesis-repro-kernel-<pid>-<n>.json`` (connection file)
#: and ``thesis-repro-kernel-<pid>-<n>-<port>`` (IPC sockets); ``<pid>`` is the process that started the kernel.
KERNEL_PREFIX = "thesis-repro-kernel-"
#: Kernels started by this process and not shut down yet (killed by :func:`kill_kernels`).
_LIVE: set[QuietKernelManager] = set()
#: Signals that end a run (Ctrl-C, and SIGTERM/SIGHUP where the command line raises on them).
INTERRUPTS: tuple[signal.Signals, ...] = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: Set while a signal of :data:`INTERRUPTS` ends the running notebook (:func:`noting_interrupts`).
_INTERRUPTED: list[int] = []


class QuietKernelManager(AsyncKernelManager):
    """Kernel manager whose kernel talks over IPC sockets in the temp folder (no unencrypted-TCP warning).

    The connection file and the socket files (``<tmp>/thesis-repro-kernel-<pid>-<n>[.json|-<port>]``) are
    removed when the kernel shuts down, by :func:`kill_kernels` when this process is interrupted, or by
    :func:`clean_stale` once ``<pid>`` is dead. ``extra_env`` is added to the kernel's environment.
    Shutdown skips jupyter_client's preliminary SIGINT (papermill shuts down an idle kernel), which made
    the kernel log "KeyboardInterrupt caught in kernel" now and then. The shutdown of an interrupted run
    (:func:`noting_interrupts`) is :meth:`kill_now`: asked to shut down, the busy kernel ended its pool's
    workers itself, and the cell then raised ``BrokenProcessPool`` and the exiting kernel wrote asyncio's "Task
    was destroyed but it is pending!" onto the terminal it shares with this process.
    """

    _count = 0
    extra_env: dict[str, str] = {}

    def __init__(self, **kwargs: Any):
        super().__init__(**kwargs)
        QuietKernelManager._count += 1
        base = Path(tempfile.gettempdir()) / f"{KERNEL_PREFIX}{os.getpid()}-{self._count}"
        self.transport = "ipc"
        self.connection_file = f"{base}.json"
        self.ip = str(base)
        self._closing = False
        self._muted = False

    async def _async_pre_start_kernel(self, **kw: Any) -> tuple[list[str], dict[str, Any]]:
        if self.extra_env:
            kw["env"] = {**kw.get("env", os.environ), **self.extra_env}
        _LIVE.add(self)
        return await super()._async_pre_start_kernel(**kw)

    async def _async_launch_kernel(self, kernel_cmd: list[str], **kw: Any) -> None:
        """Launch the kernel with its stderr (and its children's) on a pipe that :meth:`_relay` copies to
        this process's stderr, so that what the kernel family writes there once :meth:`kill_now` ends it is
        dropped (the pool's resource tracker, for one, warns of the semaphores it then cleans up)."""
        read, write = os.pipe()
        try:
            kw = {**kw, "stderr": write}
            if not self._launch_warm(kernel_cmd, kw):
                await super()._async_launch_kernel(kernel_cmd, **kw)
        except BaseException:
            os.close(read)
            raise
        finally:
            os.close(write)  # the kernel holds its own copy: the relay ends when the kernel family is gone
        threading.Thread(target=self._relay, args=(read,), name=f"stderr of {self.ip}", daemon=True).start()

    def _launch_warm(self, kernel_cmd: list[str], kw: dict[str, Any]) -> bool:
        """Fork the kernel from a book build's warm server (:mod:`thesis_repro.book.warm_kernels`) and set up
        the provisioner as jupyter_client's launch would; False: no warm kernel, launch it cold."""
        from thesis_repro.book import warm_kernels

        proc = warm_kernels.launch(kernel_cmd, kw)
        if proc is None:
            return False
        prov = self.provisioner
        assert prov is not None
        prov.process, prov.pid = proc, proc.pid  # type: ignore[attr-defined]
        prov.pgid = proc.pid  # type: ignore[attr-defined]  # the kernel leads a session of its own
        prov.cwd = kw.get("cwd", Path.cwd())  # type: ignore[attr-defined]
        self._reconcile_connection_info(prov.connection_info)
        return True

    def _relay(self, fd: int) -> None:
        """Copy the kernel's stderr pipe ``fd`` to this process's stderr (file descriptor 2, which the kernel
        used to inherit) until every writer is gone; once muted, read on and drop."""
        with open(fd, "rb", buffering=0) as pipe:
            while chunk := pipe.read(65536):
                while chunk and not self._muted:
                    try:
                        chunk = chunk[os.write(2, chunk) :]
                    except OSError:  # stderr closed (a reader that went away): nothing to show it on
                        break

    async def _async_interrupt_kernel(self) -> None:
        if not self._closing:
            await super()._async_interrupt_kernel()

    async def shutdown_kernel(self, now: bool = False, restart: bool = False) -> None:  # type: ignore[override]
        if _INTERRUPTED and not restart:  # nbclient's cleanup of an interrupted run: kill, never ask politely
            self.kill_now()
            return
        self._closing = True
        try:
            await super()._async_shutdown_kernel(now=now, restart=restart)
        finally:
            self._closing = False
            _LIVE.discard(self)
            _remove_kernel_files(self.ip)

    def kill_now(self, grace: float = 2.0) -> None:
        """Synchronously end the kernel's process group (the kernel and its worker processes: the kernel runs
        in a session of its own), wait up to ``grace`` seconds, then remove its connection and socket files.
        Whatever the dying kernel family writes to its stderr from now on is dropped."""
        self._muted = True
        prov = self.provisioner
        pid, pgid = getattr(prov, "pid", None), getattr(prov, "pgid", None)
        if pgid is not None and pgid == os.getpgid(0):
            pgid = None  # never signal our own process group
        for sig in (signal.SIGTERM, signal.SIGKILL):
            if not _signal_kernel(pid, pgid, sig):
                break
            deadline = time.time() + grace
            while time.time() < deadline and _signal_kernel(pid, pgid, 0):
                with contextlib.suppress(Exception):
                    prov.process.poll()  # reap the kernel so that it stops counting as alive
                time.sleep(0.05)
        with contextlib.suppress(Exception):
            prov.process.poll()
        _LIVE.discard(self)
        _remove_kernel_files(self.ip)


def _signal_kernel(pid: int | None, pgid: int | None, sig: int) -> bool:
    """Send ``sig`` to the kernel's group (else the kernel); False if nothing is left to signal."""
    try:
        if pgid is not None:
            os.killpg(pgid, sig)
        elif pid is not None:
            os.kill(pid, sig)
        else:
            return False
    except (ProcessLookupError, PermissionError):
        return False
    return True


@contextlib.contextmanager
def noting_interrupts() -> Iterator[None]:
    """While a notebook runs, a signal of :data:`INTERRUPTS` whose handler is Python code (Ctrl-C's
    ``KeyboardInterrupt``, the command line's ``Terminated``) is noted in :data:`_INTERRUPTED` before that
    handler raises: nbclient's cleanup, which the exception passes through first, then kills the kernel (and
    its workers) at once (:meth:`QuietKernelManager.shutdown_kernel`). Outside the main thread: no change."""

    def noted(old: Callable[[int, Any], Any]) -> Callable[[int, Any], Any]:
        def handler(signum: int, frame: Any) -> Any:
            _INTERRUPTED.append(signum)
            return old(signum, frame)

        return handler

    saved: dict[signal.Signals, Any] = {}
    for sig in INTERRUPTS:
        old = signal.getsignal(sig)
        if callable(old):
            with contextlib.suppress(ValueError, OSError):  # not the main thread
                signal.signal(sig, noted(old))
                saved[sig] = old
    _INTERRUPTED.clear()
    try:
        yield
    finally:
        for sig, old in saved.items():
            signal.signal(sig, old)
        _INTERRUPTED.clear()


def _remove_kernel_files(base: str) -> None:
    """Remove a kernel's connection file (``<base>.json``) and IPC socket files (``<base>-<port>``)."""
    base_path = Path(base)
    for p in [Path(f"{base}.json"), *base_path.parent.glob(f"{base_path.name}-*")]:
        with contextlib.suppress(OSError):
            p.unlink()


def kill_kernels() -> None:
    """End every kernel this process started and still runs, and remove their files (on an interrupt and at
    exit; a no-op after a normal run)."""
    for km in list(_LIVE):
        km.kill_now()


atexit.register(kill_kernels)


def owner_pid(name: str, prefix: str, sep: str = "-") -> int | None:
    """The pid in ``<prefix><pid>-...`` (``sep`` ``"-"``) or ``<prefix>...-<pid>`` (``sep`` ``""``), else None.

    >>> owner_pid("thesis-repro-kernel-123-4-5555", KERNEL_PREFIX), owner_pid(".staging-x-77", ".staging-", "")
    (123, 77)
    """
    rest = name[len(prefix) :] if name.startswith(prefix) else None
    if rest is None:
        return None
    text = rest.split("-", 1)[0] if sep else rest.rsplit("-", 1)[-1]
    return int(text) if text.isdigit() else None


class _TrackedStderr:
    """This process's stderr as papermill writes a notebook's stderr (its progress bars) onto it, remembering
    whether the last line is still open (a bar redrawn with ``\r``), so that an error starts on its own line."""

    line_open = False

    def write(self, text: str) -> int:
        if text:
            _TrackedStderr.line_open = not text.endswith("\n")
        return sys.stderr.write(text)

    def flush(self) -> None:
        sys.stderr.flush()


TRACKED_STDERR = _TrackedStderr()


def line_open() -> bool:
    """True while a notebook's progress bar holds the terminal's last line (nothing has ended it)."""
    return _TrackedStderr.line_open


def line_ended() -> None:
    """Note that the terminal's last line was ended (a new command starts, or an error line was printed)."""
    _TrackedStderr.line_open = False
