"""Library errors speak in library words; the CLI adds the flags (contract: Exit codes and
streams)."""

from __future__ import annotations

import ast
import pickle
import re
from collections.abc import Iterator
from pathlib import Path

import pytest
import typer
from twincd_cli.common import command, fail, flag_hint

from twincd.errors import LogReadError, RobotModelError, Terminated, TwincdError, UsageError

LIBRARY = Path(__file__).resolve().parents[1] / "twincd"
# a command-line flag: -c, --robot (not "non-negative", "IV-B", "{n}-sample")
FLAG = re.compile(r"(?<![\w-])--?[A-Za-z]")
ROOTS = {"TwincdError", "MethodSkipped"}


def _name(node: ast.expr) -> str:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return node.attr
    return ""


def _error_classes(trees: list[ast.Module]) -> set[str]:
    """TwincdError, MethodSkipped and every class of the library derived from them."""
    names = set(ROOTS)
    grew = True
    while grew:
        grew = False
        for tree in trees:
            for node in ast.walk(tree):
                if (
                    isinstance(node, ast.ClassDef)
                    and node.name not in names
                    and any(_name(b) in names for b in node.bases)
                ):
                    names.add(node.name)
                    grew = True
    return names


def _texts(node: ast.AST) -> Iterator[str]:
    """String constants under ``node``; an f-string reads with ``0`` for each field."""
    if isinstance(node, ast.JoinedStr):
        yield "".join(
            v.value if isinstance(v, ast.Constant) and isinstance(v.value, str) else "0"
            for v in node.values
        )
        return
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        yield node.value
        return
    for child in ast.iter_child_nodes(node):
        yield from _texts(child)


def _assigned(scope: ast.AST, name: str) -> Iterator[ast.AST]:
    for node in ast.walk(scope):
        if isinstance(node, ast.Assign | ast.AnnAssign) and node.value is not None:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            if any(isinstance(t, ast.Name) and t.id == name for t in targets):
                yield node.value


def flagged_messages(source: str, classes: set[str], where: str) -> list[str]:
    """Strings built into an error of ``classes`` that name a flag, as ``where:line: text``."""
    tree = ast.parse(source)
    found = []
    scopes: list[ast.AST] = [tree]
    scopes += [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)]
    for scope in scopes:
        for call in ast.walk(scope):
            if not (isinstance(call, ast.Call) and _name(call.func) in classes):
                continue
            parts: list[ast.AST] = [*call.args, *(k.value for k in call.keywords)]
            for part in list(parts):
                if (
                    isinstance(part, ast.Name) and scope is not tree
                ):  # hint = "..."; Error(.., hint)
                    parts += _assigned(scope, part.id)
            found += [
                f"{where}:{call.lineno}: {text}"
                for part in parts
                for text in _texts(part)
                if FLAG.search(text)
            ]
    return sorted(set(found))


def test_the_scan_sees_flags() -> None:
    classes = {"TwincdError", "MethodSkipped", "UsageError"}
    bad = """
def f(n):
    hint = "pass --robot"
    raise UsageError("x", "y", hint)
def g(n):
    raise MethodSkipped(f"needs {n} logs (-c)")
"""
    good = """
def f(n):
    raise UsageError(f"too short for {n}-sample windows", "non-negative", "IV-B", option="robot")
"""
    assert len(flagged_messages(bad, classes, "bad")) == 2
    assert flagged_messages(good, classes, "good") == []


def test_no_library_error_names_a_flag() -> None:
    files = sorted(LIBRARY.rglob("*.py"))
    sources = {path: path.read_text(encoding="utf-8") for path in files}
    classes = _error_classes([ast.parse(s) for s in sources.values()])
    assert {"UsageError", "NotFittedError", "SettingsError", "MethodSkipped"} <= classes
    found = [
        hit
        for path, source in sources.items()
        for hit in flagged_messages(source, classes, str(path.relative_to(LIBRARY.parent)))
    ]
    assert found == [], "library errors must not name flags (set option=...):\n" + "\n".join(found)


def test_errors_survive_pickling_with_their_option() -> None:
    err = pickle.loads(pickle.dumps(RobotModelError("what", "where", "hint", option="robot")))
    assert isinstance(err, RobotModelError)
    assert err.message == "what (where) — hint" and err.option == "robot"
    plain = pickle.loads(pickle.dumps(LogReadError("what", "where", "hint")))
    assert plain.option is None and plain.message == "what (where) — hint"


def test_flag_hint() -> None:
    assert flag_hint(None) == ""
    assert flag_hint("robot") == "(option --robot)"
    assert flag_hint("label_topic") == "(option --label-topic)"
    assert flag_hint("calibration,train,val") == "(options -c/--calibration, --train, --val)"
    assert flag_hint("some_new_setting") == "(option --some-new-setting)"


def test_a_command_s_own_flags_are_declared_not_patched_in() -> None:
    """watch names a causal calibration by fit's flag; other commands by their own, whichever
    ran first in the process."""
    assert flag_hint("causal", "watch") == "(option fit --causal)"
    assert flag_hint("causal", "detect") == "(option --causal/--zero-phase)"
    assert flag_hint("causal") == "(option --causal/--zero-phase)"  # outside a command


@pytest.mark.parametrize(
    ("exc", "line"),
    [
        (
            UsageError(
                "repeats must be at least 1", "repeats=0", "give 1 or more", option="repeats"
            ),
            "twincd: error: repeats must be at least 1 (repeats=0) — give 1 or more"
            " (option --repeats)",
        ),
        (TwincdError("a", "b", "c"), "twincd: error: a (b) — c"),
    ],
)
def test_fail_adds_the_flag_on_one_line(
    exc: TwincdError, line: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(typer.Exit) as done:
        fail(exc, debug=False)
    assert done.value.exit_code == exc.exit_code
    assert capsys.readouterr().err == line + "\n"


@pytest.mark.parametrize(("stop", "code"), [(Terminated(), 143), (KeyboardInterrupt(), 130)])
def test_a_signal_python_wraps_is_still_the_signal(stop: BaseException, code: int) -> None:
    """SIGTERM landing while a class is created comes back as "RuntimeError: Error calling
    __set_name__" (Python wraps it): exit 143 (Ctrl-C: 130), not an internal error's 3."""

    def run_it(quiet: bool = True, debug: bool = False) -> None:
        try:
            raise stop
        except BaseException as inner:
            raise RuntimeError("Error calling __set_name__ on 'Field' instance 'data'") from inner

    with pytest.raises(typer.Exit) as done:
        command(run_it)(quiet=True, debug=False)
    assert done.value.exit_code == code
