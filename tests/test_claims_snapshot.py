"""The shipped claims snapshot: a fresh clone's ``claims`` judges the numbers the pages saved where the book ran,
identically to that build, says so on stderr, and never judges a corrupt or missing file."""

from __future__ import annotations

import gzip
import json

import pytest

from thesis_repro.claims import cli, evidence, ledger, ledger_row, registry, report, snapshot, store
from thesis_repro.claims import synthetic as S

SCALE = "small"
IDS = ["3.3-negative-correlation", "3.3-not-valid-metric", "4.1-harder-settings"]


def _measures(page: str) -> set[str]:
    return {s.rule["measure"] for s in registry.specs() if "measure" in s.rule and page in s.data_pages}


@pytest.fixture
def built(tmp_path, monkeypatch):
    """Every file the ledger reads, saved by this kit (synthetic per-seed numbers) in a private build folder,
    with a private shipped layer; returns the build's figures folder."""
    for var in ("THESIS_REPRO_BUILD", "THESIS_REPRO_DATA", "THESIS_REPRO_REFERENCE", "THESIS_REPRO_PUBLISHED_BUILD"):
        monkeypatch.setenv(var, str(tmp_path / var.lower()))
    for name in snapshot.files():
        page = snapshot.page_of(name)
        if name.endswith(".rule.json"):
            n = max(
                int(s.rule["page_verdict"]) for s in registry.specs() if s.page == page and "page_verdict" in s.rule
            )
            report.save_rule(page, SCALE, [report.Verdict(page, "c", report.REPRODUCES, "e")] * (n + 1))
        else:
            # every measure's frames; chapter 5's arm curves ("cast_bic") replace the generic ones of that name
            measures = sorted(_measures(page), key=lambda m: (m == "cast_bic", m))
            frames = {k: v for m in measures for k, v in S.frames_for(m, 3, 0).items()}
            store.save_page(page, SCALE, frames, {"scale": SCALE})
    return store.data_path("fig-3.3", SCALE).parent


def _ledger(ids=IDS):
    with store.one_pass():  # each page read once, as `claims` reads them
        return {i: ledger.judge(registry.spec(i), SCALE, with_null=False) for i in ids}


def _verdict(row: ledger_row.Row) -> dict:
    return {k: v for k, v in row.as_dict().items() if k != "shipped_pages"}


def _clear(build) -> None:
    for p in build.iterdir():
        p.unlink()


def test_the_snapshot_judges_every_claim_exactly_as_the_build_it_was_shipped_from(built, capsys):
    ids = [s.id for s in registry.specs()]
    before = _ledger(ids)
    assert snapshot.ship(SCALE) == snapshot.files()  # every data file written the first time
    _clear(built)  # a fresh clone: no build, only the shipped layer
    after = _ledger(ids)
    assert {i: _verdict(r) for i, r in after.items()} == {i: _verdict(r) for i, r in before.items()}
    assert after["3.3-negative-correlation"].shipped == ["fig-3.3"]
    assert after["3.3-not-valid-metric"].shipped == ["fig-3.3"]  # derived claims carry their parts' pages
    assert evidence.describe(after["3.3-negative-correlation"]).endswith(
        "numbers of fig-3.3 from the shipped claims snapshot (not computed here)"
    )
    assert "shipped claims snapshot" not in evidence.describe(before["3.3-negative-correlation"])
    assert all(r.status != report.NOT_COMPUTED and not r.stale for r in after.values())

    assert cli.main(["--scale", SCALE, "--json", "--no-null", "--ids", *IDS]) == 0
    out, err = capsys.readouterr()
    blob = json.loads(out)
    assert blob["shipped_pages"] == ["fig-3.3", "fig-4.1"] and "shipped at" in blob["snapshot"]
    assert err.count("\n") == 1 and err.startswith("shipped: the numbers of 2 page(s) (fig-3.3, fig-4.1)")
    assert "`make book SCALE=small`" in err


def test_shipping_again_rewrites_no_data_file_and_is_deterministic(built):
    snapshot.ship(SCALE)
    data = {p.name: p.read_bytes() for p in snapshot.folder(SCALE).glob("*.gz")}
    assert snapshot.ship(SCALE) == []
    assert {p.name: p.read_bytes() for p in snapshot.folder(SCALE).glob("*.gz")} == data
    # the code stamp lives in the index, not in the data file
    blob = json.loads(gzip.decompress(data["fig-3.3.data.json.gz"]))
    assert (
        "kit" not in blob
        and snapshot.read("fig-3.3.data.json", SCALE)["kit"]
        == snapshot.index(SCALE)["files"]["fig-3.3.data.json"]["kit"]
    )


