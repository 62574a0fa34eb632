"""Warm kernels (:mod:`thesis_repro.book.warm_kernels`): a book build forks its notebooks' kernels from a server
that has imported the heavy libraries, and a warm kernel records the same kit modules, and shows the same
outputs (inline figures where a cold one puts them), as a cold one; anything unusual launches the kernel cold."""

from __future__ import annotations

import asyncio
import json
import os
import re
import socket
import sys
import tempfile
from pathlib import Path

import pytest

from tests.test_book import shared_smoke_dirs
from thesis_repro.book import notebook_kernel, notebooks, warm_kernels


def test_env_differences_ignore_only_per_kernel_variables():
    server = {"MKL_CBWR": "COMPATIBLE", "OMP_NUM_THREADS": "1", "THESIS_REPRO_BUILD": "a", "JPY_SESSION_NAME": "x"}
    kernel = {**server, "THESIS_REPRO_BUILD": "b", "THESIS_REPRO_PUBLISHED_BUILD": "c", "JPY_PARENT_PID": "1"}
    assert warm_kernels.env_differences(server, kernel) == []
    assert warm_kernels.env_differences(server, {**kernel, "MKL_CBWR": "AUTO", "MPLBACKEND": "agg"}) == [
        "MKL_CBWR",
        "MPLBACKEND",
    ]
    assert warm_kernels.env_differences(server, {k: v for k, v in kernel.items() if k != "OMP_NUM_THREADS"}) == [
        "OMP_NUM_THREADS"
    ]


def test_the_socket_is_a_kernel_file_of_the_builder():
    """``clean_stale`` removes a dead builder's socket with its kernels' files."""
    name = warm_kernels.SOCKET_NAME.format(pid=123)
    assert name.startswith(notebook_kernel.KERNEL_PREFIX)
    assert notebook_kernel.owner_pid(name, notebook_kernel.KERNEL_PREFIX) == 123


def test_warm_process_reads_the_exit_status_the_server_sends():
    """The handle's returncode is what the server reports after reaping the kernel; with the server gone, the
    kernel counts as alive while it exists."""
    ours, servers = socket.socketpair()
    proc = warm_kernels.WarmProcess(os.getpid(), ours)
    assert proc.poll() is None
    servers.sendall(b"-9\n")
    assert proc.wait(5) == -9 and proc.poll() == -9
    ours, servers = socket.socketpair()
    proc = warm_kernels.WarmProcess(os.getpid(), ours, b"0\n")  # the status came with the pid
    assert proc.poll() == 0
    ours, servers = socket.socketpair()
    proc = warm_kernels.WarmProcess(os.getpid(), ours)
    servers.close()
    assert proc.poll() is None  # this process is alive


def test_off_switch(monkeypatch):
    monkeypatch.setenv(warm_kernels.WARM_ENV, "0")
    with warm_kernels.warm_kernels() as server:
        assert server is None
        assert warm_kernels.launch([sys.executable, "-m", "ipykernel_launcher"], {}) is None


def _kernel_files(pid: int) -> list[str]:
    return sorted(p.name for p in Path(tempfile.gettempdir()).glob(f"thesis-repro-kernel-{pid}-*"))


