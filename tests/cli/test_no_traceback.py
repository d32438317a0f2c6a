"""Every command, given a workspace (or file) that does not exist, ends in one line, no traceback.

The commands are found by walking the CLI itself, so a new command is covered the day it lands.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import pytest
import typer
import typer.core
from typer.testing import CliRunner

from cam2sim.cli.main import app

if TYPE_CHECKING:
    from pathlib import Path

# Commands that do not take an existing input (the demo builds its own).
NO_INPUT = {"demo"}


def _commands() -> list[tuple[list[str], Any]]:
    root = typer.main.get_command(app)
    ctx = typer.core.TyperGroup.make_context(root, "cam2sim", [], resilient_parsing=True)
    out: list[tuple[list[str], Any]] = []

    def walk(cmd: Any, path: list[str]) -> None:
        if hasattr(cmd, "list_commands"):
            for name in cmd.list_commands(ctx):
                walk(cmd.get_command(ctx, name), [*path, name])
        elif path[-1] not in NO_INPUT:
            out.append((path, cmd))

    walk(root, [])
    return out


COMMANDS = _commands()


def _args(cmd: Any, missing: Path) -> list[str]:
    """The command's required arguments and options, each a path that does not exist."""
    args: list[str] = []
    for p in cmd.params:
        if not p.required:
            continue
        value = str(missing / p.name)
        args += [value] if not p.opts[0].startswith("-") else [p.opts[0], value]
    return args


def test_the_walk_finds_every_command() -> None:
    names = {" ".join(path) for path, _ in COMMANDS}
    assert {"detect", "drive", "run", "campaign", "ads train", "evaluate drive"} <= names
    assert len(names) >= 20


@pytest.mark.parametrize(("path", "cmd"), COMMANDS, ids=[" ".join(p) for p, _ in COMMANDS])
def test_a_missing_input_is_one_line_and_exit_1(path: list[str], cmd: Any, tmp_path: Path) -> None:
    missing = tmp_path / "nothing-here"
    result = CliRunner().invoke(app, [*path, *_args(cmd, missing)])
    text = result.output
    assert result.exit_code != 0, text
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(
        result.exception
    )
    assert "Traceback" not in text
    assert "error" in text.lower()
    assert "nothing-here" in text  # names what is missing
    assert not missing.exists()  # and creates nothing in its place


def test_an_unexpected_error_is_one_line_unless_debug(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import cam2sim.stages.extract as extract_stage

    def boom(*_: object, **__: object) -> None:
        msg = "something nobody planned for"
        raise RuntimeError(msg)

    monkeypatch.setattr(extract_stage, "extract", boom)
    from cam2sim.core.config import Config
    from cam2sim.core.workspace import Workspace

    ws = Workspace.create(tmp_path / "ws", Config())
    result = CliRunner().invoke(app, ["extract", str(ws.root)])
    assert result.exit_code == 1
    assert "unexpected RuntimeError: something nobody planned for" in result.output
    assert "--debug" in result.output
    assert "Traceback" not in result.output
    result = CliRunner().invoke(app, ["--debug", "extract", str(ws.root)])
    assert isinstance(result.exception, RuntimeError)  # the traceback is the user's to see


def test_os_errors_name_the_file_and_the_fix(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import cam2sim.stages.extract as extract_stage

    def denied(*_: object, **__: object) -> None:
        raise PermissionError(13, "Permission denied", str(tmp_path / "ws" / "dataset"))

    monkeypatch.setattr(extract_stage, "extract", denied)
    from cam2sim.core.config import Config
    from cam2sim.core.workspace import Workspace

    ws = Workspace.create(tmp_path / "ws", Config())
    result = CliRunner().invoke(app, ["extract", str(ws.root)])
    assert result.exit_code == 1
    assert "permission denied" in result.output
    assert "dataset" in result.output


CHILD = """
import os, sys
if {reader_gone}:
    r, w = os.pipe(); os.close(r); os.dup2(w, 1); os.close(w)
    sys.stdout = open(1, "w", buffering=1, closefd=False)
import typer
from cam2sim.cli import main as m

@m.app.command("shout")
def shout() -> None:
    typer.echo("x")
    raise BrokenPipeError(32, "Broken pipe")  # reached only while stdout still has a reader

sys.argv = ["cam2sim", "shout"]
m.main()
"""


@pytest.mark.parametrize("reader_gone", [True, False])
def test_a_reader_that_leaves_early_ends_the_command_quietly(reader_gone: bool) -> None:
    # `cam2sim ... | head`: head has left when the command prints, and it ends without the
    # "cam2sim bug" line. A broken pipe that is not stdout's (a socket) is still reported.
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-c", CHILD.format(reader_gone=reader_gone)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr, done.stderr
    assert ("cam2sim bug" in done.stderr) is not reader_gone, done.stderr
