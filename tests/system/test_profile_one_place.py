"""A maker's knowledge stays in `gateway.profile`: the poller, the MQTT bridge, the settings, the
console and the field tools ask a drive's profile (the `DriveProfile` protocol) what it needs,
never which maker the drive is. Found by reading each module with Python's own parser.

What counts as asking "which maker": the old `is_invt` flag, a name `invt` (`invt: bool`,
`_invt(profile)`), a comparison with a profile's `manufacturer`, or an `isinstance` test against
a maker's profile class. The simulators are exempt: a simulated drive *is* one maker's model.
"""

from __future__ import annotations

import ast
from pathlib import Path

import gateway

PACKAGE = Path(gateway.__file__).parent
EXEMPT = (
    "profile/",  # the makers' knowledge itself
    "instruments/simulator/",  # each simulated drive is one maker's model
    "instruments/commands/simulate.py",  # which models the simulator can play
)
PROFILE_CLASSES = frozenset({"InvtProfile", "GenericProfile", "AbbProfile", "DeviceProfile"})


def maker_questions(source: str) -> list[str]:
    """Each place in `source` that asks which maker a drive is, as "line: what"."""
    found: list[str] = []
    for node in ast.walk(ast.parse(source)):
        line = getattr(node, "lineno", 0)
        if isinstance(node, ast.Attribute) and node.attr in ("is_invt", "invt"):
            found.append(f"{line}: .{node.attr}")
        elif isinstance(node, ast.Name | ast.arg) and _named_invt(node):
            found.append(f"{line}: a name 'invt'")
        elif isinstance(node, ast.FunctionDef) and node.name.strip("_") in ("invt", "is_invt"):
            found.append(f"{line}: def {node.name}")
        elif isinstance(node, ast.Compare) and _compares_manufacturer(node):
            found.append(f"{line}: compares a manufacturer")
        elif isinstance(node, ast.Call) and _isinstance_of_a_profile(node):
            found.append(f"{line}: isinstance of a maker's profile class")
    return found


def _named_invt(node: ast.Name | ast.arg) -> bool:
    name = node.id if isinstance(node, ast.Name) else node.arg
    return name.lower() in ("invt", "is_invt")


def _compares_manufacturer(node: ast.Compare) -> bool:
    sides = [node.left, *node.comparators]
    return any(isinstance(side, ast.Attribute) and side.attr == "manufacturer" for side in sides)


def _isinstance_of_a_profile(node: ast.Call) -> bool:
    if not (isinstance(node.func, ast.Name) and node.func.id == "isinstance"):
        return False
    names = {n.id for n in ast.walk(node) if isinstance(n, ast.Name)}
    names |= {n.attr for n in ast.walk(node) if isinstance(n, ast.Attribute)}
    return bool(names & PROFILE_CLASSES)


def test_the_check_finds_each_kind_of_maker_question() -> None:
    """The walk finds what it looks for (a check that finds nothing proves nothing)."""
    source = (
        "if profile.is_invt: pass\n"
        "def _span(start: int, invt: bool) -> None: pass\n"
        "def _invt(profile) -> bool: return True\n"
        "x = profile.manufacturer == 'ABB'\n"
        "y = isinstance(profile, InvtProfile)\n"
    )
    assert sorted(maker_questions(source)) == [
        "1: .is_invt",
        "2: a name 'invt'",
        "3: def _invt",
        "4: compares a manufacturer",
        "5: isinstance of a maker's profile class",
    ]


def test_no_module_outside_the_profile_asks_which_maker_a_drive_is() -> None:
    asked = {
        path.relative_to(PACKAGE).as_posix(): questions
        for path in sorted(PACKAGE.rglob("*.py"))
        if not path.relative_to(PACKAGE).as_posix().startswith(EXEMPT)
        if (questions := maker_questions(path.read_text(encoding="utf-8")))
    }
    assert asked == {}, f"ask the drive's profile instead (gateway.profile.protocol): {asked}"


def test_the_point_resolver_lives_in_the_profile() -> None:
    assert (PACKAGE / "profile" / "points.py").exists()
    assert not (PACKAGE / "tools" / "points.py").exists()
