"""Commands whose extra is not installed say which one to install, in one line, and exit 2.

A missing package is simulated by ``sys.modules[name] = None``, which makes ``import name``
raise ImportError as if it were not installed.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import typer
from pydantic import SecretStr
from typer.testing import CliRunner

from app.cli import app
from app.commands._extras import install_command, missing_extra_message, require
from app.commands._setup import ENCRYPTED
from app.db.encryption import EncryptionUnavailable
from app.db.session import Database
from app.settings import Settings

# The install from the clone's folder: "attune" on PyPI is another project, and the client is on
# no package index, so pip must be given its folder (README, "With pip").
CLONE = "in the folder of the Attune clone, run"
FLEET = f"attune fleet needs the 'fleet' extra: {CLONE} pip install ./clients/python '.[fleet]'\n"
PLOT = (
    "attune fleet simulate --plot needs the 'fleet' extra: "
    f"{CLONE} pip install ./clients/python '.[fleet]'\n"
)
EXPERIMENTS = (
    f"attune experiment needs the 'experiments' extra: {CLONE} pip install '.[experiments]'\n"
)
ENCRYPTION = (
    "An encrypted SQLite database (ATTUNE_DB_KEY or ATTUNE_DB_KEY_FILE) needs the 'encryption' "
    f"extra: {CLONE} pip install '.[encryption]'\n"
)
NOBODY = "http://127.0.0.1:9"  # nothing listens there: the command must stop before connecting


def without(monkeypatch: pytest.MonkeyPatch, *modules: str) -> None:
    for name in modules:
        monkeypatch.setitem(sys.modules, name, None)


def test_require_passes_when_the_module_imports() -> None:
    require("json", "fleet", "attune fleet")


def test_the_install_commands_are_the_readmes() -> None:
    """Each extra's command is the one the README's "With pip" section gives."""
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    with_pip = readme.split("### With pip", 1)[1].split("\n## ", 1)[0]
    assert install_command("fleet") == "pip install ./clients/python '.[fleet]'"
    assert install_command("dev") == "pip install ./clients/python '.[dev]'"
    assert install_command("experiments") == "pip install '.[experiments]'"
    assert install_command("encryption") == "pip install '.[encryption]'"
    for extra in ("fleet", "experiments", "encryption"):
        assert f"`{extra}`" in with_pip
    for extra in ("fleet", "experiments", "encryption"):
        assert f"`{install_command(extra)}`" in with_pip, extra
    assert "attune[" not in missing_extra_message("fleet", "attune fleet")


def test_require_names_the_extra_and_exits_2(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    without(monkeypatch, "matplotlib")
    with pytest.raises(typer.Exit) as stopped:
        require("matplotlib", "experiments", "attune experiment")
    assert stopped.value.exit_code == 2
    assert capsys.readouterr().err == EXPERIMENTS


@pytest.mark.parametrize("command", ["paper", "ablation"])
def test_experiments_without_matplotlib(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, command: str
) -> None:
    without(monkeypatch, "matplotlib")
    done = CliRunner().invoke(
        app,
        [
            "experiment",
            command,
            "--seeds",
            "1",
            "--users",
            "1",
            "--jobs",
            "1",
            "--out",
            str(tmp_path / "out"),
        ],
    )
    assert done.exit_code == 2
    assert done.stderr == EXPERIMENTS
    assert done.stdout == ""
    assert not (tmp_path / "out").exists()  # stopped before running anything


def test_robustness_without_matplotlib(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    without(monkeypatch, "matplotlib")
    done = CliRunner().invoke(
        app,
        ["experiment", "robustness", "--seeds", "2", "--jobs", "1", "--out", str(tmp_path / "out")],
    )
    assert done.exit_code == 2
    assert done.stderr == EXPERIMENTS
    assert done.stdout == ""
    assert not (tmp_path / "out").exists()


def test_fleet_without_the_client(monkeypatch: pytest.MonkeyPatch) -> None:
    without(monkeypatch, "attune_client")
    done = CliRunner().invoke(app, ["fleet", "simulate", "--key", "att_x", "--url", NOBODY])
    assert done.exit_code == 2
    assert done.stderr == FLEET
    assert done.stdout == ""


def test_fleet_without_the_client_says_so_before_other_options(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    without(monkeypatch, "attune_client")
    monkeypatch.delenv("ATTUNE_KEY", raising=False)
    done = CliRunner().invoke(app, ["fleet", "simulate"])  # no --key either
    assert done.exit_code == 2
    assert done.stderr == FLEET
    # With the client, the missing key is what is said.
    monkeypatch.undo()
    monkeypatch.delenv("ATTUNE_KEY", raising=False)
    done = CliRunner().invoke(app, ["fleet", "simulate"])
    assert done.exit_code == 2
    assert done.stderr == "attune fleet simulate needs an API key: pass --key or set ATTUNE_KEY.\n"


def test_fleet_plot_without_matplotlib(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    without(monkeypatch, "matplotlib")
    done = CliRunner().invoke(
        app,
        [
            "fleet",
            "simulate",
            "--key",
            "att_x",
            "--url",
            NOBODY,
            "--plot",
            str(tmp_path / "reward.png"),
        ],
    )
    assert done.exit_code == 2
    assert done.stderr == PLOT  # before trying the service: no "No service answers"
    # Without --plot, matplotlib is not needed: the command goes on (and finds no service).
    done = CliRunner().invoke(
        app,
        ["fleet", "simulate", "--key", "att_x", "--url", NOBODY, "--timeout", "1", "--no-progress"],
    )
    assert done.exit_code == 2
    assert "No service answers" in done.stderr


def test_the_console_script_prints_one_line_and_no_traceback(tmp_path: Path) -> None:
    """As the ``attune`` script runs it (``app.cli:main``), in a fresh interpreter."""
    code = (
        "import sys; sys.modules['matplotlib'] = None; "
        "sys.argv = ['attune', 'experiment', 'paper', '--seeds', '1', '--out', "
        f"{str(tmp_path / 'out')!r}]; "
        "from app.cli import main; main()"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 2
    assert done.stderr == EXPERIMENTS
    assert done.stdout == ""


def test_a_database_key_without_sqlcipher(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """A key set without the extra: one line naming it, exit 2, and no database file made; the
    service's own engine says the same (``EncryptionUnavailable``)."""
    without(monkeypatch, "sqlcipher3", "sqlcipher3.dbapi2")
    url = f"sqlite:///{tmp_path / 'attune.db'}"
    env = {"ATTUNE_DATABASE_URL": url, "ATTUNE_DB_KEY": "a passphrase", "ATTUNE_DB_KEY_FILE": None}
    for args in (["db", "upgrade"], ["serve", "--port", "9"], ["keys", "list"]):
        done = CliRunner(env=env).invoke(app, args)
        assert done.exit_code == 2, args
        assert done.stderr == ENCRYPTION
        assert "a passphrase" not in done.output
    assert not (tmp_path / "attune.db").exists()
    assert str(EncryptionUnavailable()) + "\n" == ENCRYPTION
    assert missing_extra_message("encryption", ENCRYPTED) + "\n" == ENCRYPTION
    key = SecretStr("a passphrase")
    settings = Settings(database_url=url, db_key=key, _env_file=None)  # type: ignore[call-arg]
    with pytest.raises(EncryptionUnavailable):
        Database(settings)
