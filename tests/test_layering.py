"""The package's layers, read from its imports (every import statement, including the ones
deferred into functions). One rule: a module imports only modules of the layers below its
own, of its own package, or of a package that contains its own (learning/rl/ may use
learning/networks.py, never learning/supervised/). On top of that, what each layer may
load of the world: anatomy neither dm_control nor MuJoCo, the entities no renderer, and
nothing below the learning layer a learning library."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "cathsim_dmc"

# Bottom to top; docs/architecture.md draws the same picture.
LAYERS = (
    "cathsim_dmc.core",
    "cathsim_dmc.anatomy",
    "cathsim_dmc.sim",
    "cathsim_dmc.entities",
    "cathsim_dmc.tasks",
    "cathsim_dmc.suite",
    "cathsim_dmc.evaluation",
    "cathsim_dmc.control",
    "cathsim_dmc.learning",
    "cathsim_dmc.agents",
    "cathsim_dmc.app",
)
# The package's own __init__ selects the GL backend and registers the Gymnasium ids by name.
ROOT_IMPORTS = {"cathsim_dmc.sim.gl_backend", "cathsim_dmc.core.registry"}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[0] == "tasks":  # tasks/ ships as cathsim_dmc.tasks
        parts = [PACKAGE] + parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _files() -> dict:
    return {_module_name(p): p for folder in (PACKAGE, "tasks") for p in (ROOT / folder).rglob("*.py")}


def _packages(files: dict) -> set:
    return {name for name, path in files.items() if path.name == "__init__.py"}


def import_graph(files: dict | None = None) -> dict:
    """{module: the package's modules it imports}. `from a import b` counts as an import of
    the module a.b when b is a module, else of a."""
    files = _files() if files is None else files
    graph = {}
    for name, path in files.items():
        imported = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                imported.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                for alias in node.names:
                    sub = f"{node.module}.{alias.name}"
                    imported.add(sub if sub in files else node.module)
        graph[name] = {m for m in imported if m in files and m != name}
    return graph


def layer_of(module: str) -> int:
    for index, layer in enumerate(LAYERS):
        if module == layer or module.startswith(layer + "."):
            return index
    raise KeyError(f"{module} is in no layer of LAYERS")


def package_of(module: str, packages: set) -> str:
    return module if module in packages else module.rpartition(".")[0]


def may_import(module: str, imported: str, packages: set) -> bool:
    """The one rule: a lower layer, the module's own package, or a package containing it."""
    if layer_of(imported) < layer_of(module):
        return True
    home = package_of(module, packages)
    owner = package_of(imported, packages)
    return home == owner or home.startswith(owner + ".")


def upward_imports(graph: dict, packages: set) -> list:
    offenders = []
    for module, imported in sorted(graph.items()):
        if module == PACKAGE:
            offenders += [(module, i) for i in sorted(imported - ROOT_IMPORTS)]
            continue
        offenders += [(module, i) for i in sorted(imported) if i != PACKAGE and not may_import(module, i, packages)]
    return offenders


def test_every_module_is_in_a_layer():
    unplaced = []
    for module in _files():
        try:
            module == PACKAGE or layer_of(module)
        except KeyError:
            unplaced.append(module)
    assert unplaced == []


def test_every_module_imports_only_what_lies_below_it():
    files = _files()
    assert upward_imports(import_graph(files), _packages(files)) == []


def test_the_rule_sees_deferred_upward_and_sideways_imports(tmp_path):
    # Most of the package imports inside functions; a graph blind to them would pass anything.
    graph = import_graph()
    assert "cathsim_dmc.evaluation.rollouts" in graph["cathsim_dmc.agents.collect"]
    packages = {"cathsim_dmc.learning", "cathsim_dmc.learning.rl", "cathsim_dmc.learning.supervised", "cathsim_dmc.sim"}
    fake = {
        "cathsim_dmc.sim.physics": {"cathsim_dmc.tasks.navigate"},  # up
        "cathsim_dmc.learning.rl.sacfd": {"cathsim_dmc.learning.networks", "cathsim_dmc.learning.supervised.bc"},
        "cathsim_dmc.learning.supervised.bc": {"cathsim_dmc.learning.networks", "cathsim_dmc.sim.physics"},
    }
    assert upward_imports(fake, packages) == [
        ("cathsim_dmc.learning.rl.sacfd", "cathsim_dmc.learning.supervised.bc"),  # sideways
        ("cathsim_dmc.sim.physics", "cathsim_dmc.tasks.navigate"),
    ]


def test_the_schemas_are_imported_by_the_apps_alone():
    graph = import_graph()
    schemas = {"cathsim_dmc.app.train_schema", "cathsim_dmc.app.tool_schemas"}
    importers = sorted(m for m, imported in graph.items() if imported & schemas and not m.startswith("cathsim_dmc.app"))
    assert importers == []


def test_nothing_imports_the_tests():
    offenders = []
    for folder in (PACKAGE, "tasks", "scripts", "experiments"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            text = path.read_text()
            names = _imported_names(path)
            if any(n.split(".")[0] in ("tests", "conftest", "shipped") for n in names) or '"tests"' in text:
                offenders.append(str(path.relative_to(ROOT)))
    assert offenders == []


@pytest.mark.parametrize("module", ["cathsim_dmc.anatomy", "cathsim_dmc.anatomy.validate"])
def test_anatomy_imports_without_dm_control_or_mujoco(module):
    # A fresh interpreter: this test process has loaded everything already.
    code = (
        f"import sys, {module}; "
        "loaded = [m for m in ('dm_control', 'mujoco') if m in sys.modules]; "
        "assert not loaded, loaded"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr


def _imported_names(path: Path) -> list:
    """Every module an import statement of `path` names (`from a import b`: a and a.b)."""
    names = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names += [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
    return names


def test_anatomy_never_imports_dm_control_or_mujoco():
    # Not even deferred into a function: building, importing and validating an asset run
    # without a simulator; the MuJoCo compile check is cathsim_dmc.sim.model_check.
    offenders = [
        (path.name, name)
        for path in sorted((ROOT / PACKAGE / "anatomy").rglob("*.py"))
        for name in _imported_names(path)
        if name.split(".")[0] in ("dm_control", "mujoco")
    ]
    assert offenders == []


# The renderers: an entity is built and simulated without images.
RENDERER = ("cathsim_dmc.sim.render", "cathsim_dmc.sim.raster")


def test_entities_never_import_the_renderer():
    offenders = [
        (path.name, name)
        for path in sorted((ROOT / PACKAGE / "entities").rglob("*.py"))
        for name in _imported_names(path)
        if any(name == f or name.startswith(f + ".") for f in RENDERER)
    ]
    assert offenders == []


def test_importing_entities_loads_no_renderer():
    # A fresh interpreter: this test process has loaded everything already.
    code = (
        "import sys, cathsim_dmc.entities; "
        "loaded = [m for m in ('cathsim_dmc.sim.render', 'cathsim_dmc.sim.raster', 'cathsim_dmc.tasks') "
        "if m in sys.modules]; "
        "assert not loaded, loaded"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr


def _top_level_imports(path: Path) -> set:
    """The first name of every module `path` imports, deferred imports included."""
    return {name.split(".")[0] for name in _imported_names(path)}


def test_the_layers_below_learning_load_no_learning_library():
    # The simulation, the suite, the evaluation and the scripted policies run without SB3 or
    # torch (deferred imports included).
    below = [m for m, p in _files().items() if m != PACKAGE and layer_of(m) < layer_of("cathsim_dmc.learning")]
    assert len(below) > 60  # the walk sees the package
    libraries = {"stable_baselines3", "torch"}
    files = _files()
    offenders = sorted((m, name) for m in below for name in _top_level_imports(files[m]) & libraries)
    assert offenders == []


def test_no_import_circles():
    graph = import_graph()
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    assert found == []
