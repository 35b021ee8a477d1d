"""The package's layers (data flows top to bottom, STYLE.md): a module imports only from its own layer or the
layers below it, and no modules import each other in a circle. Imports are read with ``ast`` (any import
statement, also inside functions), so the test runs nothing of the package."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "mocapnet"

# Lowest first. A module belongs to the layer of its longest matching prefix.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("mocapnet.motion", "mocapnet.threads", "mocapnet.io.atomic", "mocapnet.safe_cache"),
    (
        "mocapnet.io",
        "mocapnet.kinematics",
        "mocapnet.mirror",
        "mocapnet.segments",
        "mocapnet.fill",
        "mocapnet.selfcheck",
        "mocapnet.adaptive_smooth",
        "mocapnet.parallel",
    ),
    ("mocapnet", "mocapnet.corrupt", "mocapnet.corpus"),  # the package __init__ re-exports io and motion
    ("mocapnet.nn",),
    ("mocapnet.methods",),
    ("mocapnet.evaluate", "mocapnet.clean"),
    ("mocapnet.batch",),
    ("mocapnet.cli",),
)


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer_of(module: str) -> int:
    best, best_len = -1, -1
    for level, prefixes in enumerate(LAYERS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > best_len:
                best, best_len = level, len(prefix)
    assert best >= 0, f"{module} is in no layer: add it to LAYERS"
    return best


def imports_of(path: Path, modules: set[str]) -> set[str]:
    """The package modules ``path`` imports (``from mocapnet.x import y`` counts ``mocapnet.x.y`` when that
    is a module, else ``mocapnet.x``)."""
    me = module_name(path)
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(
                    package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else [])
                )
            names = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        else:
            continue
        found.update(n for n in names if n == "mocapnet" or n.startswith("mocapnet."))
    found.discard(me)
    return found


def _graph() -> dict[str, set[str]]:
    files = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    return {name: imports_of(path, set(files)) for name, path in files.items()}


def test_no_upward_imports():
    upward = [
        f"{mod} (layer {layer_of(mod)}) imports {dep} (layer {layer_of(dep)})"
        for mod, deps in sorted(_graph().items())
        for dep in sorted(deps)
        if layer_of(dep) > layer_of(mod)
    ]
    assert not upward, "\n".join(upward)


def test_no_import_circles():
    graph = _graph()
    circles: list[list[str]] = []
    state: dict[str, int] = {}  # 1 = on the current path, 2 = done

    def visit(node: str, path: list[str]) -> None:
        state[node] = 1
        for dep in sorted(graph.get(node, ())):
            if dep == "mocapnet" or node == "mocapnet":
                continue  # the package __init__ is imported with every submodule, not a circle of code
            if state.get(dep) == 1:
                circles.append(path[path.index(dep) :] + [dep])
            elif dep not in state:
                visit(dep, path + [dep])
        state[node] = 2

    for start in sorted(graph):
        if start not in state:
            visit(start, [start])
    assert not circles, "\n".join(" -> ".join(c) for c in circles)


def test_layers_know_every_module():
    for name in _graph():
        layer_of(name)
