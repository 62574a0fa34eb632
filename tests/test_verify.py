"""``make verify`` and shipped evaluations: the generator ships evaluation entries keyed by
the shipped policy; ``verify`` recomputes a seeded sample of them and compares (bit-identical on the platform that
made them, else within ``VERIFY_RTOL``), prints a table and fails on a mismatch. Toy kinds, a temporary layer."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from thesis_repro import figures
from thesis_repro.cli import verify
from thesis_repro.cli.commands import main
from thesis_repro.core import backends, job_kinds
from thesis_repro.core.cache import Job, Result, RunCache, find_entry, read_entry, save_arrays, write_manifest
from thesis_repro.runs import generator, retrain_check, shipped_checks
from thesis_repro.runs import layer as runs


# ---------------------------------------------------------------- toy kinds (importable by path: the worker imports us)
def _policy(config: dict, workdir: Path) -> dict:
    (workdir / "out" / "weights.txt").write_text(str(config["w"]))
    return {"train_return": float(config["w"])}


def _evaluation(config: dict, workdir: Path) -> dict:
    """An evaluation: loads its policy through the cache that runs it, returns (points x rollouts) returns."""
    policy = RunCache.current().run(Job("test-verify-policy", config["train"]))
    if config.get("policy") != policy.identity:
        raise AssertionError("evaluated another policy than the one its key pins")
    w = float((policy.out / "weights.txt").read_text())
    returns = 100.0 * w + np.arange(2 * config["test"]["n"], dtype=np.float64).reshape(2, -1) / 7.0
    return {"returns": returns, "expected_return": returns.mean(axis=1), "auc": float(returns.sum() / 3.0)}


def _deps(config: dict) -> dict:
    return {"policy": Job("test-verify-policy", config["train"])}


def _pool_execute(job: Job, root: str | None, reference: str | bool) -> Result:
    """A pool worker's entry point from this module: unpickling it imports us, which registers the toy kinds."""
    return backends.execute(job, root, reference)


job_kinds.register("test-verify-policy", "tests.test_verify:_policy", label=lambda c: f"w{c['w']}")
job_kinds.register(
    "test-verify-eval",
    "tests.test_verify:_evaluation",
    label=lambda c: f"w{c['train']['w']}__eval",
    deps="tests.test_verify:_deps",
    pin=True,
)
TRAINS = [{"w": w} for w in (1, 2, 3)]


def _eval_job(train: dict) -> Job:
    return Job("test-verify-eval", {"train": train, "test": {"n": 3}})


@pytest.fixture
def toy_figure(monkeypatch):
    """A figure making 3 toy policies and their evaluations at every scale; ``verify`` checks the toy kind."""

    @figures.register_figure(
        "_verify", "toy figure", kinds=["test-verify-policy", "test-verify-eval"], settings_id="_example"
    )
    def _grid(settings):
        return [Job("test-verify-policy", t) for t in TRAINS] + [_eval_job(t) for t in TRAINS]

    monkeypatch.setattr(verify, "KINDS", ("test-verify-eval",))
    monkeypatch.setattr(verify, "VERIFIABLE", ("test-verify-eval",))
    yield
    figures.FIGURES.pop("_verify", None)


def _generate(layer: Path, kind: str) -> tuple[list[runs.Exported], list[str]]:
    lines: list[str] = []
    out = generator.generate("smoke", ["_verify"], kinds=[kind], layer_root=layer, log=lines.append)
    return out, lines


@pytest.fixture
def layer(toy_figure, tmp_path, monkeypatch) -> Path:
    """A shipped layer (``THESIS_REPRO_REFERENCE``) with the 3 toy policies and their 3 evaluations."""
    layer = tmp_path / "reference"
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(layer))
    _generate(layer, "test-verify-policy")
    _generate(layer, "test-verify-eval")
    return layer


def _evaluations(layer: Path) -> list[Path]:
    return sorted((layer / "test-verify-eval").iterdir())


NATIVE = {"MKL_CBWR": None, "ATEN_CPU_CAPABILITY": None, "torch_cpu_capability": "AVX512"}


