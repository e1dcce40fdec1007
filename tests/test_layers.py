"""The package's shape: every folder with code is installed under `aftershock`, and imports go one way.

Layers, bottom to top (a module imports only from layers below it, or from its own component):
0. vocabulary: types, config, errors, classes, geometry, progress, cloud_io, the ROS codec, metrics, planecheck
1. models: the networks (not their training pipelines)
2. components: sources; the stages (register, level, voxel_map, label, labellers, cluster, refine, damage, trajectory)
3. the stream and the sink interface it owns
4. sinks, which implement that interface
5. the mission library: one mission from source to sinks and the analyses of its final map (pipeline.mission)
6. batch: many missions on Ray (pipeline.batch), each run by the mission library; the site report
   (pipeline.report), which reads what missions wrote
7. the command line: cli, commands, and the training pipelines (they drive the simulator and the stages) --
   thin: a command may import the library below, nothing below imports a command
"""

from __future__ import annotations

import ast
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Final

import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

REPO: Final = Path(__file__).resolve().parents[1]
NAMESPACE: Final = "aftershock"

VOCABULARY: Final = (
    *(f"pipeline.{m}" for m in ("types", "config", "errors", "classes", "geometry", "progress", "cloud_io")),
    *(f"pipeline.{m}" for m in ("text", "limits", "outputs")),
    *("pipeline.pointcloud2", "pipeline.metrics", "pipeline.planecheck", "pipeline", "recordings"),
)
STAGES: Final = tuple(
    f"pipeline.{m}"
    for m in (
        "register",
        "level",
        "voxel_map",
        "label",
        "labellers",
        "cluster",
        "refine",
        "damage",
        "structure",
        "trajectory",
        "scan_stats",
    )
)


def _package_dirs() -> dict[str, str]:
    return tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]


