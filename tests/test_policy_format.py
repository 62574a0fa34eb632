"""Policies are stored and loaded as tensors only: a planted pickle payload is refused, its code never run."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy

from thesis_repro.learners.policies import SCNPolicy
from thesis_repro.learners.policy_file import UnsafePolicyFile, build_policy, load_policy, read_state_dict, save_policy


def _saved(folder: Path, cls: type = ActorCriticPolicy) -> ActorCriticPolicy:
    th.manual_seed(0)
    obs = gym.spaces.Box(-np.inf, np.inf, (5,), np.float64)
    act = gym.spaces.Box(np.array([-1, -2], np.float32), np.array([1, 3], np.float32), (2,), np.float32)
    net = cls(obs, act, lambda _: 3e-4, net_arch={"pi": [8], "vf": [8]}, activation_fn=th.nn.Tanh)
    folder.mkdir(parents=True, exist_ok=True)
    meta = {**save_policy(net, folder), "algorithm": "ppo", "class": "PPO", "env": "Hopper", "num_timesteps": 0}
    (folder / "learner.json").write_text(json.dumps(meta, indent=1))
    return net


class _Payload:
    """What an attacker plants: unpickling it would create ``marker``."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


@pytest.mark.parametrize("cls", [ActorCriticPolicy, SCNPolicy])
def test_a_saved_policy_reloads_bit_for_bit(tmp_path, cls):
    net = _saved(tmp_path, cls)
    state = read_state_dict(tmp_path / "policy.pth")
    assert state.keys() == net.state_dict().keys()
    assert all(th.equal(state[k], v) for k, v in net.state_dict().items())
    meta = json.loads((tmp_path / "learner.json").read_text())
    rebuilt = build_policy(meta, state)
    assert rebuilt.action_space == net.action_space and rebuilt.observation_space == net.observation_space
    obs = np.random.default_rng(0).normal(size=(16, 5))
    pol = load_policy(tmp_path)
    with th.no_grad():
        want = net._predict(th.as_tensor(obs, dtype=th.float32), deterministic=True).numpy()
    assert np.array_equal(pol(obs), np.clip(want, [-1, -2], [1, 3]))


def test_a_planted_pickle_payload_is_refused_with_one_line(tmp_path):
    _saved(tmp_path)
    marker = tmp_path / "payload-ran"
    th.save({"state_dict": _Payload(marker)}, tmp_path / "policy.pth")
    with pytest.raises(UnsafePolicyFile) as err:
        load_policy(tmp_path)
    assert not marker.exists(), "the payload ran"
    assert "\n" not in str(err.value) and "refusing" in str(err.value) and "policy.pth" in str(err.value)
    assert isinstance(err.value, ValueError)  # the CLI prints a ValueError as one `error:` line


def test_the_cli_refuses_a_planted_payload_with_one_error_line(tmp_path):
    """Through ``retrain_check.max_abs_diff`` (what ``verify`` and the retrain check call) in a fresh process."""
    _saved(tmp_path / "a")
    _saved(tmp_path / "b")
    marker = tmp_path / "payload-ran"
    th.save({"state_dict": _Payload(marker)}, tmp_path / "b" / "policy.pth")
    code = (
        "import sys; from thesis_repro.runs import retrain_check; from thesis_repro.cli.commands import _guarded\n"
        "sys.exit(_guarded(lambda: retrain_check.max_abs_diff(sys.argv[1], sys.argv[2])))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path / "a"), str(tmp_path / "b")], capture_output=True, text=True
    )
    assert done.returncode != 0 and not marker.exists()
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: refusing"), done.stderr


def test_a_legacy_sb3_pickle_is_refused(tmp_path):
    net = _saved(tmp_path)
    net.save(str(tmp_path / "policy.pth"))  # SB3's BasePolicy.save: a pickle of spaces, classes, a function
    with pytest.raises(UnsafePolicyFile, match="not a tensors-only policy file"):
        read_state_dict(tmp_path / "policy.pth")


def test_a_class_outside_the_allowlist_is_refused(tmp_path):
    _saved(tmp_path)
    meta = json.loads((tmp_path / "learner.json").read_text())
    meta["policy_kwargs"]["activation_fn"] = {"class": "os:system"}
    with pytest.raises(ValueError, match="unknown policy constructor class 'os:system'"):
        build_policy(meta, read_state_dict(tmp_path / "policy.pth"))