def _rewrite(entry: Path, edit_returns=None, platform: dict | None = None, numerics: dict | None = None) -> None:
    """Forge a shipped entry (a valid manifest, other values, another recorded platform or numerics)."""
    if edit_returns is not None:
        values, _ = read_entry(entry)
        returns = edit_returns(np.array(values["returns"]))
        save_arrays(entry / "arrays.npz", {"returns": returns, "expected_return": returns.mean(axis=1)})
    prov = json.loads((entry / "provenance.json").read_text())
    if platform is not None:
        prov["platform"] = platform
    if numerics is not None:
        prov["numerics"] = numerics
    (entry / "provenance.json").write_text(json.dumps(prov))
    write_manifest(entry)


# ---------------------------------------------------------------- item 2: the generator ships evaluations
def test_the_generator_ships_evaluations_keyed_by_the_shipped_policy(toy_figure, tmp_path):
    layer = tmp_path / "reference"
    out, lines = _generate(layer, "test-verify-eval")
    assert out == [] and any("3 test-verify-eval jobs skipped" in line and "not shipped" in line for line in lines)

    assert len(_generate(layer, "test-verify-policy")[0]) == 3
    out, _ = _generate(layer, "test-verify-eval")
    assert len(out) == 3 and all(e.path.parent == layer / "test-verify-eval" for e in out)
    for e in out:
        files = {p.name for p in e.path.iterdir()}
        assert {"config.json", "provenance.json", "result.json", "arrays.npz", "manifest.json"} <= files
        assert e.bytes < 20_000
    assert _generate(layer, "test-verify-eval")[1][0].endswith(
        f"3 already shipped, 0 to produce (0 env steps in all) -> {layer}"
    )

    # a fresh clone loads them (same key: the shipped policy's identity), nothing is re-evaluated
    clone = RunCache(tmp_path / "clone", reference=layer)
    assert all(clone.run(_eval_job(t)).source == "shipped" for t in TRAINS)
    assert shipped_checks.check_shipped("smoke", layer) == []  # shipped evaluations count under their bound keys


def test_export_requires_an_evaluations_values(tmp_path):
    cache = RunCache(tmp_path / "runs", reference=False)
    result = cache.run(Job("square", {"x": 2}))
    (result.path / "config.json").write_text(
        json.dumps({**json.loads((result.path / "config.json").read_text()), "kind": "evaluate"})
    )
    with pytest.raises(ValueError, match="lacks arrays.npz"):
        runs.export(result, tmp_path / "layer")


# ---------------------------------------------------------------- item 3: make verify
def test_verify_passes_on_shipped_evaluations(layer, capsys):
    assert main(["verify", "--scale", "smoke", "-n", "2", "--seed", "5"]) == 0
    out = capsys.readouterr().out
    assert "2 of 3 shipped test-verify-eval entries, seed 5 (repeat with --seed 5)" in out
    assert out.count(" identical") == 2 and "2/2 match" in out and "MISMATCH" not in out
    header = next(line for line in out.splitlines() if line.startswith("entry"))
    assert header.split() == ["entry", "shipped", "recomputed", "|diff|", "verdict"]
    chosen = verify.sample(_evaluations(layer), 2, 5)
    assert chosen == verify.sample(_evaluations(layer), 2, 5)  # the seed repeats the sample
    assert all(verify._name(p) in out for p in chosen)


def test_verify_is_bit_for_bit_where_numerics_are_pinned_and_states_the_native_tolerance(layer, capsys):
    same, other_native, other_pinned = _evaluations(layer)
    _rewrite(same, lambda r: r + np.eye(*r.shape))  # one rollout 1.0 higher, on the platform that made it
    # 1 % off, made elsewhere under THESIS_REPRO_NUMERICS=native: the one case a tolerance applies
    _rewrite(other_native, lambda r: r * 1.01, platform={"cpu": "another CPU"}, numerics=NATIVE)
    # 1 % off, made elsewhere with pinned numerics (the default): a CPU flag is no excuse
    _rewrite(other_pinned, lambda r: r * 1.01, platform={"cpu": "another CPU"})
    assert main(["verify", "--scale", "smoke", "-n", "3", "--seed", "0"]) == 1
    out = capsys.readouterr().out
    assert "bit-identical wherever the numerics are pinned" in out and "THESIS_REPRO_NUMERICS=native" in out
    rows = {line.split()[0]: line for line in out.splitlines() if line.startswith("w")}
    row = rows[verify._name(same)]
    assert "MISMATCH: not bit-identical (max |diff| 1," in row and row.split()[3] == "1"  # |diff|
    assert "within 5% (native numerics on another CPU" in rows[verify._name(other_native)]
    assert "MISMATCH: not bit-identical" in rows[verify._name(other_pinned)]
    assert "1/3 match; 2 MISMATCH" in out


