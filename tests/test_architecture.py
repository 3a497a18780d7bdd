"""The package's dependency rules, checked on the source: a layer imports only the layers
below it, and the core knows nothing of HTTP, SQL, jobs or the command line; and the tests
mirror the package."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "service" / "roadlink"

# What each part of the package may import from roadlink (itself included). A part missing here
# is an error: a new folder must find its place in ARCHITECTURE.md and in this table.
ALLOWED = {
    "association": {"association"},
    "simulation": {"association", "simulation"},
    "plots": {"association"},
    "settings": set(),
    "logs": {"settings", "logs"},
    "configuration": {"settings"},
    "db": {"association", "db", "settings"},
    "queue": {"association", "db", "queue", "settings", "logs"},
    "services": {"association", "db", "queue", "settings", "services", "logs"},
    "api": {
        "association",
        "simulation",
        "plots",
        "db",
        "queue",
        "settings",
        "logs",
        "services",
        "api",
    },
    "cli": {
        "association",
        "simulation",
        "plots",
        "db",
        "queue",
        "settings",
        "logs",
        "configuration",
        "services",
        "api",
        "cli",
    },
}
SHELL_LIBRARIES = {"fastapi", "starlette", "uvicorn", "sqlalchemy", "alembic", "psycopg", "typer"}
CORE = ("association", "simulation", "plots")


def modules() -> Iterator[tuple[str, Path]]:
    for path in sorted(PACKAGE.rglob("*.py")):
        relative = path.relative_to(PACKAGE)
        part = relative.parts[0].removesuffix(".py")
        if part != "__init__":
            yield part, path


def imported(path: Path) -> set[str]:
    """Absolute names of the modules `path` imports (relative imports resolved)."""
    return imported_by(path.read_text(), ["roadlink", *path.relative_to(PACKAGE).parent.parts])


def imported_by(source: str, package: list[str]) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            names.add(".".join([*base, *([node.module] if node.module else [])]))
    return names


def roadlink_parts(names: set[str]) -> set[str]:
    return {name.split(".")[1] for name in names if name.startswith("roadlink.") and "." in name}


@pytest.mark.parametrize(("part", "path"), list(modules()), ids=lambda v: str(v))
def test_a_module_imports_only_the_layers_beneath_it(part: str, path: Path) -> None:
    assert part in ALLOWED, f"{part} has no place in the layer table"
    forbidden = roadlink_parts(imported(path)) - ALLOWED[part]
    assert not forbidden, f"{path.relative_to(PACKAGE)} imports roadlink.{sorted(forbidden)}"


@pytest.mark.parametrize("part", CORE)
def test_the_core_imports_no_web_database_or_command_line_library(part: str) -> None:
    for path in [p for name, p in modules() if name == part]:
        libraries = {name.split(".")[0] for name in imported(path)} & SHELL_LIBRARIES
        assert not libraries, f"{path.relative_to(PACKAGE)} imports {sorted(libraries)}"


WEB_LIBRARIES = {"fastapi", "starlette", "uvicorn"}


def test_the_services_import_no_web_library() -> None:
    """What a request does is told apart from how it came: the services raise ServiceProblem,
    and only the API knows HTTP."""
    paths = [p for name, p in modules() if name == "services"]
    assert paths, "no services package"
    for path in paths:
        libraries = {name.split(".")[0] for name in imported(path)} & WEB_LIBRARIES
        assert not libraries, f"{path.relative_to(PACKAGE)} imports {sorted(libraries)}"


ROUTERS = PACKAGE / "api" / "routers"


@pytest.mark.parametrize("path", sorted(ROUTERS.glob("*.py")), ids=lambda p: p.name)
def test_no_router_imports_another_router(path: Path) -> None:
    """What several routers need lives below them (roadlink/services/ and the like), so that
    each router reads on its own."""
    routers = {
        name
        for name in imported(path)
        if name.startswith("roadlink.api.routers") and name != "roadlink.api.routers"
    }
    assert not routers, f"{path.name} imports {sorted(routers)}"


GENERIC = [PACKAGE / "association" / "associators" / "assignment" / "matching.py"]


@pytest.mark.parametrize("path", GENERIC, ids=lambda p: p.name)
def test_a_generic_solver_imports_nothing_of_the_domain(path: Path) -> None:
    """The assignment solver knows edges and costs, not detections or tracks: it imports no
    roadlink module, so it can be read, tested and reused on its own."""
    ours = {name for name in imported(path) if name.split(".")[0] == "roadlink"}
    assert not ours, f"{path.relative_to(PACKAGE)} imports {sorted(ours)}"


def test_the_reader_resolves_absolute_relative_and_nested_imports() -> None:
    source = "import sqlalchemy\nfrom ..db import models\nfrom . import metrics\n"
    source += "def f():\n    from roadlink.api.errors import ApiProblem\n"
    names = imported_by(source, ["roadlink", "association"])
    assert names == {"sqlalchemy", "roadlink.db", "roadlink.association", "roadlink.api.errors"}
    assert roadlink_parts(names) == {"db", "association", "api"}


DRIVERS = PACKAGE / "db" / "drivers"
# Column types say how a value is stored on each database (SQLAlchemy hands them the dialect).
COLUMN_TYPES = PACKAGE / "db" / "models.py"
MIGRATIONS_ENVIRONMENT = PACKAGE.parent.parent / "migrations" / "env.py"


def test_only_the_drivers_tell_the_databases_apart() -> None:
    """Whatever differs between SQLite and PostgreSQL is asked of the driver
    (`roadlink.db.drivers`): no other module names a database to decide something."""
    for path in [*PACKAGE.rglob("*.py"), MIGRATIONS_ENVIRONMENT]:
        if path.is_relative_to(DRIVERS) or path == COLUMN_TYPES:
            continue
        names = {
            node.value
            for node in ast.walk(ast.parse(path.read_text()))
            if isinstance(node, ast.Constant) and node.value in ("sqlite", "postgresql")
        }
        assert not names, f"{path} tells {sorted(names)} apart itself"


# Modules that are pure declarations (models, constants) and so have no test module of their own;
# each says where what uses it is tested.
DECLARATIONS_ONLY = {
    "api/schemas/examples.py",  # one constant
    "api/schemas/health.py",  # two response models (tests/api/routers/test_health.py)
    "api/schemas/pages.py",  # the page models of the lists (tests/api/test_listing.py)
    "db/drivers/backup_advice.py",  # one exception (tests/cli/test_backup.py)
    "services/problems.py",  # the problem item and its exception (every service test's refusals)
}


def test_every_module_with_behaviour_has_its_test_module_at_the_mirror_path() -> None:
    tests = PACKAGE.parent.parent / "tests"
    missing = [
        f"tests/{relative.parent / ('test_' + relative.name)}".replace("/./", "/")
        for path in sorted(PACKAGE.rglob("*.py"))
        if path.name not in ("__init__.py", "__main__.py")
        and (relative := path.relative_to(PACKAGE)).as_posix() not in DECLARATIONS_ONLY
        and not (tests / relative.parent / f"test_{relative.name}").is_file()
    ]
    assert not missing, (
        f"modules without their test module (or add to DECLARATIONS_ONLY): {missing}"
    )
