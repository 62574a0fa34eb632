"""Regenerate the chapter-3 CSVs of ``data/thesis/`` from the thesis's extracted plain text.

The CSVs are the committed, reviewed reference; this script only documents (and can repeat) how the
chapter-3 ones were transcribed. Rows are taken strictly in order, 4 per environment, because the env
labels of Tables 3.5 and 3.7 are misplaced in the extracted text (see README.md).

Usage::

    .venv/bin/python data/thesis/transcribe.py /path/to/thesis.txt
"""

from __future__ import annotations

import csv
import re
import sys
from pathlib import Path

from thesis_repro.core import paths

ENVS = ["Walker2d", "Hopper", "HalfCheetah", "InvertedPendulum", "InvertedDoublePendulum"]
TESTS = ["obs", "act", "env", "dom"]
TEST_TOKENS = {"OBS.": "obs", "ACT.": "act", "ENV.": "env", "DOM.": "dom"}
METHOD_NAMES = {
    "PPO": "ppo",
    "TRPO": "trpo",
    "DDPG": "ddpg",
    "SAC": "sac",
    "PPO-16": "ppo-16",
    "PPO-SCN": "ppo-scn",
    "PPO-SCN-16": "ppo-scn-16",
    "PPO-ENT": "ppo-ent",
    "PPO-APRL": "ppo-arpl",  # thesis typo for ARPL (Mandlekar et al., 2017)
    "PPO-OBSNOISE": "ppo-obsnoise",
    "PPO-ACTNOISE": "ppo-actnoise",
    "PPO-ENVNOISE": "ppo-envnoise",
    "PPO-MDL": "ppo-mdl",
    "PPO-EPOPT": "ppo-epopt",
    "PPO-MAML-DG": "ppo-maml-dg",
    "PPO-REPTILE-DG": "ppo-reptile-dg",
}
PM = re.compile(r"(-?\d+(?:\.\d+)?)\s*\\pm\s*(\d+(?:\.\d+)?)")


def _block(lines: list[str], caption: str, n_rows: int) -> tuple[list[str], list[str]]:
    """Header cells and the ``n_rows`` data lines following the first line starting with ``caption``."""
    start = next(i for i, line in enumerate(lines) if line.startswith(caption))
    header_at = next(i for i in range(start, len(lines)) if lines[i].startswith("ENV. NAME"))
    header = [c.strip() for c in lines[header_at].split("\t") if c.strip() not in ("", "ENV. NAME", "TEST")]
    return header, lines[header_at + 1 : header_at + 1 + n_rows]


def auc_table(lines: list[str], number: str) -> list[dict]:
    """Tidy rows (env, test, method, mean, std) of Table 3.4-3.7, rows taken strictly in order."""
    header, body = _block(lines, f"Table {number}:", 20)
    methods = [METHOD_NAMES[h.upper()] for h in header]
    rows = []
    for k, line in enumerate(body):
        env, test = ENVS[k // 4], TESTS[k % 4]
        token = next(c.strip() for c in line.split("\t") if c.strip() in TEST_TOKENS)
        if TEST_TOKENS[token] != test:
            raise ValueError(f"Table {number} row {k}: expected {test}, found {token!r}")
        values = PM.findall(line)
        if len(values) != len(methods):
            raise ValueError(f"Table {number} row {k}: {len(values)} values for {len(methods)} methods")
        for method, (mean, std) in zip(methods, values, strict=True):
            rows.append({"env": env, "test": test, "method": method, "mean": mean, "std": std})
    return rows


def fig3_3c(lines: list[str]) -> list[dict]:
    """Correlation coefficients of Figure 3.3(c): 5 envs x 4 tests."""
    start = next(i for i, line in enumerate(lines) if line.strip().split("\t") == ["OBS.", "ACT.", "ENV.", "DOM."])
    rows = []
    for k, env in enumerate(ENVS):
        cells = lines[start + 1 + k].split("\t")
        for test, value in zip(TESTS, cells[1:5], strict=True):
            rows.append({"env": env, "test": test, "value": value.strip()})
    return rows


def table3_3(lines: list[str]) -> tuple[list[dict], list[dict]]:
    """Table 3.3 (a) training returns and (b) testing returns of Walker2d-PPO."""
    start = next(i for i, line in enumerate(lines) if line.startswith("(a) Training performance"))
    a_lines = lines[start + 3 : start + 7]
    a_rows = []
    for k, line in enumerate(a_lines):
        values = PM.findall(line)
        noise = next(c.strip() for c in line.split("\t") if c.strip().endswith(".")).rstrip(".").lower()
        if k == 0:  # the deterministic column holds a single value (one policy for all noise types)
            mean, std = values.pop(0)
            a_rows.append(
                {"train_condition": "deterministic", "train_sigma": 0.0, "noise_type": "none", "mean": mean, "std": std}
            )
        ((mean, std),) = values
        a_rows.append({"train_condition": "noisy", "train_sigma": 0.2, "noise_type": noise, "mean": mean, "std": std})
    start = next(i for i, line in enumerate(lines) if line.startswith("(b) Testing performance"))
    b_rows = []
    for k, line in enumerate(lines[start + 2 : start + 14]):
        noise, sigma_te = TESTS[k // 3], [0.0, 0.2, 0.4][k % 3]
        cells = [c.strip() for c in line.split("\t")]
        if float(cells[1]) != sigma_te or (cells[0] and TEST_TOKENS[cells[0]] != noise):
            raise ValueError(f"Table 3.3(b) row {k} is not ({noise}, {sigma_te}): {line!r}")
        for train_sigma, (mean, std) in zip([0.0, 0.2], PM.findall(line), strict=True):
            b_rows.append(
                {"noise_type": noise, "sigma_te": sigma_te, "train_sigma": train_sigma, "mean": mean, "std": std}
            )
    return a_rows, b_rows


def write(name: str, rows: list[dict]) -> None:
    """Write ``rows`` to ``data/thesis/<name>.csv``."""
    with paths.thesis_table_path(name).open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def main(thesis_txt: str) -> None:
    lines = Path(thesis_txt).read_text().splitlines()
    write("fig3_3c", fig3_3c(lines))
    a_rows, b_rows = table3_3(lines)
    write("table3_3a", a_rows)
    write("table3_3b", b_rows)
    for number in ["3.4", "3.5", "3.6", "3.7"]:
        write(f"table{number.replace('.', '_')}", auc_table(lines, number))


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    main(sys.argv[1])
