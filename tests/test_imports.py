"""What depends on what: no import cycle among the app's modules, counting imports inside
functions and those made for type checking only (where cycles hide), and the package __init__
every import of a submodule runs; the packages of app/ form layers (no cycle among them either);
and the commands that need no filter or GL start without loading numba or OpenGL."""

from __future__ import annotations

import argparse
import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

from app.cli import build_parser
from tests.conftest import ROOT, SHARED_DATA

APP = ROOT / "app"


def _modules() -> dict[str, Path]:
    mods = {}
    for p in APP.rglob("*.py"):
        name = ".".join(p.relative_to(ROOT).with_suffix("").parts)
        mods[name.removesuffix(".__init__")] = p
    return mods


def _imports(name: str, path: Path, mods: dict[str, Path]) -> set[str]:
    """Modules `name` imports (at run time or for type checking alike), with the packages whose
    __init__ each import runs (not `name`'s own, already running)."""
    tree = ast.parse(path.read_text())
    own = {".".join(name.split(".")[:i]) for i in range(1, name.count(".") + 2)}
    out: set[str] = set()
    for node in ast.walk(tree):
        if not isinstance(node, (ast.Import, ast.ImportFrom)):
            continue
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        else:
            base = node.module or ""
            targets = [
                f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names
            ]
        for target in targets:
            parts = target.split(".")
            for i in range(2, len(parts) + 1):
                t = ".".join(parts[:i])
                if t in mods and t not in own:
                    out.add(t)
    return out


def _cycles(graph: dict[str, set[str]]) -> list[str]:
    state: dict[str, int] = {}  # 1: on the path, 2: done
    cycles = []

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                cycles.append(" -> ".join(path[path.index(n) :] + [n]))
            elif n not in state:
                visit(n, path + [n])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    return cycles


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    return {m: _imports(m, p, mods) for m, p in mods.items()}


def test_no_import_cycles():
    assert _cycles(_graph()) == []


def test_packages_form_layers():
    """`ls app/` reads as the architecture: every module sits in a package (no loose module but
    __init__ and __main__), and the packages import one another in one direction only, so each
    can be read knowing only those below it (docs/ARCHITECTURE.md lists them in this order)."""
    loose = sorted(p.name for p in APP.glob("*.py"))
    assert loose == ["__init__.py", "__main__.py"]
    layers: dict[str, set[str]] = {}
    for m, targets in _graph().items():
        parts = m.split(".")
        if len(parts) < 2 or parts[1] == "__main__":
            continue
        layers.setdefault(parts[1], set()).update(
            t.split(".")[1] for t in targets if t.split(".")[1] != parts[1]
        )
    assert _cycles(layers) == []
    assert layers["core"] == set()  # the ground floor imports nothing of the app
    assert layers["geodesy"] <= {"core"}
    assert {"render", "ui"} & (layers["camera"] | layers["session"] | layers["io"]) == set()


def _loaded(*argv: str) -> set[str]:
    code = (
        "import sys\nfrom app.cli import main\ntry:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
        "print('LOADED:', ' '.join(sorted({m.split('.')[0] for m in sys.modules})))"
    )
    run = subprocess.run(
        [sys.executable, "-c", code, *argv], capture_output=True, text=True, cwd=ROOT
    )
    line = next(x for x in run.stdout.splitlines() if x.startswith("LOADED:"))
    return set(line.split()[1:])


HEAVY = {"numba", "moderngl", "OpenGL", "glfw", "imgui_bundle", "cv2"}


def test_help_starts_without_numba_or_opengl():
    assert _loaded("--help") & HEAVY == set()


@pytest.mark.shared_data
def test_telemetry_starts_without_numba_or_opengl(shared_data):
    clip = shared_data / "real" / "gopro" / "max-heromode.mp4"
    if not clip.is_file():
        pytest.skip(f"{clip} is absent")
    assert SHARED_DATA.is_dir() and _loaded("telemetry", str(clip)) & HEAVY == set()


def test_imports_at_the_top_of_modules():
    """Every import of the app is at its module's top: an import inside a function hides what
    depends on what (and the cycles above). The command line's one lazy step, importing the
    chosen command's module after parsing, goes through importlib in app/cli/__init__.py."""
    inside = []
    for path in sorted(APP.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                inside += [
                    f"{path.relative_to(ROOT)}:{sub.lineno}"
                    for sub in ast.walk(node)
                    if isinstance(sub, (ast.Import, ast.ImportFrom))
                ]
    assert inside == []


def test_every_command_has_its_module():
    """Each command's job names a module of app.cli and a function in it."""
    parser = build_parser()
    jobs = set()

    def walk(p) -> None:
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    walk(sub)
        if p.get_default("job"):
            jobs.add(p.get_default("job"))

    walk(parser)
    assert len(jobs) >= 10
    for job in jobs:
        module, _, function = job.partition(":")
        assert callable(getattr(importlib.import_module(f"app.cli.{module}"), function or "run"))
