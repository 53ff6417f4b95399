"""Package architecture (issue 12): no import cycle between robust_drake modules, no function
longer than about 80 lines, and no subpackage that hides a name of the flat API.

The import graph is read from the source with :mod:`ast`, so it holds every import a module can
make: module-level ones and the lazy ones inside functions (a cycle hidden in a function import
is still a cycle: each module needs the other to work). ``if TYPE_CHECKING:`` blocks are left out,
they never run.
"""

from __future__ import annotations

import ast
from pathlib import Path

import robust_drake

PKG_DIR = Path(robust_drake.__file__).resolve().parent
MAX_FUNCTION_LINES = 80


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PKG_DIR.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, ast.Module]:
    return {_module_name(p): ast.parse(p.read_text(), filename=str(p))
            for p in sorted(PKG_DIR.rglob("*.py"))}


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def _imports(tree: ast.Module, name: str, is_pkg: bool, known: set[str]) -> set[str]:
    """robust_drake modules that ``name`` imports anywhere (outside ``if TYPE_CHECKING``)."""
    out: set[str] = set()
    stack: list[ast.AST] = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.If) and _is_type_checking(node):
            stack.extend(node.orelse)
            continue
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = name.split(".")
                anchor = anchor if is_pkg else anchor[:-1]
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            out.add(base)
            # ``from pkg import module`` imports the submodule
            out.update(f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in known)
        stack.extend(ast.iter_child_nodes(node))
    # importing a.b.c runs a/__init__ and a/b/__init__ too; those are edges of their own,
    # but package __init__ files here are empty or import nothing that loops back.
    return {m for m in out if m in known and m != name}


def import_graph() -> dict[str, set[str]]:
    mods = _modules()
    known = set(mods)
    pkgs = {_module_name(p) for p in PKG_DIR.rglob("__init__.py")}
    return {m: _imports(t, m, m in pkgs, known) for m, t in mods.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as a list of modules (first == last), or None (depth-first)."""
    WHITE, GREY, BLACK = 0, 1, 2
    color = dict.fromkeys(graph, WHITE)
    path: list[str] = []

    def visit(u: str) -> list[str] | None:
        color[u] = GREY
        path.append(u)
        for v in sorted(graph[u]):
            if color[v] == GREY:
                return path[path.index(v):] + [v]
            if color[v] == WHITE and (c := visit(v)):
                return c
        path.pop()
        color[u] = BLACK
        return None

    for m in sorted(graph):
        if color[m] == WHITE and (c := visit(m)):
            return c
    return None


def test_find_cycle_sees_a_three_module_circle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    cyc = find_cycle(graph)
    assert cyc is not None and cyc[0] == cyc[-1] and set(cyc) == {"a", "b", "c"}
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def test_import_graph_reads_function_level_imports():
    # robust_drake.api imports the repair pipeline only inside api.repair()
    assert "robust_drake.model_repair.pipeline" in import_graph()["robust_drake.api"]


def test_no_import_cycle():
    cyc = find_cycle(import_graph())
    assert cyc is None, "import cycle: " + " -> ".join(cyc)


#: The layer order, bottom first (issue 22; each package folder in one layer, so the folders stack
#: too): a module may import its own layer and the layers below, never one above (function-level imports count, ``if TYPE_CHECKING`` ones do not). A
#: module belongs to the longest prefix that names it.
LAYERS = [
    ["robust_drake.errors", "robust_drake.robots_dir", "robust_drake.allocator", "robust_drake.divergence",
     "robust_drake.extras", "robust_drake.log", "robust_drake.joints",
     "robust_drake.tables", "robust_drake.forces"],
    ["robust_drake.description", "robust_drake.kinematics", "robust_drake.loop_defaults", "robust_drake.metrics",
     "robust_drake.parallel", "robust_drake.analysis"],
    ["robust_drake.models", "robust_drake.registry", "robust_drake.regressor", "robust_drake.uncertainty",
     "robust_drake.trajectories", "robust_drake.plotting"],
    ["robust_drake.effects"],  # the effect library: regressor columns and their Drake blocks
    ["robust_drake.identification"],  # logs, data, fits; the product (model, export)
    ["robust_drake.systems", "robust_drake.diagram", "robust_drake.viz"],  # blocks, controllers, loop
    ["robust_drake.synthetic", "robust_drake.model_repair"],
    ["robust_drake.experiments", "robust_drake.scenario", "robust_drake.excitation"],
    ["robust_drake.batch", "robust_drake.montecarlo"],
    ["robust_drake.api", "robust_drake.cli", "robust_drake.commands", "robust_drake"],
]
#: upward imports still to remove (each a named debt, not a tolerance: the list only shrinks)
KNOWN_UPWARD: set = set()


def layer_of(module: str) -> int:
    best = None
    for i, group in enumerate(LAYERS):
        for prefix in group:
            if (module == prefix or module.startswith(prefix + ".")) and (best is None or len(prefix) > best[1]):
                best = (i, len(prefix))
    assert best is not None, f"{module} is in no layer of LAYERS"
    return best[0]


def upward_imports(graph: dict[str, set[str]]) -> set[tuple[str, str]]:
    # ``robust_drake`` itself (the lazy flat API face) is read as ``from robust_drake import sub``
    return {(a, b) for a, bs in graph.items() for b in bs if b != "robust_drake" and layer_of(b) > layer_of(a)}


def test_upward_imports_are_seen():
    assert layer_of("robust_drake.identification.model") > layer_of("robust_drake.effects.base")
    assert layer_of("robust_drake.systems.controllers.spong") == layer_of("robust_drake.systems")
    graph = {"robust_drake.errors": {"robust_drake.api"}, "robust_drake.api": {"robust_drake.errors"}}
    assert upward_imports(graph) == {("robust_drake.errors", "robust_drake.api")}


def test_no_module_imports_a_higher_layer():
    up = upward_imports(import_graph())
    assert up <= KNOWN_UPWARD, "upward imports: " + ", ".join(f"{a} -> {b}" for a, b in sorted(up - KNOWN_UPWARD))
    assert up == KNOWN_UPWARD, f"gone, strike from KNOWN_UPWARD: {sorted(KNOWN_UPWARD - up)}"


def test_no_function_over_80_lines():
    long = []
    for name, tree in _modules().items():
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                start = min([node.lineno] + [d.lineno for d in node.decorator_list])
                n = node.end_lineno - start + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{name}.{node.name} ({n} lines)")
    assert not long, "functions over 80 lines: " + ", ".join(sorted(long))


def test_no_subpackage_hides_a_flat_api_name():
    # importing robust_drake.<sub> sets the attribute robust_drake.<sub> to the module, which would
    # replace a lazy public function of the same name (why the repair loop is ``model_repair``)
    subs = {p.parent.name for p in PKG_DIR.glob("*/__init__.py")} | {p.stem for p in PKG_DIR.glob("*.py")}
    clash = sorted(n for n, mod in robust_drake._LAZY.items() if n in subs and mod != f"robust_drake.{n}")
    assert not clash, f"subpackages/modules named like flat API names: {clash}"
