"""The package's layering, read from its imports (every import statement, including the
ones deferred into functions): no module outside cli/ imports cli/, no import circles,
the anatomy layer (its validation included) imports without dm_control or MuJoCo, the
entities import neither the renderer nor any layer built on them, and the tasks import
none of the layers that drive them."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "cathsim_dmc"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[0] == "tasks":  # tasks/ ships as cathsim_dmc.tasks
        parts = [PACKAGE] + parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict:
    """{module: the package's modules it imports}. `from a import b` counts as an import of
    the module a.b when b is a module, else of a."""
    files = {_module_name(p): p for folder in (PACKAGE, "tasks") for p in (ROOT / folder).rglob("*.py")}
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


def cycles(graph: dict) -> list:
    """Strongly connected components with more than one module (Tarjan)."""
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
    return found


def test_the_graph_sees_deferred_imports():
    # Most of the package imports inside functions; a graph blind to them would pass anything.
    graph = import_graph()
    assert "cathsim_dmc.evaluation.rollouts" in graph["cathsim_dmc.agents.collect"]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_module_outside_cli_imports_cli():
    graph = import_graph()
    offenders = [
        (m, i)
        for m, imported in graph.items()
        if not m.startswith(f"{PACKAGE}.cli")
        for i in imported
        if i.startswith(f"{PACKAGE}.cli")
    ]
    assert offenders == []


def test_no_import_circles():
    assert cycles(import_graph()) == []


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


def test_anatomy_never_imports_dm_control_or_mujoco():
    # Not even deferred into a function: building, importing and validating an asset run
    # without a simulator; the MuJoCo compile check is cathsim_dmc.sim.model_check.
    offenders = []
    for path in sorted((ROOT / PACKAGE / "anatomy").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            else:
                continue
            offenders += [(path.name, n) for n in names if n.split(".")[0] in ("dm_control", "mujoco")]
    assert offenders == []


# What an entity may not import: the image observables and their renderers, and every
# layer built on entities (tasks, the Gymnasium adapter, learning, the command line).
ENTITY_FORBIDDEN = (
    "cathsim_dmc.sim.render",
    "cathsim_dmc.sim.raster",
    "cathsim_dmc.sim.gl_backend",
    "cathsim_dmc.tasks",
    "cathsim_dmc.suite.gym",
    "cathsim_dmc.learning.rl",
    "cathsim_dmc.learning.supervised",
    "cathsim_dmc.agents.trained",
    "cathsim_dmc.app.cli",
)


def _imported_names(path: Path) -> list:
    """Every module an import statement of `path` names (`from a import b`: a and a.b)."""
    names = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names += [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
    return names


def test_entities_never_import_the_renderer_or_the_layers_above():
    # Not even deferred into a function: an entity is built and simulated without images.
    offenders = [
        (path.name, name)
        for path in sorted((ROOT / PACKAGE / "entities").rglob("*.py"))
        for name in _imported_names(path)
        if any(name == f or name.startswith(f + ".") for f in ENTITY_FORBIDDEN)
    ]
    assert offenders == []


def test_the_entity_check_sees_a_forbidden_import(tmp_path):
    module = tmp_path / "bad.py"
    module.write_text("def f():\n    from cathsim_dmc import observables\n    import cathsim_dmc.sim.raster\n")
    assert {"cathsim_dmc.sim.render", "cathsim_dmc.sim.raster"} <= set(_imported_names(module))


def test_importing_entities_loads_no_renderer():
    # A fresh interpreter: this test process has loaded everything already. The package's
    # own __init__ picks the GL backend (cathsim_dmc.sim.gl_backend, a few lines of os and ctypes)
    # before dm_control is imported, so only the modules that render are checked here.
    code = (
        "import sys, cathsim_dmc.entities; "
        "loaded = [m for m in ('cathsim_dmc.sim.render', 'cathsim_dmc.sim.raster', 'cathsim_dmc.tasks') "
        "if m in sys.modules]; "
        "assert not loaded, loaded"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr


# What the task layer may not import: the layers that drive a task (the Gymnasium adapter,
# policies and experts, learning, evaluation, the command line).
TASK_FORBIDDEN = (
    "cathsim_dmc.suite.gym",
    "cathsim_dmc.learning.rl",
    "cathsim_dmc.learning.supervised",
    "cathsim_dmc.control.policies",
    "cathsim_dmc.control.expert",
    "cathsim_dmc.evaluation.rollouts",
    "cathsim_dmc.evaluation.fidelity",
    "cathsim_dmc.app.cli",
)


def test_tasks_never_import_the_layers_that_drive_them():
    offenders = [
        (path.name, name)
        for path in sorted((ROOT / "tasks").rglob("*.py"))
        for name in _imported_names(path)
        if any(name == f or name.startswith(f + ".") for f in TASK_FORBIDDEN)
    ]
    assert offenders == []


def test_physics_and_fidelity_never_import_the_gymnasium_adapter():
    # fidelity measures the model through the composer environment (cathsim_dmc.tasks).
    offenders = [
        (name, imported)
        for name in ("physics.py", "fidelity.py", "arena.py")
        for imported in _imported_names(ROOT / PACKAGE / name)
        if imported.startswith("cathsim_dmc.suite.gym")
    ]
    assert offenders == []


def _top_level_imports(path: Path) -> set:
    """The first name of every module `path` imports, deferred imports included."""
    tree = ast.parse(path.read_text())
    plain = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    named = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module}
    return {name.split(".")[0] for name in plain | named}


def test_policies_evaluation_and_the_simulation_load_no_learning_library():
    # The scripted policies, the evaluation and the simulation (tasks/, entities/), with
    # every module they reach (deferred imports included), run without SB3 or torch and
    # never reach into the learning layer (rl/, supervised/, agents.py, which loads checkpoints).
    files = {_module_name(p): p for folder in (PACKAGE, "tasks") for p in (ROOT / folder).rglob("*.py")}
    graph = import_graph()
    starts = [f"{PACKAGE}.policies", f"{PACKAGE}.evaluation"]
    starts += [m for m in graph if m.startswith((f"{PACKAGE}.tasks", f"{PACKAGE}.entities"))]
    reached, stack = set(), list(starts)
    while stack:
        module = stack.pop()
        if module not in reached:
            reached.add(module)
            stack.extend(graph[module])
    assert len(reached) > 20 and f"{PACKAGE}.observables" in reached  # the walk follows the imports
    learning = (f"{PACKAGE}.rl", f"{PACKAGE}.supervised", f"{PACKAGE}.agents")
    offenders = sorted(m for m in reached if m.startswith(learning))
    libraries = {"stable_baselines3", "torch"}
    offenders += sorted((m, name) for m in reached for name in _top_level_imports(files[m]) & libraries)
    assert offenders == []
