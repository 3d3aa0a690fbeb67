"""``attune experiment claims-map --quick``: the files it writes, a table with every claim, the
default setting and the best one, the held-out seeds, --json, and the defaults of the command."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner, Result

from app.cli import app

# The module's shared run is made once: every test of the module on one worker.
pytestmark = pytest.mark.xdist_group("experiment-claims-map")

FILES = ("claims-map.md", "claims-map.csv", "claims-map.png", "summary.json")
AXES = ("time_slots", "p_self", "noise", "m", "optimism", "exclusion", "pref_scale")


def run(out: Path, *extra: str) -> Result:
    return CliRunner(env={"COLUMNS": "40"}).invoke(
        app,
        [
            "experiment",
            "claims-map",
            "--quick",
            "--jobs",
            "1",
            "--no-progress",
            "--out",
            str(out),
            *extra,
        ],
    )


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> tuple[Result, Path, dict[str, Any]]:
    out = tmp_path_factory.mktemp("claims-map")
    done = run(out)
    assert done.exit_code == 0, done.output
    return done, out, json.loads((out / "summary.json").read_text(encoding="utf-8"))


@pytest.mark.slow
def test_writes_the_files(quick: tuple[Result, Path, dict[str, Any]]) -> None:
    done, out, summary = quick
    for name in FILES:
        assert (out / name).stat().st_size > 0, name
    assert (out / "claims-map.png").read_bytes().startswith(b"\x89PNG")
    assert f"Wrote {len(FILES)} files" in done.stderr
    assert [a["key"] for a in summary["axes"]] == list(AXES)
    assert summary["run"]["quick"] is True
    assert summary["run"]["default_map"] is False


@pytest.mark.slow
def test_every_setting_and_claim_is_in_the_summary_and_the_csv(
    quick: tuple[Result, Path, dict[str, Any]],
) -> None:
    _, out, summary = quick
    sizes = [len(a["values"]) for a in summary["axes"]]
    count = 1
    for size in sizes:
        count *= size
    assert summary["settings_count"] == len(summary["settings"]) == count
    claims = [c["key"] for c in summary["claims"]]
    assert len(claims) == 12  # the paper's claims; DTS's is not decided here
    assert sum(summary["histogram"]) == count
    with (out / "claims-map.csv").open(encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == count
    assert list(rows[0]) == [*AXES, "label", "held", *claims]
    for row in rows:
        held = sum(int(row[c]) for c in claims)
        assert int(row["held"]) == held
        assert row["label"] == "default" or row["label"].startswith("reading: ")
    for i, claim in enumerate(summary["claims"]):
        assert 0.0 <= claim["share"] <= 1.0
        assert claim["settings_held"] == sum(s["claims"][i] for s in summary["settings"])


@pytest.mark.slow
def test_best_settings_hold_the_most_claims(quick: tuple[Result, Path, dict[str, Any]]) -> None:
    _, _, summary = quick
    most = max(s["held"] for s in summary["settings"])
    assert summary["best"]
    assert all(b["held"] == most for b in summary["best"])
    assert summary["default"]["label"] == "default"
    assert summary["default"]["held"] <= most
    changes = [
        len(b["label"].split(",")) if b["label"] != "default" else 0 for b in summary["best"]
    ]
    assert changes == sorted(changes)  # fewest changes from the default first


@pytest.mark.slow
def test_default_and_best_are_decided_again_on_held_out_seeds(
    quick: tuple[Result, Path, dict[str, Any]],
) -> None:
    done, _, summary = quick
    confirmation = summary["confirmation"]
    assert confirmation["seeds"][0] == summary["run"]["seeds"]  # after the sweep's seeds
    labels = [c["label"] for c in confirmation["settings"]]
    assert labels[0] == "default"
    assert set(labels[1:]) <= {b["label"] for b in summary["best"]}
    for c in confirmation["settings"]:
        assert c["held"] == sum(c["claims"])
        assert len(c["evidence"]) == 12
    assert "Held-out seeds" in done.stderr


@pytest.mark.slow
def test_the_table_names_every_claim_and_the_elapsed_time(
    quick: tuple[Result, Path, dict[str, Any]],
) -> None:
    done, out, summary = quick
    markdown = (out / "claims-map.md").read_text(encoding="utf-8")
    for claim in summary["claims"]:
        assert claim["key"] in done.stdout
        assert claim["key"] in markdown
    assert "Best setting" in done.stdout
    assert "Elapsed:" in done.stdout
    assert "not the default map" in done.stdout
    assert "Finished" in done.stderr
    assert "s of CPU time" in done.stderr
    assert "runs in" in done.stderr
    assert "a reading" in markdown
    assert "not the paper" in markdown


@pytest.mark.slow
def test_json_is_the_summary(tmp_path: Path) -> None:
    done = run(tmp_path, "--json", "--confirm-seeds", "0")
    assert done.exit_code == 0, done.output
    printed = json.loads(done.stdout)
    assert printed == json.loads((tmp_path / "summary.json").read_text(encoding="utf-8"))
    assert printed["confirmation"] is None


def test_help_explains_the_ranges_and_the_files() -> None:
    done = CliRunner().invoke(app, ["experiment", "claims-map", "--help"])
    assert done.exit_code == 0
    page = " ".join(done.stdout.split())  # the paragraphs, unwrapped
    for text in (
        "--seeds",
        "--confirm-seeds",
        "--quick",
        "--workers",
        "--json",
        "--out",
        "claims-map.csv",
        "claims-map.png",
        "reading",
        "time slots",
        "p_self",
        "noise",
        "known threshold",
        "unknown pairs",
        "exclusion scope",
        "preference scale",
    ):
        assert text in page, text


def test_the_defaults_of_the_command_are_the_maps() -> None:
    from app.experiments import claims_map

    assert claims_map.DEFAULT_SEEDS >= 2  # the map's seeds; more are held out
    assert claims_map.DEFAULT_CONFIRM_SEEDS >= claims_map.DEFAULT_SEEDS
    assert claims_map.DEFAULT_USERS == 6  # the paper's six users
    assert claims_map.TARGET_SECONDS <= 300  # a few minutes on 2 CPUs