def _modules() -> dict[str, Path]:
    """Dotted name (without the namespace) -> file, for every module under the mapped folders."""
    out: dict[str, Path] = {}
    for package, folder in _package_dirs().items():
        root = package.removeprefix(f"{NAMESPACE}.")
        for path in (REPO / folder).rglob("*.py"):
            parts = [root, *path.relative_to(REPO / folder).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


def layer_of(module: str) -> tuple[int, str]:
    """(layer, component) of a module; see the module docstring."""

    def under(prefixes: tuple[str, ...]) -> bool:
        return any(module == p or module.startswith(f"{p}.") for p in prefixes)

    if module in VOCABULARY:
        return 0, "vocabulary"
    if module.startswith("models.") and module.endswith("_train"):
        return 7, "cli"
    if under(("models",)):
        return 1, "models"
    if under(("sources",)):
        return 2, "sources"
    if under(STAGES):
        return 2, "stages"
    if module in ("pipeline.stream", "pipeline.sink"):
        return 3, "stream"
    if under(("sinks",)):
        return 4, "sinks"
    if module == "pipeline.mission":
        return 5, "mission"
    if under(("pipeline.batch",)):
        return 6, "batch"
    if under(("pipeline.report",)):
        return 6, "report"
    if under(("pipeline.cli", "pipeline.__main__", "pipeline.commands")):
        return 7, "cli"
    raise AssertionError(f"{module} has no layer: add it to tests/test_layers.py")


def _runtime_nodes(tree: ast.Module) -> Iterator[ast.AST]:
    """Every node except those under `if TYPE_CHECKING:` (annotations only, never imported at run time)."""
    stack: list[ast.AST] = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            stack.extend(node.orelse)
            continue
        yield node
        stack.extend(ast.iter_child_nodes(node))


def import_graph() -> tuple[dict[str, set[str]], list[str]]:
    """Module -> the project modules it imports at run time (also inside functions); and imports of private
    names from another module. `from package import submodule` counts as importing the submodule."""
    modules = _modules()
    edges: dict[str, set[str]] = {m: set() for m in modules}
    private: list[str] = []
    prefix = f"{NAMESPACE}."

    def resolve(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    for module, path in modules.items():
        for node in _runtime_nodes(ast.parse(path.read_text())):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                for alias in node.names:
                    full = f"{node.module}.{alias.name}"
                    sub = full.removeprefix(prefix) in modules
                    targets.append(full if sub else node.module)
                    if alias.name.startswith("_") and not sub and node.module.startswith(prefix):
                        private.append(f"{module} imports {alias.name} from {node.module}")
            for target in targets:
                if target.startswith(prefix) and (dep := resolve(target.removeprefix(prefix))) and dep != module:
                    edges[module].add(dep)
    return edges, private


def test_every_package_folder_is_installed() -> None:
    """A folder with an __init__.py that pyproject does not list would be missing from the wheel."""
    listed = set(tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    for package, folder in _package_dirs().items():
        assert package.startswith(f"{NAMESPACE}."), f"{package} is not under the {NAMESPACE} namespace"
        for init in (REPO / folder).rglob("__init__.py"):
            rel = init.parent.relative_to(REPO / folder).parts
            name = ".".join((package, *rel))
            assert name in listed, f"{name} ({init.parent}) is not listed in pyproject's packages"


def test_imports_go_one_way() -> None:
    edges, private = import_graph()
    assert not private, private
    wrong = []
    for module, deps in edges.items():
        layer, component = layer_of(module)
        for dep in deps:
            dep_layer, dep_component = layer_of(dep)
            if dep_layer > layer or (dep_layer == layer and dep_component != component):
                wrong.append(
                    f"{module} (layer {layer}, {component}) imports {dep} (layer {dep_layer}, {dep_component})"
                )
    assert not wrong, "\n".join(sorted(wrong))


def test_no_import_cycles() -> None:
    edges, _ = import_graph()
    names = sorted(edges)
    index = {n: i for i, n in enumerate(names)}
    src = [index[m] for m, deps in edges.items() for _ in deps]
    dst = [index[d] for deps in edges.values() for d in deps]
    graph = coo_matrix(([1] * len(src), (src, dst)), shape=(len(names), len(names)))
    _, comp = connected_components(graph, directed=True, connection="strong")
    groups: dict[int, list[str]] = {}
    for name, c in zip(names, comp, strict=True):
        groups.setdefault(int(c), []).append(name)
    cycles = [g for g in groups.values() if len(g) > 1]
    assert not cycles, cycles


KNOWN_LAYERS: Final = {
    "pipeline.stream": 3,
    "sources.mcap_source": 2,
    "models.crackembed": 1,
    "pipeline.damage": 2,
    "pipeline.mission": 5,
    "pipeline.batch.worker": 6,
    "pipeline.commands.run": 7,
}


@pytest.mark.parametrize("module", sorted(KNOWN_LAYERS))
def test_known_modules_have_their_layer(module: str) -> None:
    """Guards the rules themselves: a few modules the layering must place where the docstring says."""
    edges, _ = import_graph()
    assert module in edges
    assert layer_of(module)[0] == KNOWN_LAYERS[module]


def test_the_command_line_is_thin() -> None:
    """Commands hold options and printing: no sink is made or told there (that is the stream's and the
    mission's), and every command module is wired into the app by name in cli.py, none loaded from a table."""
    edges, _ = import_graph()
    cli_modules = [m for m in edges if layer_of(m) == (7, "cli") and not m.startswith("models.")]
    to_sinks = sorted(f"{m} imports {d}" for m in cli_modules for d in edges[m] if layer_of(d)[1] == "sinks")
    allowed = {"pipeline.commands.view"}  # `view` opens a viewer on a log and a recording: no sink, no stream
    assert [t for t in to_sinks if t.split()[0] not in allowed] == []
    commands = {p.stem for p in (REPO / "pipeline" / "commands").glob("*.py") if p.stem != "__init__"}
    cli = ast.parse((REPO / "pipeline" / "cli.py").read_text())
    wired = {
        node.value.id
        for node in ast.walk(cli)
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in commands
    }
    assert wired == commands, f"command modules not wired in cli.py: {sorted(commands - wired)}"
