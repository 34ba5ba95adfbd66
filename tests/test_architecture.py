"""The package's shape, checked from its source: no import circles, no reaching into another module's privates,
and the policy and the robots independent of each other (a user installs the policy without robot code).

Imports are read with `ast`, so the check sees imports inside functions too (the lazy ones a circle hides in).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "lerobot_focal"

#: Lazy imports between an env's config and its env module: LeRobot's own pattern (the config builds the env
#: only when asked, so parsing a command line never loads the simulator). Module-level circles stay refused.
LAZY_CIRCLES_ALLOWED = (
    {"lerobot_focal.envs.focal_metaworld", "lerobot_focal.envs.metaworld_env"},
    {"lerobot_focal.envs.focal_adroit", "lerobot_focal.envs.adroit_env"},
)


def _modules() -> dict[str, Path]:
    mods = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        mods[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return mods


MODULES = _modules()


def _imports(module: str, top_level_only: bool) -> list[tuple[str, list[str]]]:
    """(imported lerobot_focal module, names taken from it) for each import statement of `module`."""
    path = MODULES[module]
    tree = ast.parse(path.read_text())
    nodes = tree.body if top_level_only else ast.walk(tree)
    out = []
    for node in nodes:
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")[: len(module.split(".")) - node.level + (path.name == "__init__.py")]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            names = [a.name for a in node.names]
            # `from pkg import mod` imports a module; `from mod import name` a name of it
            out += [(f"{target}.{n}", []) for n in names if f"{target}.{n}" in MODULES]
            out += [(target, [n for n in names if f"{target}.{n}" not in MODULES])] if target in MODULES else []
        elif isinstance(node, ast.Import):
            out += [(a.name, []) for a in node.names if a.name in MODULES]
    return out


def _circles(top_level_only: bool) -> list[set[str]]:
    graph = {m: {t for t, _ in _imports(m, top_level_only)} - {m} for m in MODULES}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    circles = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while not component or v not in component:
                component.add(stack.pop())
            if len(component) > 1:
                circles.append(component)

    for m in sorted(graph):
        if m not in index:
            visit(m)
    return circles


def test_the_analysis_sees_imports_names_and_circles():
    """The checks below can fail: the reader finds the imports, names and the one circle it must find."""
    imports = dict(_imports("lerobot_focal.benchmarks.grid.methods", top_level_only=True))
    assert "GridPreset" in imports["lerobot_focal.benchmarks.grid.grid_presets"]
    assert LAZY_CIRCLES_ALLOWED[0] in _circles(top_level_only=False)


def test_no_module_imports_in_a_circle():
    assert _circles(top_level_only=True) == [], "modules that import each other at module level"
    lazy = [c for c in _circles(top_level_only=False) if c not in LAZY_CIRCLES_ALLOWED]
    assert lazy == [], "modules that import each other (inside functions too); move the shared piece down"


def test_no_module_takes_another_modules_private_names():
    found = [f"{m} takes {n} from {t}" for m in MODULES for t, names in _imports(m, top_level_only=False)
             for n in names if n.startswith("_") and not n.startswith("__") and t != m]
    assert found == [], "make the name public where it is shared, or move it to the module that uses it"


@pytest.mark.parametrize(("a", "b"), [("policy", "robots"), ("policy", "benchmarks"), ("robots", "benchmarks")])
def test_policy_robots_and_benchmarks_layering(a, b):
    """The policy needs no robot or benchmark code, and the robots no benchmark code."""
    found = [f"{m} imports {t}" for m in MODULES if m.startswith(f"lerobot_focal.{a}")
             for t, _ in _imports(m, top_level_only=False) if t.startswith(f"lerobot_focal.{b}")]
    assert found == []
