"""Quiet, clean runs: no MuJoCo deprecation spam, no temp-folder litter, no insecure-transport kernel warning."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import tempfile
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from thesis_repro import notebooks
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
        km = notebooks.QuietKernelManager(kernel_name="python3")
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
