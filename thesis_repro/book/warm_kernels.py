"""Warm kernels for a book build: one helper process imports the heavy libraries once and forks each kernel.

A fresh Jupyter kernel spends about 5 s importing the same third-party modules (torch, scipy, matplotlib, pandas,
stable-baselines3, gymnasium, MuJoCo, seaborn) before its notebook does anything; a book executes 25 notebooks.
:func:`warm_kernels` (the book builder's context) starts a *server*: ``python -c`` with the kernelspec's flags,
which imports :data:`PRELOAD` and ipykernel, then forks one kernel per request on a Unix socket
(:data:`SOCKET_NAME`, removed with the build or by :func:`thesis_repro.book.notebooks.clean_stale`).
:class:`thesis_repro.book.notebook_kernel.QuietKernelManager` asks it first (:func:`launch`) and launches the
kernel the usual (cold) way when there is no server, it failed, or the kernel would differ from the server in
anything but its per-kernel variables (:data:`PER_KERNEL`).

What a warm kernel must share with a cold one:

* **No kit module but ``thesis_repro`` itself.** Every notebook records the kit modules its kernel imported
  (its execution key); the server imports only third-party modules, after ``thesis_repro`` (its ``__init__``
  pins the numerics variables before torch loads), and the forked kernel forgets this module and its package.
* **The same environment.** The server is started with the builder's environment; a kernel whose environment
  differs in anything else (numerics, thread counts, ``MPLBACKEND``, ``MUJOCO_GL``, ...) or whose python is not
  the server's runs cold. The server sets ``MPLBACKEND`` as ipykernel would before matplotlib loads (inline
  figures), and the kernel gets exactly its requested environment.
* **Fork safety.** The server is single-threaded and runs no torch op (a GNU OpenMP parallel region does not
  survive a fork).
* **The process handle.** The kernel is the server's child (the server reaps it and reports its exit status):
  :class:`WarmProcess` is the Popen-like handle jupyter_client's provisioner keeps; the kernel runs in a session
  of its own, so interrupts and :meth:`~thesis_repro.book.notebook_kernel.QuietKernelManager.kill_now` work as
  for a cold kernel. The server ends with the build, or when the builder dies (its stdin pipe closes; the
  parent-death signal); a kernel ends when the server does (ipykernel's parent poller).

``THESIS_REPRO_WARM_KERNELS=0`` turns it off. Only :mod:`thesis_repro` and the standard library are imported at
module level: the server imports this module.
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import importlib
import importlib.util
import json
import os
import select
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Iterator
from pathlib import Path
from typing import Any

#: ``THESIS_REPRO_WARM_KERNELS=0`` launches every kernel cold.
WARM_ENV = "THESIS_REPRO_WARM_KERNELS"
#: Third-party modules the server imports (what the notebooks' kernels import anyway; ~5 s a kernel).
PRELOAD: tuple[str, ...] = (
    "numpy",
    "scipy.stats",
    "scipy.optimize",
    "pandas",
    "matplotlib.pyplot",
    "seaborn",
    "torch",
    "torch.nn.functional",
    "torch.optim",
    "torch._dynamo",  # imported by every optimizer step (torch.optim.optimizer._use_grad): 2-3 s a kernel
    "gymnasium",
    "mujoco",
    "stable_baselines3",
    "sb3_contrib",
    "yaml",
    "tqdm",
    "IPython.display",
    "ipykernel.kernelapp",
)
#: The backend ipykernel sets (``IPKernelApp.init_gui_pylab``) unless ``MPLBACKEND`` is set.
INLINE_BACKEND = "module://matplotlib_inline.backend_inline"
#: Variables that may differ between the server and a kernel (set per kernel; the kit reads none of them at
#: import): the staging and published build folders, and jupyter_client's (``JPY_*``).
PER_KERNEL: tuple[str, ...] = ("THESIS_REPRO_BUILD", "THESIS_REPRO_PUBLISHED_BUILD")
#: Launch keywords a warm kernel honours (any other means a cold launch).
_KEYWORDS = {"env", "cwd", "stdout", "stderr", "extra_arguments", "kernel_id"}
#: Seconds to wait for the server's imports, and for a fork's reply.
START_TIMEOUT, REPLY_TIMEOUT = 180.0, 30.0
#: The server's socket in the temp folder, named as a kernel file of the builder
#: (:data:`thesis_repro.book.notebook_kernel.KERNEL_PREFIX`, not imported: it imports this module), so that
#: :func:`thesis_repro.book.notebooks.clean_stale` removes it once the builder is dead.
SOCKET_NAME = "thesis-repro-kernel-{pid}-warm"
_ACTIVE: list[WarmServer] = []


def _per_kernel(name: str) -> bool:
    return name in PER_KERNEL or name.startswith("JPY_")


def _kernel_env(env: dict[str, str]) -> dict[str, str]:
    """``env`` as jupyter_client hands it to a python kernel (it drops ``PYTHONEXECUTABLE``)."""
    return {k: v for k, v in env.items() if k != "PYTHONEXECUTABLE"}


def env_differences(
    server: dict[str, str], kernel: dict[str, str], imported: dict[str, str] | None = None
) -> list[str]:
    """Variables whose values differ between ``server`` and ``kernel``, per-kernel ones aside, and those the server's
    imports set (``imported``) to the kernel's value (gymnasium sets ``PYGAME_HIDE_SUPPORT_PROMPT`` on import: the
    builder has it once it imported gymnasium, the server once it has, and a kernel once it does).

    >>> env_differences({"MKL_CBWR": "COMPATIBLE", "THESIS_REPRO_BUILD": "a"}, {"THESIS_REPRO_BUILD": "b"})
    ['MKL_CBWR']
    >>> env_differences({}, {"PYGAME_HIDE_SUPPORT_PROMPT": "hide"}, {"PYGAME_HIDE_SUPPORT_PROMPT": "hide"})
    []
    """
    imported = imported or {}
    return sorted(
        k
        for k in set(server) | set(kernel)
        if not _per_kernel(k) and server.get(k) != kernel.get(k) and (k not in imported or imported[k] != kernel.get(k))
    )


class WarmProcess:
    """Popen-like handle of a kernel the server forked (not this process's child: no ``waitpid`` here).

    The server reports the exit status on the request's connection once it has reaped the kernel; if the server
    is gone, the kernel counts as alive while ``kill(pid, 0)`` finds it (its exit status is then unknown: 1).
    """

    stdin = stdout = stderr = None

    def __init__(self, pid: int, conn: socket.socket, buf: bytes = b""):
        self.pid, self.returncode, self.args = pid, None, ["warm kernel", str(pid)]
        self._conn: socket.socket | None = conn
        self._buf = buf  # what the server sent after the pid: the exit status, once the kernel has ended

    def poll(self) -> int | None:
        if self.returncode is not None:
            return self.returncode
        if b"\n" in self._buf:
            self.returncode = int(self._buf.split(b"\n", 1)[0])
            self._close()
            return self.returncode
        if self._conn is not None:
            while select.select([self._conn], [], [], 0)[0]:
                try:
                    chunk = self._conn.recv(64)
                except OSError:
                    chunk = b""
                if not chunk:  # the server is gone without a word: ask the kernel itself
                    self._close()
                    break
                self._buf += chunk
                if b"\n" in self._buf:
                    self.returncode = int(self._buf.split(b"\n", 1)[0])
                    self._close()
                    return self.returncode
        if self._conn is None:
            try:
                os.kill(self.pid, 0)
            except ProcessLookupError:
                self.returncode = 1
            except PermissionError:
                pass
        return self.returncode

    def _close(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        while (code := self.poll()) is None:
            if deadline is not None and time.monotonic() > deadline:
                raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
            time.sleep(0.02)
        return code

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


class WarmServer:
    """The builder's side of the server: its process, socket, and the environment and python it runs."""

    def __init__(self, argv: list[str]):
        self.prefix = argv[: argv.index("-m")]  # the kernelspec's python and its flags (-Xfrozen_modules=off)
        self.path = str(Path(tempfile.gettempdir()) / SOCKET_NAME.format(pid=os.getpid()))
        self.env = _kernel_env(dict(os.environ))
        self.executable: str | None = None
        self.imported: dict[str, str] = {}  # variables the server's imports set (env_differences)
        with contextlib.suppress(OSError):
            os.unlink(self.path)
        boot = "import sys; del sys.path[0]; from thesis_repro.book.warm_kernels import serve; serve(*sys.argv[1:])"
        self.proc = subprocess.Popen(
            [*self.prefix, "-c", boot, self.path, str(os.getpid())],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            env=self.env,
            cwd="/",
            start_new_session=True,  # a Ctrl-C on the terminal is the builder's to handle
        )

    def ready(self) -> bool:
        """Wait (once) for the server's imports; False if it failed or died."""
        if self.executable is None and self.proc.poll() is None and self.proc.stdout is not None:
            if select.select([self.proc.stdout], [], [], START_TIMEOUT)[0]:
                with contextlib.suppress(ValueError):
                    hello = json.loads(self.proc.stdout.readline() or b"{}")
                    self.executable = hello.get("executable") or ""
                    self.imported = hello.get("imported") or {}
            self.executable = self.executable or ""
        return bool(self.executable) and self.proc.poll() is None

    def compatible(self, cmd: list[str], kw: dict[str, Any]) -> bool:
        """Whether a kernel launched with ``cmd`` and ``kw`` can be forked from the server."""
        n = len(self.prefix)
        return (
            cmd[:n] == self.prefix
            and cmd[n : n + 2] == ["-m", "ipykernel_launcher"]
            and cmd[0] == self.executable
            and set(kw) <= _KEYWORDS
            and not env_differences(self.env, _kernel_env(kw.get("env", os.environ)), self.imported)
        )

    def launch(self, cmd: list[str], kw: dict[str, Any]) -> WarmProcess | None:
        """Fork a kernel for ``cmd`` (``python -m ipykernel_launcher -f <file>``), else None (launch it cold)."""
        if not (self.ready() and self.compatible(cmd, kw)):
            return None
        request = {
            "argv": cmd[len(self.prefix) + 2 :],
            "env": kw.get("env", dict(os.environ)),
            "cwd": str(kw.get("cwd") or os.getcwd()),
        }
        fds = [1 if kw.get("stdout") is None else kw["stdout"], 2 if kw.get("stderr") is None else kw["stderr"]]
        conn = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            conn.settimeout(REPLY_TIMEOUT)
            conn.connect(self.path)
            socket.send_fds(conn, [json.dumps(request).encode() + b"\n"], fds)
            reply = b""
            while b"\n" not in reply:
                chunk = conn.recv(64)
                if not chunk:
                    raise OSError("the warm-kernel server closed the connection")
                reply += chunk
            conn.settimeout(None)
            pid, _, rest = reply.partition(b"\n")
            return WarmProcess(int(pid), conn, rest)
        except (OSError, ValueError):
            conn.close()
            return None

    def close(self) -> None:
        """End the server (its stdin closes) and remove its socket."""
        for stream in (self.proc.stdin, self.proc.stdout):
            with contextlib.suppress(OSError):
                stream and stream.close()
        try:
            self.proc.wait(5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        with contextlib.suppress(OSError):
            os.unlink(self.path)


def _close_active() -> None:
    while _ACTIVE:
        _ACTIVE.pop().close()


@contextlib.contextmanager
def warm_kernels() -> Iterator[WarmServer | None]:
    """While the context runs (a book build), notebooks' kernels are forked from a warm server; None if off."""
    server = None
    if os.environ.get(WARM_ENV, "1") != "0":
        with contextlib.suppress(Exception):  # no server: every kernel starts cold
            from jupyter_client.kernelspec import KernelSpecManager

            argv = KernelSpecManager().get_kernel_spec("python3").argv
            if argv[argv.index("-m") + 1] == "ipykernel_launcher":
                server = WarmServer(argv)
    if server is not None:
        if not _ACTIVE:
            atexit.unregister(_close_active)
            atexit.register(_close_active)  # here, not on import: the server imports this module
        _ACTIVE.append(server)
    try:
        yield server
    finally:
        if server is not None:
            with contextlib.suppress(ValueError):
                _ACTIVE.remove(server)
            server.close()


def launch(cmd: list[str], kw: dict[str, Any]) -> WarmProcess | None:
    """A kernel forked by the active server for ``cmd`` and the launch keywords ``kw``; None: launch it cold."""
    return _ACTIVE[-1].launch(cmd, kw) if _ACTIVE else None


# --- the server process -------------------------------------------------------------------------------------


def _die_with_parent(parent: int) -> None:
    """Get SIGTERM when the builder dies (Linux), and exit now if it already has."""
    with contextlib.suppress(Exception):
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    if os.getppid() != parent:
        os._exit(0)


def serve(path: str, parent: str) -> None:
    """The server: import :data:`PRELOAD`, say ``{"executable": ...}`` on stdout, then fork a kernel per request
    on the Unix socket ``path`` until stdin closes (the builder ended the build or died)."""
    _die_with_parent(int(parent))
    hello = os.fdopen(os.dup(1), "w")
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)  # what the imports print is no hello
    os.close(null)
    before = dict(os.environ)
    if not os.environ.get("MPLBACKEND"):  # what ipykernel sets, and before matplotlib loads (inline figures)
        os.environ["MPLBACKEND"] = INLINE_BACKEND
    for name in PRELOAD:
        with contextlib.suppress(Exception):
            importlib.import_module(name)
    imported = {k: v for k, v in os.environ.items() if k != "MPLBACKEND" and before.get(k) != v}
    if threading.active_count() != 1:
        os._exit(1)  # a fork would copy a half-held lock: the builder sees no hello and launches cold
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(path)
    listener.listen(8)
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_r, False)
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda *_: None)  # wakes select() through wake_w
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # the parent-death signal: clean up below
    children: dict[int, socket.socket] = {}
    with hello:
        hello.write(json.dumps({"executable": sys.executable, "imported": imported}) + "\n")
    try:
        while True:
            ready = select.select([listener, 0, wake_r], [], [])[0]
            if 0 in ready and not os.read(0, 4096):
                break
            if wake_r in ready:
                with contextlib.suppress(BlockingIOError):
                    os.read(wake_r, 4096)
            if listener in ready:
                conn = listener.accept()[0]
                try:
                    _fork(conn, children, [listener.fileno(), wake_r, wake_w])
                except (OSError, ValueError):
                    conn.close()
            _reap(children)
    finally:
        for pid in children:  # the builder is gone: so are its kernels
            with contextlib.suppress(OSError):
                os.killpg(pid, signal.SIGTERM)
        with contextlib.suppress(OSError):
            os.unlink(path)
    os._exit(0)