def test_a_fresh_build_copy_wins_and_a_stale_one_yields_to_the_snapshot(built):
    snapshot.ship(SCALE)
    s = registry.spec("3.3-negative-correlation")
    assert ledger.judge(s, SCALE, with_null=False).shipped == []  # the build's own numbers first
    path = store.data_path("fig-3.3", SCALE)
    blob = json.loads(path.read_text())
    path.write_text(json.dumps({**blob, "kit": "0" * 12}))  # written by other kit code
    row = ledger.judge(s, SCALE, with_null=False)
    assert row.shipped == ["fig-3.3"] and row.stale == []


def test_retrain_ignores_the_snapshot(built, monkeypatch):
    snapshot.ship(SCALE)
    _clear(built)
    monkeypatch.setenv("THESIS_REPRO_RETRAIN", "1")
    assert ledger.judge(registry.spec("3.3-negative-correlation"), SCALE, with_null=False).status == report.NOT_COMPUTED


def test_a_corrupt_shipped_file_is_never_judged(built, capsys):
    snapshot.ship(SCALE)
    _clear(built)
    gz = snapshot.folder(SCALE) / "fig-3.3.data.json.gz"
    data = bytearray(gz.read_bytes())
    data[-1] ^= 0xFF
    gz.write_bytes(bytes(data))
    row = ledger.judge(registry.spec("3.3-negative-correlation"), SCALE, with_null=False)
    assert row.status == report.NOT_COMPUTED
    assert "corrupt" in row.note and "`make figure-3.3 SCALE=small`" in row.note
    assert ledger.judge(registry.spec("4.1-harder-settings"), SCALE, with_null=False).status != report.NOT_COMPUTED

    page = next(s for s in registry.specs() if "page_verdict" in s.rule).page
    (snapshot.folder(SCALE) / f"{page}.rule.json.gz").unlink()  # a missing file is unreadable, not absent
    row = ledger.judge(next(s for s in registry.specs() if "page_verdict" in s.rule), SCALE, with_null=False)
    assert row.status == report.NOT_COMPUTED and "unreadable" in row.note


def test_shipping_refuses_missing_or_stale_pages_in_one_line(built, capsys):
    path = store.data_path("fig-3.3", SCALE)
    blob = json.loads(path.read_text())
    path.write_text(json.dumps({**blob, "kit": "0" * 12}))
    store.data_path("fig-4.1", SCALE).unlink()
    with pytest.raises(ValueError, match=r"not run: fig-4.1; stale: fig-3.3\); run `make book SCALE=small` first"):
        snapshot.ship(SCALE)
    assert cli.main(["--scale", SCALE, "--ship"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: cannot ship the claims snapshot at small")
    assert not snapshot.folder(SCALE).exists()  # nothing half-shipped


def test_check_compares_this_builds_numbers_with_the_shipped_ones(built, capsys):
    snapshot.ship(SCALE)
    n = len(snapshot.files())
    assert cli.main(["--scale", SCALE, "--check-snapshot"]) == 0
    assert capsys.readouterr().out.splitlines()[-1].startswith(f"{n}/{n} saved files identical")
    s = registry.spec("3.3-negative-correlation")
    frames = S.frames_for(s.rule["measure"], 3, 1)  # other numbers, saved by this kit
    store.save_page("fig-3.3", SCALE, frames, {"scale": SCALE})
    store.data_path("fig-4.1", SCALE).unlink()
    got = snapshot.check(SCALE)
    assert got["fig-3.3.data.json"].startswith("differs (frames ") and got["fig-4.1.data.json"] == "not run here"
    assert sum(v == "identical" for v in got.values()) == n - 2
    assert cli.main(["--scale", SCALE, "--check-snapshot"]) == 1


def test_a_book_says_when_the_snapshot_is_out_of_date(built):
    assert snapshot.refresh_hint(SCALE) == ""  # nothing shipped: nothing to refresh
    snapshot.ship(SCALE)
    assert snapshot.refresh_hint(SCALE) == ""
    store.save_page("fig-3.3", SCALE, S.frames_for("correlation", 3, 1), {"scale": SCALE})  # other numbers
    idx = snapshot.folder(SCALE) / snapshot.INDEX
    blob = json.loads(idx.read_text())
    blob["files"]["fig-4.1.data.json"]["kit"] = "0" * 12  # shipped by other kit code
    idx.write_text(json.dumps(blob))
    n = len(snapshot.files())
    assert snapshot.refresh_hint(SCALE).endswith(
        f"out of date: of its {n} files, 1 differ from this build's numbers and 1 were shipped by other kit code; "
        "`make ship-claims SCALE=small` refreshes it from this build"
    )
