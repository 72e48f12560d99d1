"""Config becomes runtime settings in one place: `gateway.settings`. Every other part of the
service takes its settings dataclass and never imports the configuration's models; found by
reading each module's imports (Python's own parser, not a text search)."""

from __future__ import annotations

from tests.support.imports import PACKAGE, imported_modules

ALLOWED = (
    "config/",  # the models themselves
    "settings/",  # the one place they become runtime settings (and a reload compares them)
    "commands/",  # the commands that load a file (run, check-config)
    "console/config_check.py",  # the console's Check: a text loaded as check-config loads it
    "instruments/commands/",  # ... and the instruments' (demo)
    "instruments/demo_broker.py",  # the demo's MQTT section pointed at the broker it starts
)


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
