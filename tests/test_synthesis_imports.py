"""The layout of ``ges_core.synthesis``: an acyclic import graph and the step entry points at the top."""

from __future__ import annotations

import ast
from pathlib import Path

import ges_core.synthesis

ROOT = Path(ges_core.synthesis.__file__).parent
PACKAGE = "ges_core.synthesis"


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def imported(name: str, path: Path) -> set[str]:
    """Modules of the package that ``name`` imports anywhere in its file (function-level imports included)."""
    out = set()
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{anchor}.{base}" if base else anchor
            for alias in node.names:  # `from pkg import submodule` imports the submodule
                out.add(f"{base}.{alias.name}" if f"{base}.{alias.name}" in MODULES else base)
    return {m for m in out if m in MODULES and m != name}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of ``graph`` as a path that ends where it starts, or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return [*path[path.index(nxt) :], nxt] if nxt in path else [*path, nxt]
            if nxt not in state and (cycle := visit(nxt, [*path, nxt])):
                return cycle
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (cycle := visit(start, [start])):
            return cycle
    return None


GRAPH = {name: imported(name, path) for name, path in MODULES.items()}


def test_the_import_graph_has_no_cycle():
    assert find_cycle(GRAPH) is None, " -> ".join(find_cycle(GRAPH))


def test_the_graph_sees_the_pipeline_and_its_worker():
    """The check would see the old cycle: the pipeline imports the worker, both import the tasks module."""
    run = f"{PACKAGE}.run"
    assert f"{run}.worker" in GRAPH[f"{run}.pipeline"]
    assert f"{run}.tasks" in GRAPH[f"{run}.worker"] and f"{run}.tasks" in GRAPH[f"{run}.pipeline"]
    assert f"{PACKAGE}.contacts.slicing" in GRAPH[f"{PACKAGE}.contacts.generate"]  # `from pkg import module`
    assert find_cycle({**GRAPH, f"{run}.tasks": {f"{run}.pipeline"}}) is not None


def test_modules_import_no_package_init_of_their_own_step():
    """A module inside the package imports modules, never a package's re-exports (those import it back)."""
    packages = {name for name, path in MODULES.items() if path.name == "__init__.py"}
    for name, path in MODULES.items():
        if path.name != "__init__.py":
            assert not GRAPH[name] & packages, f"{name} imports {sorted(GRAPH[name] & packages)}"


def test_step_entry_points_are_exported_at_the_top():
    for name in ("generate_contacts", "GraspRetargeter", "refine_grasp", "pregrasp", "validate_grasp"):
        assert name in ges_core.synthesis.__all__ and callable(getattr(ges_core.synthesis, name))
    for name in ("SynthesisConfig", "run_synthesis", "run_demo", "table_rows"):
        assert name in ges_core.synthesis.__all__


def test_one_step_module_does_not_import_the_whole_stage():
    """The env's scripted expert imports physics.squeeze; that must not pull in the run, the dataset or trimesh."""
    import subprocess
    import sys

    script = (
        "import sys, ges_core.synthesis.physics.squeeze, ges_core.synthesis as s;"
        "print(sorted(m for m in ('ges_core.synthesis.run', 'ges_core.dataset', 'trimesh') if m in sys.modules));"
        "s.run_synthesis; print('ges_core.synthesis.run' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True).stdout.split("\n")
    assert out[:2] == ["[]", "True"]  # nothing heavy until a run name is asked for, then it is there
