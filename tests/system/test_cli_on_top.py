"""The CLI sits on top: it loads each command's module by name (`importlib`, so no import
checker sees the edge), and none of them may import it back for its exit codes, or a command
would load every other. The exit codes have their own module, `gateway.exit_codes`."""

from __future__ import annotations

from gateway import exit_codes
from tests.support.imports import PACKAGE, imported_modules

ENTRY = "__main__.py"  # `python -m gateway`: the one module above the CLI


def test_no_module_imports_the_cli_back() -> None:
    importers = sorted(
        path.relative_to(PACKAGE).as_posix()
        for path in PACKAGE.rglob("*.py")
        if "gateway.cli" in imported_modules(path)
    )
    assert ENTRY in importers  # the walk finds what it looks for
    others = [name for name in importers if name != ENTRY]
    assert others == [], f"these import gateway.cli; take gateway.exit_codes instead: {others}"


def test_the_codes_a_service_manager_acts_on_are_distinct() -> None:
    codes = {name: value for name, value in vars(exit_codes).items() if name.startswith("EXIT_")}
    assert len(set(codes.values())) == len(codes), codes
    # The systemd unit's RestartPreventExitStatus= and the README name these numbers.
    assert (codes["EXIT_CONFIG"], codes["EXIT_STARTUP"]) == (3, 4)
