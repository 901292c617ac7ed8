"""The import structure of the library and the lab beside it: no import circles, no module importing
from a higher layer, and the lab (``lab/cmzdril_lab``) a block above the library that the library never
imports (as rl-baselines3-zoo stands beside stable-baselines3).

Read from the source with ``ast`` (nothing is imported), every import counts: at module level,
inside functions (the lazy imports of optional extras) and under ``TYPE_CHECKING``. An import of a
package's parent ``__init__`` that Python runs implicitly is not an edge; what a file names is.
"""
from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

PACKAGE = "sb3_cmzdril"
LAB = "cmzdril_lab"
REPO = Path(__file__).resolve().parent.parent
ROOT = REPO / PACKAGE
LAB_ROOT = REPO / "lab" / LAB

#: The layers, lowest first. A module may import from its own layer and the ones below, never from a
#: higher one; a module belongs to the entry that names it or the package holding it (longest match).
#: The package itself (``sb3_cmzdril/__init__.py``, the public face) is its own layer.
LAYERS: list[tuple[str, set[str]]] = [
    ("foundations: version, the error class, files, printing, spaces, optional extras",
     {"_version", "errors", "io", "console", "data.spaces", "spaces", "extras", "_mujoco_log", "policies"}),
    ("records and configuration: the data types, and the deprecated paths of what moved to them",
     {"shipped", "selection", "data", "demo_readers", "demos", "hyperparams"}),
    ("the imitation parts: ensemble, reward rules, and what the learners share (common: the imitation part, "
     "its save format, behaviour cloning)", {"ensemble", "rewards", "common"}),
    ("the learners, one package each (and the deprecated paths of what moved to them and to common)",
     {"cmzdril", "cmzdril_sac", "algorithm", "sac", "scoring", "demo_replay", "imitation", "bc"}),
    ("measuring and experts", {"metrics", "experts"}),
    ("environments (they register their scripted experts)", {"envs"}),
    ("the public face", {""}),
    ("one run of the command line", {"training"}),
    ("entry points (and the deprecated paths of what moved)", {"cli", "zoo", "__main__", "experiments"}),
    # Everything of the lab: above the whole library, which never imports it.
    ("the lab", {LAB}),
]


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(path, root): path for root in (ROOT, LAB_ROOT) for path in sorted(root.rglob("*.py"))}


def imported(module: str) -> Iterator[str]:
    """The package's modules that ``module``'s file imports (each name resolved to the deepest module)."""
    path = MODULES[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parent + ([node.module] if node.module else []))
            # `from pkg import mod` imports the module pkg.mod; `from mod import name`, the module mod.
            names = [f"{base}.{alias.name}" for alias in node.names] + [base]
        else:
            continue
        for name in names:
            while name and name not in MODULES:
                name = name.rpartition(".")[0]
            if name and name != module:
                yield name


GRAPH = {module: sorted(set(imported(module))) for module in MODULES}


def layer_of(module: str) -> int:
    if module == LAB or module.startswith(LAB + "."):
        return len(LAYERS) - 1
    relative = module[len(PACKAGE) + 1:] if module != PACKAGE else ""
    best: tuple[int, int] | None = None  # (length of the matching entry, layer)
    for index, (_, names) in enumerate(LAYERS):
        for name in names:
            if relative == name or (name and relative.startswith(name + ".")):
                if best is None or len(name) > best[0]:
                    best = (len(name), index)
    assert best is not None, f"{module} is in no layer: add it to LAYERS in {Path(__file__).name}"
    return best[1]


def test_the_library_never_imports_the_lab():
    # Every import the library's files write, by name, whether or not the lab is installed.
    offenders = []
    for module, path in MODULES.items():
        if module.startswith(PACKAGE):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                names = ([alias.name for alias in node.names] if isinstance(node, ast.Import)
                         else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
                offenders += [f"{module} imports {name}" for name in names if name.split(".")[0] == LAB]
    assert offenders == []
    assert f"{PACKAGE}.cli.train" in GRAPH[f"{LAB}.cli"]  # the check sees the lab's imports of the library


def test_every_module_has_a_layer():
    for module in MODULES:
        layer_of(module)


def test_no_module_imports_from_a_higher_layer():
    upward = [
        f"{module} ({LAYERS[layer_of(module)][0]}) imports {target} ({LAYERS[layer_of(target)][0]})"
        for module, targets in GRAPH.items()
        for target in targets
        if layer_of(target) > layer_of(module)
    ]
    assert upward == []


def cycles(graph: dict[str, list[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph[node]:
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in graph:
        if node not in index:
            visit(node)
    return found


def test_no_import_circles():
    assert cycles(GRAPH) == []


def test_the_checks_see_a_circle_and_an_upward_import():
    assert cycles({"a": ["b"], "b": ["c"], "c": ["a"], "d": ["a"]}) == [["a", "b", "c"]]
    assert layer_of(f"{PACKAGE}.io") < layer_of(f"{PACKAGE}.algorithm") < layer_of(f"{LAB}.run.grid")
    assert layer_of(f"{PACKAGE}.common.imitation") < layer_of(f"{PACKAGE}.cmzdril.cmzdril")
    assert layer_of(f"{PACKAGE}.cli") < layer_of(f"{LAB}.cli")
    assert f"{PACKAGE}.cmzdril.scoring" in GRAPH[f"{PACKAGE}.cmzdril.cmzdril"]
    assert f"{PACKAGE}.extras" in GRAPH[f"{PACKAGE}.common.bc"]  # imports inside functions count too
    assert f"{LAB}.run.remote" in GRAPH[f"{LAB}.run.grid"]
