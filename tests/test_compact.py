"""The compact arrays layout (``runs --compact``): every shipped number back bit for bit, the old ``.npz`` still
read, and a compact file that does not decode to what it recorded refused."""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

from thesis_repro.core import paths
from thesis_repro.core.cache import entry_identity, read_entry, same_computation, write_manifest
from thesis_repro.core.compact import CODEC, CompactError, is_compact, read_arrays, write_compact
from thesis_repro.runs.layer import compact_entry, compact_shipped, export


def _shipped_train(n: int) -> list[Path]:
    """``n`` shipped training runs of different learners (one-env and many-env runs, curves of several kinds)."""
    found = sorted((paths.ROOT / "data" / "reference" / "train").glob("*__*"))  # the real shipped layer
    picked: dict[str, Path] = {}
    for p in found:
        if not is_compact(p / "arrays.npz"):  # runs the generator shipped compact already are not inputs here
            picked.setdefault(p.name.split("__")[0], p)
    if not picked:
        pytest.skip("no shipped training runs")
    return list(picked.values())[:n]


def _same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    return set(a) == set(b) and all(
        a[k].dtype == b[k].dtype and a[k].shape == b[k].shape and a[k].tobytes() == b[k].tobytes() for k in a
    )


def test_round_trip_is_bit_identical_on_shipped_files(tmp_path: Path) -> None:
    for entry in _shipped_train(12):
        with np.load(entry / "arrays.npz", allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
        out = tmp_path / f"{entry.name}.npz"
        write_compact(out, arrays)
        assert is_compact(out) and _same(read_arrays(out), arrays), entry.name
        assert out.stat().st_size < (entry / "arrays.npz").stat().st_size


def test_edge_cases_round_trip(tmp_path: Path) -> None:
    arrays = {
        "empty_f": np.zeros(0),
        "empty_i": np.zeros(0, dtype=np.int64),
        "nan_payload": np.array([np.nan, -np.nan, 1e-310, np.inf, 0.1]),  # a subnormal float64, not float32-exact
        "wide_ints": np.array([-(2**62), 2**62, 0]),
        "grid": np.arange(0, 10**7, 1000, dtype=np.int64),
        "table": np.arange(12, dtype=np.float64).reshape(4, 3),
        "flags": np.array([True, False]),
        "f32": np.array([1.5, 2.25], dtype=np.float32),
    }
    p = tmp_path / "a.npz"
    write_compact(p, arrays)
    assert _same(read_arrays(p), arrays)
    write_compact(tmp_path / "b.npz", arrays)
    assert p.read_bytes() == (tmp_path / "b.npz").read_bytes()  # bytes depend on the arrays only


def test_old_format_still_read(tmp_path: Path) -> None:
    entry = _shipped_train(1)[0]
    assert not is_compact(entry / "arrays.npz")
    values, _ = read_entry(entry)
    with np.load(entry / "arrays.npz", allow_pickle=False) as npz:
        assert all(values[k].tobytes() == npz[k].tobytes() for k in npz.files)


def test_corrupt_compact_file_is_refused(tmp_path: Path) -> None:
    p = tmp_path / "a.npz"
    write_compact(p, {"episode_lengths": np.array([3, 4]), "episode_returns": np.array([1.0, 2.0])})
    with zipfile.ZipFile(p) as zf:
        members = {n: zf.read(n) for n in zf.namelist()}
    codec = json.loads(members[CODEC])
    codec["arrays"]["episode_returns"]["sha256"] = "0" * 64  # a consistent zip that decodes to other numbers
    members[CODEC] = json.dumps(codec).encode()
    bad = tmp_path / "bad.npz"
    with zipfile.ZipFile(bad, "w") as zf:
        for n, data in members.items():
            zf.writestr(n, data)
    with pytest.raises(CompactError, match="episode_returns"):
        read_arrays(bad)
    codec["format"] = 99
    members[CODEC] = json.dumps(codec).encode()
    with zipfile.ZipFile(bad, "w") as zf:
        for n, data in members.items():
            zf.writestr(n, data)
    with pytest.raises(CompactError, match="format 99"):
        read_arrays(bad)


def test_compact_command_keeps_numbers_and_identity(tmp_path: Path) -> None:
    layer = tmp_path / "layer"
    for entry in _shipped_train(3):
        shutil.copytree(entry, layer / "train" / entry.name)
    before = {p.name: (read_entry(p)[0], entry_identity(p)) for p in (layer / "train").iterdir()}
    done = compact_shipped(layer)
    assert len(done) == len(before) and all(a < b for b, a in done.values())
    for p in (layer / "train").iterdir():
        values, _ = read_entry(p)  # verifies the rewritten manifest too
        old, identity = before[p.name]
        assert entry_identity(p) == identity
        assert set(values) == set(old)
        assert all(not isinstance(v, np.ndarray) or v.tobytes() == values[k].tobytes() for k, v in old.items())
    assert compact_shipped(layer) == {}  # idempotent
    assert compact_entry(next((layer / "train").iterdir())) is None
    # a compact entry whose arrays file is damaged fails its manifest, as any entry does
    victim = next((layer / "train").iterdir())
    data = bytearray((victim / "arrays.npz").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (victim / "arrays.npz").write_bytes(bytes(data))
    with pytest.raises(ValueError, match="arrays.npz"):
        read_entry(victim)


def test_runs_compact_command(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    from thesis_repro.cli.commands import main

    entry = _shipped_train(1)[0]
    shutil.copytree(entry, tmp_path / "train" / entry.name)
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(tmp_path))
    assert main(["runs", "--compact"]) == 0
    assert "1 shipped training runs compacted" in capsys.readouterr().out
    assert is_compact(tmp_path / "train" / entry.name / "arrays.npz")
    assert main(["runs", "--compact"]) == 0 and "0 shipped training runs compacted" in capsys.readouterr().out


def test_export_ships_a_training_run_compact(tmp_path: Path) -> None:
    """A newly shipped training run lands compact: the same arrays bit for bit, the same identity."""
    entry = _shipped_train(1)[0]
    local = tmp_path / "runs" / "train" / entry.name
    shutil.copytree(entry, local)
    if is_compact(local / "arrays.npz"):
        pytest.skip("the shipped run is compact already")
    write_manifest(local, None)  # as the run cache writes a new entry: its identity is its files' hash
    shipped = export(type("Result", (), {"path": local})(), tmp_path / "layer").path
    assert is_compact(shipped / "arrays.npz")
    assert _same(read_arrays(shipped / "arrays.npz"), read_arrays(local / "arrays.npz"))
    assert entry_identity(shipped) == entry_identity(local)
    read_entry(shipped)  # its manifest verifies
    assert compact_entry(shipped) is None


def _run_and_old_export(local_root: Path, layer_root: Path) -> tuple[Path, Path]:
    """A new local training run and its compact copy in the layer, committed as exports used to commit one: with
    an identity of its own (its files' hash)."""
    entry = _shipped_train(1)[0]
    local, copy = local_root / "train" / entry.name, layer_root / "train" / entry.name
    shutil.copytree(entry, local)
    if is_compact(local / "arrays.npz"):
        pytest.skip("the shipped run is compact already")
    write_manifest(local, None)  # as the run cache writes a new entry
    shutil.copytree(local, copy)
    write_compact(copy / "arrays.npz", read_arrays(local / "arrays.npz"))
    write_manifest(copy, None)
    return local, copy


def test_a_local_run_and_its_compact_copy_are_the_same_computation(tmp_path: Path) -> None:
    """A shipped compact copy with an identity of its own (as exports made it before they kept the local one) is
    still the local run's computation, so the generator evaluates it; another policy is not."""
    local, copy = _run_and_old_export(tmp_path / "runs", tmp_path / "layer")
    assert entry_identity(copy) != entry_identity(local)
    assert same_computation(local, copy) and same_computation(copy, local)
    policy = copy / "out" / "policy.pth"
    policy.write_bytes(policy.read_bytes() + b"\0")
    write_manifest(copy, None)
    assert not same_computation(local, copy)


def test_the_generator_evaluates_a_run_whose_shipped_copy_has_an_identity_of_its_own(tmp_path: Path) -> None:
    """The generating machine's local run and its compact shipped copy (committed with the copy's own identity):
    the evaluation is bound to the shipped identity and the local run adopts it, so the job that loads the local
    run finds the identity it was bound to."""
    from thesis_repro.core.cache import Job, RunCache
    from thesis_repro.runs.generator import Queued, _bind_to_layer

    local, shipped = _run_and_old_export(tmp_path / "runs", tmp_path / "layer")
    train = json.loads((local / "config.json").read_text())["config"]
    job = Job("evaluate", {"train": train, "test": {"perturbation": "obs", "sigmas": [0.0], "n_rollouts": 1}})
    assert local.name.endswith(Job("train", train).key)
    lines: list[str] = []
    bound = _bind_to_layer([Queued(job)], tmp_path / "layer", RunCache(tmp_path / "runs"), lines.append)
    assert len(bound) == 1 and bound[0].job.config["policy"] == entry_identity(shipped) and not lines
    assert entry_identity(local) == entry_identity(shipped)
    read_entry(local)  # its manifest still verifies
