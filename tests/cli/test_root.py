"""The command line's root: each command's module registers it, and `main` imports only the
module of the command it runs (`roadlink.cli.app_for`)."""

import subprocess
import sys
from typing import Any

import typer

import roadlink.cli
from roadlink.cli import COMMAND_MODULES, app_for


def commands(app: typer.Typer) -> dict[str, Any]:
    """The app's commands by name (a click group's, as typer builds it)."""
    return dict(typer.main.get_command(app).commands)  # type: ignore[attr-defined]


def test_every_command_is_named_with_the_module_that_registers_it_in_the_help_order():
    assert list(commands(roadlink.cli.app)) == list(COMMAND_MODULES)
    for command, module in COMMAND_MODULES.items():
        registering = sys.modules[f"roadlink.cli.{module}"]
        assert any(
            getattr(f, "__module__", None) == registering.__name__
            for f in _callbacks(roadlink.cli.app, command)
        ), command


def _callbacks(app: typer.Typer, name: str) -> list[object]:
    command = commands(app)[name]
    if hasattr(command, "commands"):  # `keys`: its sub-commands' callbacks
        return [c.callback for c in command.commands.values()]
    return [command.callback]


def imported_by(args: list[str]) -> list[str]:
    """The command modules a fresh process imports to build the app for `args`."""
    script = (
        "import sys\n"
        "from roadlink.cli import COMMAND_MODULES, app_for\n"
        f"app_for({args!r})\n"
        "print(' '.join(m for m in dict.fromkeys(COMMAND_MODULES.values())"
        " if f'roadlink.cli.{m}' in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return out.stdout.split()


def test_a_command_line_imports_its_commands_module_alone():
    assert imported_by(["associate", "--json", "x.csv"]) == ["analysis"]
    assert imported_by(["serve", "--help"]) == ["server"]


def test_help_and_unknown_commands_import_every_command():
    everything = list(dict.fromkeys(COMMAND_MODULES.values()))
    assert imported_by([]) == everything
    assert imported_by(["--help"]) == everything
    assert imported_by(["--help", "associate"]) == everything  # the root's help
    assert imported_by(["asociate"]) == everything


def test_a_module_of_one_command_still_runs_it_by_name():
    """`config` is its module's only command: the root's callback keeps `roadlink` a group, where
    a group of one command would take `config` for an argument."""
    out = subprocess.run(
        [sys.executable, "-m", "roadlink.cli", "config"], capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    assert "ROADLINK_DATABASE_URL" in out.stdout


def test_an_unknown_command_is_refused_with_the_known_ones_listed():
    out = subprocess.run(
        [sys.executable, "-m", "roadlink.cli", "asociate"], capture_output=True, text=True
    )
    assert out.returncode == 2
    assert "No such command 'asociate'" in out.stderr


def test_the_app_for_a_command_line_is_the_root_app():
    from roadlink.cli.root import app

    assert app_for(["associate"]) is app
