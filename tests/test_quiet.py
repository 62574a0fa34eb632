"""Quiet, clean runs: no MuJoCo deprecation spam, no temp-folder litter, no insecure-transport kernel warning."""

from __future__ import annotations

import asyncio
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from thesis_repro.book import notebook_kernel, notebooks
from thesis_repro.envs import make_env
from thesis_repro.envs.registry import MODEL_XML


def test_halfcheetah_model_matches_gymnasium():
    """The kit's HalfCheetah model (explicit density) compiles to Gymnasium's masses and inertias."""
    ours = make_env("HalfCheetah").unwrapped
    assert Path(ours.fullpath) == MODEL_XML["HalfCheetah"]
    ref_xml = Path(gym.envs.mujoco.__file__).parent / "assets" / "half_cheetah.xml"
    assert 'settotalmass="14"' in ref_xml.read_text()
    assert "settotalmass" not in MODEL_XML["HalfCheetah"].read_text().split("-->", 1)[1]
    ref = mujoco.MjModel.from_xml_path(str(ref_xml))
    np.testing.assert_allclose(ours.model.body_mass, ref.body_mass, rtol=1e-12)
    np.testing.assert_allclose(ours.model.body_inertia, ref.body_inertia, rtol=1e-12)
    assert ours.model.body_mass.sum() == pytest.approx(14.0)
    for name in ("geom_size", "geom_friction", "jnt_range", "actuator_gear", "dof_damping", "opt.timestep"):
        obj_a, obj_b = ours.model, ref
        for part in name.split("."):
            obj_a, obj_b = getattr(obj_a, part), getattr(obj_b, part)
        np.testing.assert_array_equal(obj_a, obj_b, err_msg=name)


def test_building_every_task_prints_no_mujoco_warning(tmp_path):
    """Zero 'settotalmass is deprecated' (or any MuJoCo) warnings, and no MUJOCO_LOG.TXT, when building envs."""
    code = (
        "from thesis_repro.envs import ENVS, make_env\n"
        "for name in ENVS:\n"
        "    env = make_env(name, 'env', 0.1, seed=0)\n"
        "    env.step(env.action_space.sample())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, check=True)
    text = out.stdout + out.stderr
    assert text.count("settotalmass") == 0, text
    assert "WARNING" not in text, text
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_kernel_uses_ipc_transport_and_cleans_up():
    """The notebook kernel runs over IPC sockets (no 'TCP without encryption' warning) and removes them."""

    async def run() -> tuple[dict, list[str]]:
        km = notebook_kernel.QuietKernelManager(kernel_name="python3")
        await km.start_kernel()
        kc = km.client()
        kc.start_channels()
        try:
            await kc.wait_for_ready(timeout=60)
            info = km.get_connection_info()
            sockets = sorted(p.name for p in Path(km.ip).parent.glob(Path(km.ip).name + "-*"))
        finally:
            kc.stop_channels()
            await km.shutdown_kernel(now=True)
        return info, sockets, sorted(p.name for p in Path(km.ip).parent.glob(Path(km.ip).name + "-*"))

    info, during, after = asyncio.run(run())
    assert info["transport"] == "ipc"
    assert Path(info["ip"]).parent == Path(tempfile.gettempdir())
    assert len(during) >= 5, during  # shell, iopub, stdin, control, heartbeat
    assert after == []


@pytest.mark.slow
def test_a_smoke_figure_run_is_quiet_and_leaves_no_litter(tmp_path):
    """`python -m thesis_repro figure 4.1 --scale smoke`: progress bars, verdict lines and one final line with
    the executed notebook and figures; no warnings; nothing left in the temp folder (no SB3-* logger dirs,
    no kernel sockets)."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {
        **os.environ,
        "TMPDIR": str(tmp),
        "THESIS_REPRO_DATA": str(tmp_path / "runs"),
        "THESIS_REPRO_BUILD": str(tmp_path / "build"),
        "THESIS_REPRO_JOBS": "2",
    }
    cmd = [sys.executable, "-m", "thesis_repro", "figure", "4.1", "--scale", "smoke"]
    out = subprocess.run(cmd, cwd=notebooks.paths.ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    lines = [ln for ln in (out.stdout + "\n" + out.stderr).replace("\r", "\n").splitlines() if ln.strip()]
    verdict = re.compile(r"\[4\.1\] [A-Z ]+ (- |· )")
    noise = [ln for ln in lines if re.search(r"warn|deprecat|TCP|Traceback|error", ln, re.I) and not verdict.match(ln)]
    assert not noise, noise
    stdout = out.stdout.strip().splitlines()
    assert stdout[-1].startswith("[thesis_repro] fig-4.1 (smoke, ")
    assert str(tmp_path / "build" / "smoke" / "notebooks" / "fig-4.1.ipynb") in stdout[-1]
    assert "figures: " + str(tmp_path / "build" / "smoke" / "figures" / "fig-4.1") in stdout[-1]
    assert all(verdict.match(ln) for ln in stdout[:-1]), stdout
    assert sorted(p.name for p in tmp.iterdir() if p.name.startswith("SB3-")) == []
    left = sorted(p.name for p in tmp.iterdir() if not p.name.startswith("torchinductor_"))  # torch's one cache dir
    assert left == [], "the figure run left files in the temp folder"
