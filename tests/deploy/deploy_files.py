"""Reading the deployment files (Dockerfile, compose.yaml) the way their tools read them.

Shared by the deploy tests: a small Dockerfile reader (instructions with their line continuations
joined, exec-form arguments decoded), the compose file as Compose loads it, and what the
`roadlink` command in this checkout offers.
"""

from __future__ import annotations

import http.server
import json
import re
import subprocess
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from typer.testing import CliRunner

from roadlink.cli import app

REPO_ROOT = Path(__file__).resolve().parents[2]
DOCKERFILE = REPO_ROOT / "Dockerfile"
DOCKERIGNORE = REPO_ROOT / ".dockerignore"
COMPOSE_FILE = REPO_ROOT / "compose.yaml"
PYPROJECT = REPO_ROOT / "pyproject.toml"
MIGRATIONS_DIR = REPO_ROOT / "migrations"
OPENAPI_SPEC = REPO_ROOT / "openapi" / "openapi.json"

# The services that run the roadlink image (everything in compose.yaml but the database).
ROADLINK_SERVICES = ("migrate", "api", "worker")


@dataclass(frozen=True)
class Instruction:
    """One Dockerfile instruction: its keyword (upper case), its raw arguments and its stage."""

    keyword: str
    arguments: str
    stage: int
    line: int

    def exec_form(self) -> list[str]:
        """The JSON-array (exec form) arguments, e.g. of ENTRYPOINT, CMD or HEALTHCHECK ... CMD."""
        text = self.arguments
        if self.keyword == "HEALTHCHECK":
            # Options come first (--interval=...), then `CMD` and the command.
            _, _, text = text.partition(" CMD ")
        decoded = json.loads(text)
        assert isinstance(decoded, list), f"line {self.line}: {self.keyword} is not in exec form"
        return [str(part) for part in decoded]


def read_dockerfile(path: Path = DOCKERFILE) -> list[Instruction]:
    """Instructions of a Dockerfile in order, continuation lines joined, comments dropped."""
    instructions: list[Instruction] = []
    stage = -1
    pending = ""
    start = 0
    for number, raw in enumerate(path.read_text().splitlines(), start=1):
        line = raw.strip()
        if not pending and (not line or line.startswith("#")):
            continue
        if pending and line.startswith("#"):
            # Comment lines inside a continued instruction are dropped by the parser too.
            continue
        if not pending:
            start = number
        if line.endswith("\\"):
            pending += line[:-1].rstrip() + " "
            continue
        text = pending + line
        pending = ""
        keyword, _, arguments = text.partition(" ")
        keyword = keyword.upper()
        if keyword == "FROM":
            stage += 1
        instructions.append(Instruction(keyword, arguments.strip(), stage, start))
    return instructions


def stage_names(instructions: list[Instruction]) -> list[str]:
    """The `AS name` of every stage in order ("" for an unnamed stage)."""
    names = []
    for instruction in instructions:
        if instruction.keyword == "FROM":
            match = re.search(r"\s+AS\s+(\S+)$", instruction.arguments, re.IGNORECASE)
            names.append(match.group(1) if match else "")
    return names


def arg_default(instructions: list[Instruction], name: str) -> str:
    """The default value of `ARG name=value` (the first declaration)."""
    for instruction in instructions:
        if instruction.keyword == "ARG":
            key, _, value = instruction.arguments.partition("=")
            if key == name:
                return value
    raise KeyError(f"no ARG {name} in the Dockerfile")


def read_compose(path: Path = COMPOSE_FILE) -> dict[str, Any]:
    """compose.yaml as Compose reads it before interpolation: anchors and merge keys applied."""
    loaded = yaml.safe_load(path.read_text())
    assert isinstance(loaded, dict)
    return loaded


def healthcheck_url(argv: list[str], environment: dict[str, str]) -> str:
    """The URL a `python -c` urllib probe opens, with `os.environ.get(NAME, default)` resolved."""
    code = argv[argv.index("-c") + 1]

    def resolve(match: re.Match[str]) -> str:
        return "'" + environment.get(match.group(1), match.group(2)) + "'"

    # Fold `os.environ.get('X', 'd')` into a literal, then join adjacent literals `'a' + 'b'`.
    code = re.sub(r"os\.environ\.get\('(\w+)',\s*'([^']*)'\)", resolve, code)
    code = re.sub(r"'\s*\+\s*'", "", code)
    match = re.search(r"urlopen\('([^']+)'", code)
    assert match, f"no urlopen('...') with a literal URL in the probe: {code}"
    return match.group(1)


def cli_commands() -> set[str]:
    """The sub-commands `roadlink --help` lists in this checkout."""
    return commands_in_help(CliRunner().invoke(app, ["--help"]).output)


def commands_in_help(help_text: str) -> set[str]:
    """Sub-command names in typer's help screen (rich table or plain), e.g. {"serve", "worker"}."""
    _, _, commands = help_text.partition("Commands")
    # A command name starts a row at the table's left edge; wrapped descriptions are indented more.
    rows = [
        (len(match.group(1)), match.group(2))
        for match in re.finditer(r"^[^\w\s\n]*( *)([a-z][\w-]*)", commands, re.MULTILINE)
    ]
    if not rows:
        return set()
    edge = min(indent for indent, _ in rows)
    return {name for indent, name in rows if indent == edge}


class HealthEndpoint(http.server.BaseHTTPRequestHandler):
    """Answers GET on the server's `probed_path` with the status the test sets, 404 elsewhere."""

    server: ProbedServer

    def do_GET(self) -> None:
        # Recorded before answering: once answered, the probe may exit and the test read the list
        # before this thread had appended to it.
        self.server.requested.append(self.path)
        status = self.server.status if self.path == self.server.probed_path else 404
        self.send_response(status)
        self.end_headers()

    def log_message(self, format: str, *args: object) -> None:
        """Silence the per-request log line."""


class ProbedServer(http.server.ThreadingHTTPServer):
    probed_path: str
    status = 200
    requested: list[str]


def assert_probe_tells_healthy_from_not(
    path: str, probe: Callable[[str], subprocess.CompletedProcess[str]]
) -> None:
    """`probe(port)`, a health check run against a local endpoint on `path`, exits 0 on a 200
    and non-zero on a 503 and on a refused connection."""
    server = ProbedServer(("127.0.0.1", 0), HealthEndpoint)
    server.probed_path, server.requested = path, []
    port = str(server.server_address[1])
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        healthy = probe(port)
        assert healthy.returncode == 0, healthy.stderr
        assert server.requested == [path]
        server.status = 503
        assert probe(port).returncode != 0
    finally:
        server.shutdown()
        server.server_close()
    # Nothing listens any more: a refused connection is unhealthy too.
    assert probe(port).returncode != 0
