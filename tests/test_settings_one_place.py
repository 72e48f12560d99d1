"""Config becomes runtime settings in one place: `gateway.settings`. Every other part of the
service takes its settings dataclass and never imports the configuration's models; found by
reading each module's imports (Python's own parser, not a text search)."""

from __future__ import annotations

import ast
from pathlib import Path

import gateway

PACKAGE = Path(gateway.__file__).parent
ALLOWED = (
    "config/",  # the models themselves
    "settings/",  # the one place they become runtime settings (and a reload compares them)
    "commands/",  # the commands that load a file (run, check-config)
    "instruments/commands/",  # ... and the instruments' (demo)
    "instruments/demo_broker.py",  # the demo's MQTT section pointed at the broker it starts
)


def imported_modules(path: Path) -> set[str]:
    """Every module `path` imports, relative imports resolved (`from . import config` too)."""
    package = ".".join(("gateway", *path.relative_to(PACKAGE).parent.parts))
    modules: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            modules.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*parent, base] if base else parent)
            modules.add(base)
            modules.update(f"{base}.{alias.name}" for alias in node.names)
    return modules


def config_importers() -> list[str]:
    return sorted(
        path.relative_to(PACKAGE).as_posix()
        for path in PACKAGE.rglob("*.py")
        if any(
            module == "gateway.config" or module.startswith("gateway.config.")
            for module in imported_modules(path)
        )
    )


def test_only_the_settings_module_imports_the_config_models() -> None:
    importers = config_importers()
    assert "settings/__init__.py" in importers  # the walk finds what it looks for
    others = [name for name in importers if not name.startswith(ALLOWED)]
    assert others == [], f"these import gateway.config; give them settings instead: {others}"
