"""The library's packages import only downstream (docs/architecture.md: read → twin/signal →
prepare → calibrate → detect → evaluate/live → commands; synth and reports beside them): no
package imports one above it, function-local imports included, so no circle joins two
packages, and modules import each other at load time without a circle."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent / "twincd"
# each package's rank: it may import its own and any of lower rank (the root modules:
# defaults, errors, types, version, are below all)
RANKS = {
    "root": 0,
    "io": 1,
    "signal": 2,
    "twin": 3,
    "prepare": 4,
    "executors": 4,
    "synth": 4,
    "calibration": 5,
    "detection": 6,
    "evaluation": 7,
    "live": 7,
    "reports": 8,
    "commands": 9,
}


def package(module: str) -> str:
    """``twincd.a.b`` → ``a`` (a root module → ``root``)."""
    parts = module.split(".")
    if len(parts) < 2:
        return "twincd"  # the public API's lazy index, which names everything
    return parts[1] if len(parts) > 2 or (ROOT / parts[1]).is_dir() else "root"


def modules() -> Iterator[tuple[str, Path]]:
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT.parent).with_suffix("")
        parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
        yield ".".join(parts), path


def is_module(name: str) -> bool:
    path = ROOT.parent.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def type_checking(tree: ast.Module) -> set[int]:
    """The ids of the import nodes under ``if TYPE_CHECKING:`` (never run)."""
    out: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            out |= {id(n) for child in node.body for n in ast.walk(child)}
    return out


def imports(path: Path, module: str, top_level_only: bool = False) -> Iterator[str]:
    """The ``twincd`` modules ``path`` imports when it runs (relative imports resolved; a
    name imported from a package is its submodule when it is one; imports for type checkers
    only are not)."""
    tree = ast.parse(path.read_text())
    skip = type_checking(tree)
    nodes = tree.body if top_level_only else ast.walk(tree)
    for node in nodes:
        if id(node) in skip:
            continue
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                if path.name != "__init__.py":
                    base = base[:-1]
                base = base[: len(base) - node.level + 1]
                name = ".".join([*base, *([node.module] if node.module else [])])
            else:
                name = node.module or ""
            if name.startswith("twincd"):
                subs = [f"{name}.{a.name}" for a in node.names if is_module(f"{name}.{a.name}")]
                yield from subs or [name]
        elif isinstance(node, ast.Import):
            yield from (a.name for a in node.names if a.name.startswith("twincd"))


def test_every_package_has_a_rank() -> None:
    found = {package(m) for m, _ in modules()} - {"twincd"}
    assert found == set(RANKS), found ^ set(RANKS)


@pytest.mark.parametrize(("module", "path"), list(modules()), ids=lambda x: str(x))
def test_no_package_imports_one_above_it(module: str, path: Path) -> None:
    if module == "twincd":  # the public API's lazy index names everything
        return
    mine = package(module)
    up = sorted(
        name
        for name in imports(path, module)
        if name != "twincd" and RANKS[package(name)] > RANKS[mine]
    )
    assert not up, f"{module} ({mine}) imports {up}, above it"


def test_live_imports_nothing_from_commands() -> None:
    for module, path in modules():
        if package(module) == "live":
            assert not [n for n in imports(path, module) if n.startswith("twincd.commands")]


def test_modules_load_without_a_circle() -> None:
    """The import-time graph (module-level imports) has no cycle."""
    known = dict(modules())
    graph = {
        m: {n for n in imports(p, m, top_level_only=True) if n in known and n != m}
        for m, p in known.items()
    }
    state: dict[str, int] = {}

    def visit(m: str, trail: list[str]) -> None:
        state[m] = 1
        for n in graph[m]:
            if state.get(n) == 1:
                raise AssertionError(" → ".join([*trail[trail.index(n) :], n]))
            if n not in state:
                visit(n, [*trail, n])
        state[m] = 2

    for m in graph:
        if m not in state:
            visit(m, [m])