def _reap(children: dict[int, socket.socket]) -> None:
    """Reap ended kernels and send each one's exit status (Popen's returncode) to its handle."""
    while children:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
        conn = children.pop(pid, None)
        if conn is not None:
            with contextlib.suppress(OSError):
                conn.sendall(f"{os.waitstatus_to_exitcode(status)}\n".encode())
            conn.close()


def _fork(conn: socket.socket, children: dict[int, socket.socket], server_fds: list[int]) -> None:
    """Read one request (JSON line, stdout and stderr descriptors) from ``conn``, fork its kernel, reply its pid."""
    conn.settimeout(REPLY_TIMEOUT)
    data, fds, _, _ = socket.recv_fds(conn, 1 << 20, 2)
    try:
        while not data.endswith(b"\n"):
            chunk = conn.recv(1 << 20)
            if not chunk:
                raise ValueError("truncated request")
            data += chunk
        if len(fds) != 2:
            raise ValueError("a request passes stdout and stderr")
        request = json.loads(data)
        pid = os.fork()
        if pid == 0:
            _kernel(request, fds, [conn.fileno(), *server_fds, *(c.fileno() for c in children.values())])
        children[pid] = conn
        conn.settimeout(None)
        conn.sendall(f"{pid}\n".encode())
    finally:
        for fd in fds:
            os.close(fd)


