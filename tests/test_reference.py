"""The transcribed thesis tables: shapes, completeness, cross-table consistency, spot values, errors."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pandas as pd
import pytest

from thesis_repro.core import paths, thesis_numbers

AUC_METHODS = {
    "table3_4": ["ppo", "trpo", "ddpg", "sac"],
    "table3_5": ["ppo", "ppo-obsnoise", "ppo-actnoise", "ppo-envnoise", "ppo-mdl"],
    "table3_6": ["ppo", "ppo-16", "ppo-scn", "ppo-scn-16", "ppo-ent", "ppo-arpl"],
    "table3_7": ["ppo", "ppo-mdl", "ppo-epopt", "ppo-maml-dg", "ppo-reptile-dg"],
}
THESIS_TXT = Path(os.environ.get("THESIS_TXT", "/work/shared/thesis.txt"))


def _value(name: str, env: str, test: str, method: str) -> tuple[float, float]:
    row = thesis_numbers.thesis_table(name, env=env, test=test, method=method)
    assert len(row) == 1
    return row["mean"].item(), row["std"].item()


def test_every_table_has_a_csv_and_loads_with_source_thesis():
    on_disk = {p.stem for p in paths.THESIS_DATA.glob("*.csv")}
    assert on_disk == set(thesis_numbers.TABLES)
    for name, columns in thesis_numbers.TABLES.items():
        frame = thesis_numbers.load(name)
        assert list(frame.columns[: len(columns)]) == list(columns)
        assert (frame["source"] == "thesis").all()
        assert not frame.drop(columns=[c for c in ["note"] if c in frame]).isna().any().any()


@pytest.mark.parametrize("name,methods", AUC_METHODS.items())
def test_auc_tables_are_complete_env_test_method_grids(name, methods):
    frame = thesis_numbers.load(name)
    assert len(frame) == 5 * 4 * len(methods)
    assert list(frame["env"].unique()) == list(thesis_numbers.ENVS)
    assert list(frame["test"].unique()) == list(thesis_numbers.TESTS)
    assert list(frame["method"].unique()) == methods
    assert not frame.duplicated(["env", "test", "method"]).any()
    assert (frame["std"] >= 0).all() and (frame["mean"] > 0).all()


def test_fig3_3c_shape_and_spot_values():
    frame = thesis_numbers.load("fig3_3c").set_index(["env", "test"])["value"]
    assert len(frame) == 20 and frame.between(-1, 1).all()
    assert frame["Walker2d", "obs"] == -0.760
    assert frame["HalfCheetah", "obs"] == -0.946
    assert frame["InvertedDoublePendulum", "dom"] == 0.324
    # "Most environments and noise types have clear negative correlation" (Sec 3.3.1)
    assert (frame < 0).sum() == 18


def test_ppo_column_identical_across_tables_3_4_to_3_7_and_mdl_in_3_5_and_3_7():
    def column(name: str, method: str) -> pd.DataFrame:
        frame = thesis_numbers.thesis_table(name, method=method)
        return frame[["env", "test", "mean", "std"]].reset_index(drop=True)

    for name in ["table3_5", "table3_6", "table3_7"]:
        pd.testing.assert_frame_equal(column(name, "ppo"), column("table3_4", "ppo"))
    pd.testing.assert_frame_equal(column("table3_7", "ppo-mdl"), column("table3_5", "ppo-mdl"))


def test_spot_values_including_rows_with_misplaced_labels_in_the_text():
    assert _value("table3_4", "Walker2d", "obs", "sac") == (1565.4, 544.9)
    assert _value("table3_5", "Hopper", "env", "ppo-envnoise") == (2025.1, 520.7)
    assert _value("table3_7", "InvertedDoublePendulum", "dom", "ppo-reptile-dg") == (8293.3, 94.6)
    # rows the extracted text labels "HALFCHEETAH"/"PENDULUM"/"D-PENDULUM" one or two rows early
    assert _value("table3_5", "Hopper", "dom", "ppo-mdl") == (1939.7, 425.0)
    assert _value("table3_5", "InvertedPendulum", "dom", "ppo-mdl") == (999.3, 1.8)
    assert _value("table3_7", "HalfCheetah", "act", "ppo-maml-dg") == (1977.1, 662.1)
    assert _value("table3_6", "Walker2d", "obs", "ppo-ent") == (2442.6, 723.6)
    assert _value("table3_6", "InvertedDoublePendulum", "env", "ppo-arpl") == (3147.3, 1157.1)


def test_table3_3_shapes_values_and_the_claims_of_section_3_3_3():
    a = thesis_numbers.load("table3_3a")
    assert len(a) == 5
    deterministic = a.loc[a["train_condition"] == "deterministic", "mean"].item()
    assert deterministic == 3128.6
    noisy = a[a["train_condition"] == "noisy"].set_index("noise_type")["mean"]
    # (i) training return is lower when adding noise, except environmental noise
    assert (noisy[["obs", "act", "mdl"]] < deterministic).all() and noisy["env"] > deterministic

    b = thesis_numbers.load("table3_3b")
    assert len(b) == 4 * 3 * 2
    assert not b.duplicated(["noise_type", "sigma_te", "train_sigma"]).any()
    ret = b.set_index(["noise_type", "sigma_te", "train_sigma"])["mean"]
    assert ret["obs", 0.0, 0.0] == 3723.9 and ret["dom", 0.4, 0.2] == 2468.2
    # (ii) for obs and act noise, training with sigma=0.2 helps when testing with noise
    for noise in ["obs", "act"]:
        for sigma in [0.2, 0.4]:
            assert ret[noise, sigma, 0.2] > ret[noise, sigma, 0.0]


def test_chapter4_and_5_settings():
    conditions = thesis_numbers.load("chapter4_conditions")
    panels = conditions[conditions["figure"] == "4.1"].set_index("panel")
    assert list(panels.index) == ["a", "b", "c", "d"]
    assert panels.loc["d", ["action_penalty", "wind_low", "wind_high"]].tolist() == [1.0, -2.5, 2.5]
    assert (conditions["wind_low"] == -conditions["wind_high"]).all()

    ch4 = thesis_numbers.load("chapter4_settings").set_index(["parameter", "condition"])["value"]
    per_domain = ch4["batch_size_per_domain", "kl_avg"] * ch4["n_domains_per_iteration", "kl_avg"]
    assert ch4["batch_size", "joint"] == per_domain == ch4["timesteps_per_iteration", "all"]
    ch5 = thesis_numbers.load("chapter5_settings").set_index(["parameter", "condition"])["value"]
    assert ch5["pretraining_trials", "curriculum"] == 6000 and ch5["bic_trials", "curriculum"] == 4000
    assert ch5["n_transfer_experiments", "all"] == ch5["n_task_categories", "all"] ** 2


def test_unknown_names_and_filters_raise_clear_errors():
    with pytest.raises(ValueError, match="valid thesis tables are: .*'table3_4'"):
        thesis_numbers.load("table9_9")
    with pytest.raises(ValueError, match="valid envs are: .*'InvertedPendulum'"):
        thesis_numbers.thesis_table("table3_4", env="Pendulum")
    with pytest.raises(ValueError, match="valid methods are: .*'sac'"):
        thesis_numbers.thesis_table("table3_4", method="ppo-mdl")
    with pytest.raises(ValueError, match="no 'method' column"):
        thesis_numbers.thesis_table("fig3_3c", method="ppo")


def test_load_rejects_a_csv_with_missing_columns_or_values(tmp_path, monkeypatch):
    monkeypatch.setattr(paths, "THESIS_DATA", tmp_path)
    (tmp_path / "fig3_3c.csv").write_text("env,test\nHopper,obs\n")
    with pytest.raises(ValueError, match="lacks columns \\['value'\\]"):
        thesis_numbers.load("fig3_3c")
    (tmp_path / "fig3_3c.csv").write_text("env,test,value\nHopper,obs,\n")
    with pytest.raises(ValueError, match="missing values"):
        thesis_numbers.load("fig3_3c")


@pytest.mark.skipif(not THESIS_TXT.exists(), reason="thesis plain text not available")
def test_csvs_match_a_fresh_transcription_of_the_thesis_text():
    spec = importlib.util.spec_from_file_location("transcribe", paths.THESIS_DATA / "transcribe.py")
    transcribe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(transcribe)
    lines = THESIS_TXT.read_text().splitlines()
    fresh = {"fig3_3c": transcribe.fig3_3c(lines)}
    fresh["table3_3a"], fresh["table3_3b"] = transcribe.table3_3(lines)
    for number in ["3.4", "3.5", "3.6", "3.7"]:
        fresh[f"table{number.replace('.', '_')}"] = transcribe.auc_table(lines, number)
    for name, rows in fresh.items():
        expected = pd.DataFrame(rows).astype({c: float for c in ["mean", "std", "value"] if c in rows[0]})
        got = thesis_numbers.load(name).drop(columns="source")
        pd.testing.assert_frame_equal(got, expected, check_dtype=False)