def _key(entry: Path) -> str:
    return entry.name.rsplit("__", 1)[1]


def test_a_consistent_edit_is_caught_by_verify_entry_and_verify_figure(layer, capsys):
    """The fault checks' edit: one evaluation's returns x1.045 and its manifest rehashed; every manifest check
    passes."""
    target = _evaluations(layer)[1]
    _rewrite(target, lambda r: r * 1.045)
    assert shipped_checks.verify_shipped(layer) == {}  # the manifest is consistent: only recomputing catches it
    assert main(["verify", "--scale", "smoke", "--entry", _key(target)[:8]]) == 1
    out = capsys.readouterr().out
    assert "1 shipped entry to recompute" in out and "0/1 match; 1 MISMATCH" in out
    assert "MISMATCH: not bit-identical (max |diff| " in out and "0.0431 relative" in out
    assert main(["verify", "--scale", "smoke", "--entry", target.name.rsplit("__", 1)[0]]) == 1  # by label
    assert "1 shipped entry to recompute" in capsys.readouterr().out
    assert main(["verify", "--scale", "smoke", "--figure", "_verify"]) == 1
    out = capsys.readouterr().out
    assert "figure _verify: 3 shipped entries to recompute" in out
    assert "2/3 match; 1 MISMATCH" in out
    rows = {line.split()[0]: line for line in out.splitlines() if line.startswith("w")}
    assert "MISMATCH" in rows[verify._name(target)]
    assert main(["verify", "--scale", "smoke", "--all"]) == 1
    assert "2/3 match; 1 MISMATCH" in capsys.readouterr().out


def test_verify_claim_recomputes_its_entries_and_compares_its_pages_with_the_snapshot(layer, monkeypatch, capsys):
    monkeypatch.setattr(verify, "claim_pages", lambda cid: ["fig-_verify"])
    saved = {"page": "fig-_verify", "frames": {"auc": [{"seed": 0, "auc": 317.41}]}, "kit": "k"}
    snapshot = {**saved, "frames": {"auc": [{"seed": 0, "auc": 331.70}]}}  # edited, index rehashed

    def pages(pages, scale, layer, root, log, rtol):
        return {"fig-_verify.data.json": verify.compare_saved(saved, snapshot, rtol)}

    monkeypatch.setattr(verify, "recompute_pages", pages)
    assert main(["verify", "--scale", "smoke", "--claim", "toy"]) == 1
    out = capsys.readouterr().out
    assert "claim toy (pages fig-_verify): 3 shipped entries to recompute" in out and "3/3 match" in out
    assert "fig-_verify.data.json: MISMATCH: the snapshot differs from the recomputed page in frames auc" in out


def test_a_page_on_entries_made_under_native_numerics_is_compared_within_the_tolerance(layer, monkeypatch, capsys):
    """An entry made under native numerics on another CPU matches only within VERIFY_RTOL, so the page rebuilt
    from it is compared within it too (a clean clone's claim check once failed on such a page)."""
    monkeypatch.setattr(verify, "claim_pages", lambda cid: ["fig-_verify"])
    native = lambda chosen, layer, root: {  # noqa: E731
        p: verify.Check(p.name, 1.0, 1.01, 0.01, "within 5% (native numerics on another CPU: ...)", True)
        for p in chosen
    }
    monkeypatch.setattr(verify, "_check_all", native)
    saved = {"page": "fig-_verify", "frames": {"auc": [{"seed": 0, "auc": 317.41}]}, "kit": "k"}
    near = {**saved, "frames": {"auc": [{"seed": 0, "auc": 320.0}]}}  # 0.8 % off
    got = []

    def pages(pages, scale, layer, root, log, rtol):
        got.append(rtol)
        return {"fig-_verify.data.json": verify.compare_saved(saved, near, rtol)}

    monkeypatch.setattr(verify, "recompute_pages", pages)
    assert main(["verify", "--scale", "smoke", "--claim", "toy"]) == 0
    assert got == [verify.VERIFY_RTOL]
    assert "fig-_verify.data.json: within 5% (its entries were made under native numerics" in capsys.readouterr().out


