"""The size budgets the architecture page promises for the service package (issue 44), kept by
the suite: no class over `MAX_CLASS_LINES`, no module over `MAX_MODULE_LINES`, at most
`MAX_LONG_FUNCTIONS` functions over `LONG_FUNCTION_LINES`. Measured on the source's syntax tree:
a class or function from its `def`/`class` line to its last line (docstrings and comments
included, decorators not), a module by its lines.

The service is `gateway/` without the instruments (`gateway/instruments/`: the simulator, the
bench, stress and the demo, on their way to a package of their own) and without the module
protoc generates (`sparkplug_b_pb2.py`: nobody edits it).

An offender that can't be mended at once is listed in `ALLOWANCE` with its size then: it may
shrink, not grow, and an entry must go once its offender is within the budget (the test says
so), so the allowance only ever gets shorter. Empty since 2026-11-29 (it held `Bus` and
`GapKeeper`, issue 44).
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import gateway

MAX_CLASS_LINES = 400
MAX_MODULE_LINES = 650
LONG_FUNCTION_LINES = 50
"""A function longer than this is long; the service may have `MAX_LONG_FUNCTIONS` of them."""
MAX_LONG_FUNCTIONS = 8

PACKAGE = Path(gateway.__file__).parent
CHECKOUT = PACKAGE.parent
NOT_THE_SERVICE = ("gateway/instruments/",)
GENERATED = ("gateway/sparkplug/sparkplug_b_pb2.py",)

ALLOWANCE: dict[str, int] = {
    # An offender and its size when it was allowed: remove it once it meets its budget (this
    # test fails until then if it grows, and as soon as the entry is not needed).
}


@dataclass(frozen=True, slots=True)
class Size:
    name: str
    """`gateway/x.py` for a module, `gateway/x.py::Class.method` for a class or function."""
    lines: int
    kind: str
    """"module", "class" or "function"."""

    def __str__(self) -> str:
        return f"{self.name}: {self.lines} lines"


def sizes(source: str, module: str) -> Iterator[Size]:
    """The module's size, and every class's and function's in it (nested ones too)."""
    yield Size(module, len(source.splitlines()), "module")
    yield from _definitions(ast.parse(source), f"{module}::")


def _definitions(node: ast.AST, prefix: str) -> Iterator[Size]:
    for child in ast.iter_child_nodes(node):
        if isinstance(child, ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            name = f"{prefix}{child.name}"
            kind = "class" if isinstance(child, ast.ClassDef) else "function"
            yield Size(name, (child.end_lineno or child.lineno) - child.lineno + 1, kind)
            yield from _definitions(child, f"{name}.")
        else:
            yield from _definitions(child, prefix)


@cache
def service_sizes() -> tuple[Size, ...]:
    found: list[Size] = []
    for path in sorted(PACKAGE.rglob("*.py")):
        module = path.relative_to(CHECKOUT).as_posix()
        if module.startswith(NOT_THE_SERVICE) or module in GENERATED:
            continue
        found += sizes(path.read_text(encoding="utf-8"), module)
    return tuple(found)


BUDGETS = {"module": MAX_MODULE_LINES, "class": MAX_CLASS_LINES, "function": LONG_FUNCTION_LINES}


def over(kind: str) -> list[Size]:
    return [s for s in service_sizes() if s.kind == kind and s.lines > BUDGETS[kind]]


def grown(offenders: list[Size]) -> list[str]:
    return [
        f"{s} (its allowance is {ALLOWANCE[s.name]})"
        for s in offenders
        if s.name in ALLOWANCE and s.lines > ALLOWANCE[s.name]
    ]


def test_no_module_is_over_its_budget() -> None:
    offenders = over("module")
    unallowed = [str(s) for s in offenders if s.name not in ALLOWANCE]
    assert not unallowed, f"modules over {MAX_MODULE_LINES} lines: {unallowed}"
    assert not grown(offenders), f"allowed modules grew: {grown(offenders)}"


def test_no_class_is_over_its_budget() -> None:
    offenders = over("class")
    unallowed = [str(s) for s in offenders if s.name not in ALLOWANCE]
    assert not unallowed, f"classes over {MAX_CLASS_LINES} lines: {unallowed}"
    assert not grown(offenders), f"allowed classes grew: {grown(offenders)}"


def test_few_functions_are_long() -> None:
    long = over("function")
    counted = [str(s) for s in long if s.name not in ALLOWANCE]
    assert len(counted) <= MAX_LONG_FUNCTIONS, (
        f"{len(counted)} functions over {LONG_FUNCTION_LINES} lines, "
        f"at most {MAX_LONG_FUNCTIONS} allowed: {counted}"
    )
    assert not grown(long), f"allowed functions grew: {grown(long)}"


def test_every_allowance_is_still_needed() -> None:
    """An entry goes as soon as its offender is within its budget, or no longer there; and the
    functions' entries all go once the long functions, allowed ones included, fit the budget."""
    measured = {s.name: s for s in service_sizes()}
    unneeded = [
        f"{name}: {measured[name].lines} lines" if name in measured else f"{name}: gone"
        for name in ALLOWANCE
        if name not in measured or measured[name].lines <= BUDGETS[measured[name].kind]
    ]
    assert not unneeded, f"remove these from ALLOWANCE, they meet their budget: {unneeded}"
    long = over("function")
    allowed = [s.name for s in long if s.name in ALLOWANCE]
    assert not allowed or len(long) > MAX_LONG_FUNCTIONS, (
        f"{len(long)} long functions fit the budget of {MAX_LONG_FUNCTIONS}: "
        f"remove the functions' entries from ALLOWANCE: {allowed}"
    )


def test_the_walk_measures_from_the_definition_to_its_last_line() -> None:
    """What the budgets count: a method's lines within its class, nested functions by name,
    async ones too, a decorator not."""
    body = "\n".join(f"        x = {n}" for n in range(49))
    source = (
        "class Drive:\n"
        "    @property\n"
        "    def fifty(self) -> None:\n"
        f"{body}\n"
        "\n"
        "    async def read(self) -> None:\n"
        "        def inner() -> None:\n"
        "            pass\n"
    )
    measured = {s.name: (s.kind, s.lines) for s in sizes(source, "m.py")}
    assert measured == {
        "m.py": ("module", 56),
        "m.py::Drive": ("class", 56),
        "m.py::Drive.fifty": ("function", 50),
        "m.py::Drive.read": ("function", 3),
        "m.py::Drive.read.inner": ("function", 2),
    }


def test_the_service_is_measured_without_the_instruments_and_the_generated_module() -> None:
    names = {s.name for s in service_sizes() if s.kind == "module"}
    assert "gateway/app.py" in names
    assert "gateway/config/sections/mqtt.py" in names
    assert not [n for n in names if n.startswith(NOT_THE_SERVICE) or n in GENERATED]
    assert (CHECKOUT / GENERATED[0]).exists()  # still generated there: the exception is needed


def test_the_architecture_page_says_these_budgets() -> None:
    page = (CHECKOUT / "docs" / "pages" / "architecture.md").read_text(encoding="utf-8")
    assert f"| a module | {MAX_MODULE_LINES} lines |" in page
    assert f"| a class | {MAX_CLASS_LINES} lines |" in page
    functions = f"| functions over {LONG_FUNCTION_LINES} lines | {MAX_LONG_FUNCTIONS} in the whole"
    assert functions in page