@pytest.mark.slow
def test_warm_kernel_runs_forks_and_dies_like_a_cold_one(tmp_path):
    """A kernel forked by the server runs code, leads its own session, is killed with its group by ``kill_now``;
    a kernel whose numerics variable differs starts cold; the server and its socket end with the context."""
    with warm_kernels.warm_kernels() as server:
        assert server is not None and server.ready(), "the warm-kernel server did not start"
        km = notebook_kernel.QuietKernelManager(kernel_name="python3")
        asyncio.run(km.start_kernel(cwd=str(tmp_path)))
        proc = km.provisioner.process
        assert isinstance(proc, warm_kernels.WarmProcess)
        assert os.getpgid(proc.pid) == proc.pid and proc.poll() is None
        assert Path(f"/proc/{proc.pid}/stat").read_text().split()[3] == str(server.proc.pid)  # its parent: the server
        km.kill_now()
        assert proc.wait(10) is not None
        cmd = [*server.prefix, "-m", "ipykernel_launcher", "-f", "x.json"]
        env = {**server.env, "THESIS_REPRO_BUILD": "elsewhere"}
        assert server.compatible(cmd, {"env": env})
        assert not server.compatible(cmd, {"env": {**env, "MKL_CBWR": "AUTO"}})
        assert not server.compatible(["/usr/bin/python3", *cmd[1:]], {"env": env})
        assert not server.compatible(cmd, {"env": env, "stdin": 0})
    assert server.proc.poll() is not None and not Path(server.path).exists()
    assert _kernel_files(os.getpid()) == []


def _outputs(nb: dict) -> list[list[tuple[str, ...]]]:
    """Per cell, each output's type and MIME types (stream outputs: their name): where figures appear."""
    return [
        [(o["output_type"], *(sorted(o.get("data", {})) or [o.get("name", "")])) for o in c.get("outputs", [])]
        for c in nb["cells"]
    ]


@pytest.mark.slow
@pytest.mark.xdist_group("smoke")  # after the smoke book, in its process: its runs of fig-3.5 are cached then
def test_warm_kernel_records_what_a_cold_one_does(tmp_path_factory, tmp_path, monkeypatch):
    """The same smoke notebook, executed cold and then warm (its runs cached by then): the same kit modules
    (part of the execution key), the same outputs with the inline figure in the same place, the same text."""
    shared = shared_smoke_dirs(tmp_path_factory)
    monkeypatch.setenv("THESIS_REPRO_BUILD", shared["THESIS_REPRO_BUILD"])
    cached = notebooks.executed_path("3.5", "smoke").exists()  # the smoke book ran it on the shared run cache
    monkeypatch.setenv("THESIS_REPRO_DATA", shared["THESIS_REPRO_DATA"])
    launched = []
    real = warm_kernels.WarmServer.launch
    monkeypatch.setattr(warm_kernels.WarmServer, "launch", lambda *a: launched.append(real(*a)) or launched[-1])
    nbs = {}
    # a first run fills the run cache (its output says so), unless the smoke book's already did
    for mode in ("cold", "warm") if cached else ("cold-warmup", "cold", "warm"):
        monkeypatch.setenv("THESIS_REPRO_BUILD", str(tmp_path / mode))
        if mode == "warm":
            with warm_kernels.warm_kernels():
                out = notebooks.execute_notebook("3.5", "smoke", log=False)
        else:
            out = notebooks.execute_notebook("3.5", "smoke", log=False)
        nbs[mode] = json.loads(out.read_text())
    assert len(launched) == 1 and launched[0] is not None, "the warm run's kernel was not forked from the server"
    cold, warm = nbs["cold"], nbs["warm"]
    assert warm["metadata"]["thesis_repro"]["modules"] == cold["metadata"]["thesis_repro"]["modules"]
    assert warm["metadata"]["thesis_repro"]["execution_key"] == cold["metadata"]["thesis_repro"]["execution_key"]
    assert _outputs(warm) == _outputs(cold)
    assert any("image/png" in kinds for cell in _outputs(warm) for kinds in cell)

    def texts(nb: dict, mode: str) -> list[str]:
        """Printed text and text reprs (pandas' frames: what its import decided on width), paths and addresses
        aside."""
        found = []
        for o in (o for c in nb["cells"] for o in c.get("outputs", [])):
            text = "".join(o.get("text", "") or o.get("data", {}).get("text/plain", ""))
            found.append(re.sub(r" at 0x[0-9a-f]+", "", text.replace(str(tmp_path / mode), "<build>")))
        return found

    assert texts(warm, "warm") == texts(cold, "cold")