def test_verify_reports_a_corrupt_entry_and_skips_one_whose_policy_is_not_shipped(layer, capsys):
    by_train = {json.dumps(read_entry(p)[1]["config"]["train"]): p for p in _evaluations(layer)}
    orphan, corrupt = by_train[json.dumps(TRAINS[0])], by_train[json.dumps(TRAINS[1])]
    shutil.rmtree(find_entry(layer, Job("test-verify-policy", TRAINS[0])))  # its evaluation is stale now
    (corrupt / "result.json").write_text("{}")  # fails its manifest
    assert main(["verify", "--scale", "smoke", "-n", "3", "--seed", "0"]) == 1
    out = capsys.readouterr().out
    assert "2 of 2 shipped test-verify-eval entries" in out and "1 other shipped test-verify-eval entries" in out
    assert verify._name(orphan) not in out
    rows = {line.split()[0]: line for line in out.splitlines() if line.startswith("w")}
    assert "MISMATCH: shipped entry is corrupt" in rows[verify._name(corrupt)]


def test_verify_with_no_shipped_evaluations_says_so(toy_figure, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(tmp_path / "empty"))
    assert main(["verify", "--scale", "smoke"]) == 0
    out = capsys.readouterr().out
    assert "no shipped evaluations yet at scale smoke" in out and "nothing verified" in out


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["verify", "-n", "0"], "error: argument -n: invalid value '0'; valid values are integers >= 1"),
        (["verify", "-n", "-3"], "error: argument -n: invalid value '-3'; valid values are integers >= 1"),
        (["verify", "--scale", "medium"], "error: unknown scale 'medium'; valid scales are: 'smoke', 'small', 'full'"),
        (["verify", "--kind", "train"], "error: --kind: invalid value 'train'; valid kinds are: 'evaluate', 'arm-"),
        (["verify", "--figure", "9.9"], "error: unknown --figure figure '9.9'; valid --figure figures are: '3.2'"),
        (["verify", "--entry", "ab"], "error: --entry: 'ab' is too short"),
        (["verify", "--entry", "0123456789abcdef0123"], "error: --entry: no shipped entry named '0123456789abcdef"),
        (["verify", "--claim", "nosuch"], "error: unknown claim 'nosuch'; known: "),
        (["verify", "--figure", "3.3", "--all"], "error: verify: --figure and --all exclude each other"),
    ],
)
def test_verify_bad_input_is_one_error_line(argv, says, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(says)


def test_verify_kind_samples_other_shipped_kinds(layer, monkeypatch, capsys):
    monkeypatch.setattr(verify, "VERIFIABLE", ("test-verify-eval", "test-verify-policy"))
    assert main(["verify", "--scale", "smoke", "-n", "6", "--seed", "1", "--kind", "test-verify-policy"]) == 0
    out = capsys.readouterr().out
    assert "3 of 3 shipped test-verify-policy entries" in out and "3/3 match" in out
    assert all(verify._name(p) not in out for p in _evaluations(layer))
    assert main(["verify", "--scale", "smoke", "-n", "6", "--kind", "test-verify-policy", "test-verify-eval"]) == 0
    out = capsys.readouterr().out
    assert "6 of 6 shipped test-verify-policy/test-verify-eval entries" in out and "6/6 match" in out
    assert out.count(" identical") == 6


def test_a_long_verification_lists_only_the_entries_that_are_not_identical():
    same = verify.Check("e", 1.0, 1.0, 0.0, "identical", True)
    odd = verify.Check("odd", 1.0, 1.5, 0.5, "MISMATCH: not bit-identical (max |diff| 0.5)", False)
    lines: list[str] = []
    ok = verify._report({Path(str(i)): same for i in range(verify.LISTED)}, lines.append)
    assert ok and sum(" identical" in ln for ln in "\n".join(lines).splitlines()) == verify.LISTED  # all listed
    lines.clear()
    ok = verify._report({**{Path(str(i)): same for i in range(verify.LISTED)}, Path("odd"): odd}, lines.append)
    out = "\n".join(lines)
    assert not ok and "odd " in out and f"{verify.LISTED} entries bit-identical (not listed)" in out
    assert f"{verify.LISTED}/{verify.LISTED + 1} match; 1 MISMATCH" in out and out.count(" identical\n") == 0
    lines.clear()
    assert verify._report({Path(str(i)): same for i in range(verify.LISTED + 1)}, lines.append)
    assert "entry" not in "\n".join(lines) and f"{verify.LISTED + 1} entries bit-identical" in "\n".join(lines)


def test_verify_run_checks_n():
    with pytest.raises(ValueError, match="valid values are integers >= 1"):
        verify.run_checks("smoke", 0)


# ---------------------------------------------------------------- the rules
def test_compare_rules():
    a = {"returns": np.array([[100.0, 200.0]]), "auc": 3.0, "label": "x"}
    assert verify.compare_values(a, a, same=True).verdict == "identical"
    near = {**a, "returns": np.array([[90.0, 211.0]])}  # rollouts differ, their mean by 0.3 %
    assert not verify.compare_values(a, near, same=True).ok
    assert verify.compare_values(a, near, same=False).ok and verify.compare_values(a, near, same=None).ok
    assert "native numerics, platform not recorded" in verify.compare_values(a, near, same=None).verdict
    assert not verify.compare_values(a, {**a, "auc": 3.0 * 1.2}, same=False).ok
    assert not verify.compare_values(a, {**a, "label": "y"}, same=False).ok
    assert "different values" in verify.compare_values(a, {"returns": a["returns"], "label": "x"}, same=False).verdict
    nan = {"returns": np.array([[np.nan, 1.0]])}
    assert verify.compare_values(nan, nan, same=True).verdict == "identical"
    check = verify.compare_values(a, near, same=False, entry="e")
    assert check.row()["shipped"] == "150.00" and check.row()["|diff|"] == "11"
    assert verify.VERIFY_RTOL == retrain_check.OUTCOME_RTOL


def test_arm_kinds_compare_their_summaries_across_platforms():
    """A CMA-ES search redone on another CPU: weights and curves are other samples, the outcome must agree."""
    arm = {"mean_total_cost": 2224.8, "final_cost": np.array([1.62, 0.16]), "W": np.array([[0.3, -0.2]])}
    other_path = {**arm, "mean_total_cost": 2223.8, "final_cost": np.array([1.62, 0.22]), "W": np.array([[0.5, 0.1]])}
    assert not verify.compare_values(arm, other_path, same=False).ok  # the evaluations' rule: final_cost off by 6 %
    ok = verify.compare_values(arm, other_path, same=False, summaries_only=True)
    assert ok.ok and ok.verdict == "within 5% (native numerics on another CPU: summaries differ by 0.0%)"
    assert not verify.compare_values(arm, other_path, same=True, summaries_only=True).ok  # same platform: bit-identity
    worse = {**other_path, "mean_total_cost": 2224.8 * 1.2}
    assert (
        "MISMATCH: summaries differ by 16.7% > 5%"
        in verify.compare_values(arm, worse, False, summaries_only=True).verdict
    )
    assert set(verify.VERIFIABLE) == {*verify.KINDS, *verify.ARM_KINDS}
    assert all(job_kinds.KINDS.get(k) for k in verify.ARM_KINDS)  # each names a registered kind


def test_a_curriculum_entry_with_named_phases_compares():
    """Fig 5.6's curriculum entries carry an array of phase names beside their numbers: compared as values, not
    a NumPy truth-value error (`verify --entry NC__s9` used to end in one)."""
    cl = {"curve": np.array([0.5, 0.2]), "phases": np.array(["reach", "bic"])}
    assert verify.compare_values(cl, {k: v.copy() for k, v in cl.items()}, same=True).verdict == "identical"
    other = {**cl, "phases": np.array(["throw", "bic"])}
    assert verify.compare_values(cl, other, same=True).verdict == "MISMATCH: phases differ"


def _train_entry(tmp_path: Path, resumed_from: int, start: str) -> Result:
    path = tmp_path / f"r{resumed_from}-{start[:10]}"
    path.mkdir()
    (path / "provenance.json").write_text(json.dumps({"start": start}))
    return Result(path, {"resumed_from": resumed_from}, {}, source="shipped")


def test_resume_note_says_whether_the_shipped_run_was_resumed_exactly(tmp_path):
    assert "without interruption" in verify.resume_note(_train_entry(tmp_path, 0, "2026-11-20T00:00:00+00:00"))
    before = verify.resume_note(_train_entry(tmp_path, 20480, "2026-11-20T00:00:00+00:00"))
    assert "resumed from step 20,480 before exact resume landed" in before and "NOT" in before
    after = verify.resume_note(_train_entry(tmp_path, 20480, "2026-11-25T10:00:00+00:00"))
    assert "after exact resume landed" in after and "bit-identical" in after


def test_a_failing_evaluation_is_one_logged_line_and_the_generator_goes_on(toy_figure, tmp_path, monkeypatch):
    """An evaluation that fails while the policies train is one log line: the trainings and the other
    evaluations land, the generator ends normally and names it, and the next run makes it."""
    real = _evaluation

    def flaky(config: dict, workdir: Path) -> dict:
        if config["train"]["w"] == 2:
            raise RuntimeError("planted\n  failure")
        return real(config, workdir)

    monkeypatch.setattr(sys.modules[__name__], "_evaluation", flaky)
    layer, lines = tmp_path / "reference", []
    kinds = ["test-verify-policy", "test-verify-eval"]
    out = generator.generate("smoke", ["_verify"], kinds, layer_root=layer, log=lines.append)
    assert sorted(e.path.parent.name for e in out) == ["test-verify-eval"] * 2 + ["test-verify-policy"] * 3
    failed = [line for line in lines if "FAILED" in line]
    assert len(failed) == 1 and "w2__eval" in failed[0] and failed[0].endswith("planted failure")
    assert lines[-1] == "1 evaluation(s) failed and were left for the next run: w2__eval"
    monkeypatch.setattr(sys.modules[__name__], "_evaluation", real)
    again = generator.generate("smoke", ["_verify"], kinds, layer_root=layer, log=str)
    assert [e.path.name.split("__")[0] for e in again] == ["w2"]


def test_evaluations_follow_their_policy_in_one_command(toy_figure, tmp_path, monkeypatch):
    """`--kind train evaluate`: each evaluation runs as soon as the policy it loads is shipped (an item's evaluations
    land with its last training run), keyed as the two-step generator keys them; a rerun produces nothing."""
    layer = tmp_path / "reference"
    lines: list[str] = []
    out = generator.generate(
        "smoke", ["_verify"], ["test-verify-policy", "test-verify-eval"], layer_root=layer, log=lines.append
    )
    assert [e.path.parent.name for e in out] == [
        "test-verify-policy",
        "test-verify-eval",
    ] * 3  # each policy, then its eval
    assert sum("[follows] test-verify-eval" in line for line in lines) == 3
    two_step = tmp_path / "two-step"
    _generate(two_step, "test-verify-policy")
    assert sorted(p.name for p in _evaluations(layer)) == sorted(
        e.path.name for e in _generate(two_step, "test-verify-eval")[0]
    )
    kinds = ["test-verify-policy", "test-verify-eval"]
    again = generator.generate("smoke", ["_verify"], kinds, layer_root=layer, log=str)
    assert again == []
    # two at a time: the [i/n] tags count the training jobs alone, the evaluations that follow them are untagged
    pooled: list[str] = []
    monkeypatch.setattr(backends, "execute", _pool_execute)  # the pool pickles it by name: workers import us
    generator.generate("smoke", ["_verify"], kinds, layer_root=tmp_path / "pooled", n_jobs=2, log=pooled.append)
    assert sorted(line.split()[0] for line in pooled if line.startswith("[") and "follows" not in line) == [
        "[1/3]",
        "[2/3]",
        "[3/3]",
    ]
    assert sum(line.startswith("[follows] test-verify-eval") for line in pooled) == 3


def test_verify_entry_takes_a_label_and_names_the_keys_when_the_label_is_ambiguous(tmp_path):
    """``--entry ppo__Hopper__s4__obs`` finds the one shipped entry of that label; two of one label ask for a key."""
    one, two = (tmp_path / "evaluate" / f"ppo__Hopper__s4__obs__{k * 20}" for k in "ab")
    one.mkdir(parents=True)
    assert verify.find_shipped("ppo__Hopper__s4__obs", tmp_path) == one
    assert verify.find_shipped("aaaaaa", tmp_path) == one
    two.mkdir()
    with pytest.raises(ValueError, match=r"names 2 shipped entries \(keys aaaaaaaaaa, bbbbbbbbbb\); pass one key"):
        verify.find_shipped("ppo__Hopper__s4__obs", tmp_path)
