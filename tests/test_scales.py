"""The scale table: one table, strict names, overrides only for existing keys."""

from __future__ import annotations

import pytest

from thesis_repro.core import scales


def test_full_scale_is_the_thesis_setting():
    s = scales.figure_settings("_example", "full")
    assert s["train_seeds"] == 12 and s["test_rollouts"] == 20
    sig = s["sigmas"]
    assert len(sig) == 10 and abs(sum(b - a for a, b in zip(sig, sig[1:], strict=False)) / 9 * 10 - 1.0) < 1e-9


def test_scales_are_ordered_by_cost():
    st = [scales.figure_settings("_example", s) for s in scales.SCALES]
    assert st[0]["train_seeds"] <= st[1]["train_seeds"] <= st[2]["train_seeds"]
    assert st[0]["test_rollouts"] <= st[1]["test_rollouts"] <= st[2]["test_rollouts"]


def test_unknown_scale_figure_and_override_are_errors():
    with pytest.raises(ValueError, match="valid scales are: 'smoke', 'small', 'full'"):
        scales.figure_settings("_example", "medium")
    with pytest.raises(ValueError, match="unknown figure '9.9'"):
        scales.figure_settings("9.9", "small")
    with pytest.raises(ValueError, match="unknown setting"):
        scales.figure_settings("_example", "small", train_seed=3)


def test_override_and_every_figure_resolves_at_every_scale():
    assert scales.figure_settings("_example", "small", train_seeds=5)["train_seeds"] == 5
    for fig in scales.figures():
        for sc in scales.SCALES:
            s = scales.figure_settings(fig, sc)
            assert s["figure"] == fig and s["scale"] == sc


def test_the_yaml_loader_reads_every_kit_yaml_file_as_pyyamls_safe_loader_does():
    """core.yamlfile uses libyaml's parser for speed; it must give the same values as PyYAML's pure-Python one."""
    import yaml

    from thesis_repro.core import paths, yamlfile

    files = [*paths.ROOT.joinpath("thesis_repro").rglob("*.yaml"), *paths.ROOT.joinpath("data").glob("**/*.yaml")]
    assert len(files) >= 4
    for f in files:
        text = f.read_text()
        assert yamlfile.parse(text) == yaml.safe_load(text), f