def _kernel(request: dict[str, Any], fds: list[int], close: list[int]) -> None:
    """In the forked child: become what ``python -m ipykernel_launcher -f <file>`` would be, run, exit."""
    code = 1
    try:
        signal.set_wakeup_fd(-1)
        for sig in (signal.SIGCHLD, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT, signal.SIGUSR1, signal.SIGUSR2):
            signal.signal(sig, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        os.setsid()  # as jupyter_client's launch: kill_now and interrupts signal the kernel's process group
        for fd in close:
            with contextlib.suppress(OSError):
                os.close(fd)
        null = os.open(os.devnull, os.O_RDONLY)
        for fd, target in ((null, 0), (fds[0], 1), (fds[1], 2)):
            os.dup2(fd, target)
        for fd in {null, *fds} - {0, 1, 2}:
            os.close(fd)
        os.environ.clear()
        os.environ.update(request["env"])
        os.environ["JPY_PARENT_PID"] = str(os.getppid())  # the kernel ends with the server (its parent poller)
        os.chdir(request["cwd"])
        spec = importlib.util.find_spec("ipykernel_launcher")
        sys.argv = [spec.origin if spec and spec.origin else "ipykernel_launcher", *request["argv"]]
        _forget_kit()
        _as_in_a_kernel()
        from ipykernel import kernelapp

        try:
            # ipykernel read JPY_PARENT_PID when the server imported it: the parent to poll is given here
            kernelapp.IPKernelApp.launch_instance(parent_handle=int(os.environ["JPY_PARENT_PID"]))
            code = 0
        except SystemExit as err:
            code = err.code if isinstance(err.code, int) else 0 if err.code is None else 1
        with contextlib.suppress(Exception):
            threading._shutdown()  # type: ignore[attr-defined]  # what interpreter exit does before atexit
        atexit._run_exitfuncs()
    except BaseException:
        with contextlib.suppress(Exception):
            traceback.print_exc()
    finally:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        os._exit(code)


def _as_in_a_kernel() -> None:
    """Redo what a preloaded library decided on import from where it ran (the server is no Jupyter kernel): a
    cold kernel imports it with fresh entropy, and inside a kernel."""
    if (np_random := sys.modules.get("numpy.random")) is not None:
        np_random.seed()  # numpy's global generator (Python's random reseeds itself at a fork)
    if (pandas := sys.modules.get("pandas")) is not None:
        # pandas' config_init: 0 (fit the terminal) outside IPython, 20 inside a Jupyter kernel
        pandas.set_option("display.max_columns", 20)


def _forget_kit() -> None:
    """Drop every kit module but ``thesis_repro`` (this module and its package): the notebook records the kit
    modules its kernel imports, and a warm kernel must record what a cold one does."""
    import thesis_repro

    for name in [n for n in sys.modules if n.startswith("thesis_repro.")]:
        del sys.modules[name]
    for attr, value in list(vars(thesis_repro).items()):
        if getattr(value, "__name__", "").startswith("thesis_repro."):
            delattr(thesis_repro, attr)
