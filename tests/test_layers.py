"""The package's layers import downwards only: the table in the README, enforced.

Reads every module's imports (``ast``, nothing is imported) and checks four rules:
1. a module imports only from its own layer and the layers ``ALLOWED`` lists for it;
2. no circle of top-level imports between modules;
3. inside functions, only optional dependencies are imported (and anything in the CLI);
4. the kernels know no torch, the models neither Warp nor the simulator, and only the layers
   that compose or record configs touch Hydra/OmegaConf.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: layer -> the layers it may import (besides itself). The README's "Layout" table.
ALLOWED: dict[str, set[str]] = {
    "core": set(),
    "kernels": set(),
    "sim": {"core", "kernels"},
    "data": {"core", "sim"},
    "models": {"core"},
    "inference": {"core", "sim", "models"},
    "evaluation": {"core", "sim", "data", "models", "inference"},
    "training": {"core", "sim", "data", "models", "inference", "evaluation"},
    "compose": {"core", "sim", "models", "training"},
    "plots": {"core", "sim", "data", "models", "inference", "evaluation", "training", "compose"},
    "export": {"core", "sim", "inference"},
    "bench": {"core", "kernels", "sim", "data", "models", "inference", "evaluation", "training", "compose"},
    "cli": {"core", "sim", "data", "models", "inference", "evaluation", "training", "compose", "plots", "export", "bench"},
    "api": {"core", "sim", "inference", "export"},  # warp_terrain/__init__.py: the public names
}

#: third-party packages a module may import inside a function (not installed by default)
OPTIONAL = {"pyfastnoiselite", "open3d", "onnx", "onnxruntime", "laspy", "plyfile", "pypcd4", "rasterio", "CSF", "rosbags",
            "viser", "pyproj", "submitit", "hydra_plugins", "tensorboard"}
#: third-party packages only these layers may import
RESTRICTED = {
    "torch": set(ALLOWED) - {"kernels"},
    "warp": {"kernels", "sim", "data", "bench", "cli", "api"},
    "hydra": {"compose", "cli"},
    "omegaconf": {"training", "compose", "cli"},
}


def _modules() -> dict[str, Path]:
    found = {}
    for path in sorted((ROOT / "warp_terrain").rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    for path in sorted((ROOT / "kernels").glob("*.py")):
        name = "warp_terrain.kernels" + ("" if path.stem == "__init__" else f".{path.stem}")
        found[name] = path
    return found


MODULES = _modules()


def layer_of(module: str) -> str:
    parts = module.split(".")
    return "api" if len(parts) == 1 else parts[1]


def _imports(module: str, path: Path):
    """``(target, top_level, lineno)`` for every import; targets are absolute module names."""
    tree = ast.parse(path.read_text())
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    if module.startswith("warp_terrain.kernels") and path.name != "__init__.py":
        package = "warp_terrain.kernels"

    def walk(node, top):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.Import):
                for alias in child.names:
                    yield alias.name, top, child.lineno
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = package.split(".")[: len(package.split(".")) - child.level + 1]
                    target = ".".join(base + ([child.module] if child.module else []))
                else:
                    target = child.module
                names = [a.name for a in child.names]
                for name in names:  # `from . import x` may import a submodule
                    yield (f"{target}.{name}" if f"{target}.{name}" in MODULES else target), top, child.lineno
            else:
                inner = isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
                guarded = isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test)
                if not guarded:
                    yield from walk(child, top and not inner)

    yield from walk(tree, True)


IMPORTS = {m: list(_imports(m, p)) for m, p in MODULES.items()}


def test_every_module_is_in_a_known_layer():
    assert {layer_of(m) for m in MODULES} <= set(ALLOWED)


def test_imports_point_down_the_layers():
    bad = []
    for module, imports in IMPORTS.items():
        here = layer_of(module)
        for target, _top, line in imports:
            if target.startswith("warp_terrain"):
                there = layer_of(target)
                if there != here and there not in ALLOWED[here]:
                    bad.append(f"{MODULES[module].relative_to(ROOT)}:{line}: {here} imports {target} ({there})")
    assert not bad, "imports against the layer table:\n" + "\n".join(bad)


def test_no_import_circles():
    graph = {m: {t for t, top, _ in imps if top and t in MODULES and t != m} for m, imps in IMPORTS.items()}
    # a package's __init__ importing its own submodules is how packages work, not a circle
    for m in graph:
        graph[m] = {t for t in graph[m] if not (MODULES[m].name == "__init__.py" and t.startswith(m + "."))}
    state, stack, circles = {}, [], []

    def visit(m):
        state[m] = "open"
        stack.append(m)
        for t in sorted(graph[m]):
            if state.get(t) == "open":
                circles.append(" -> ".join(stack[stack.index(t):] + [t]))
            elif t not in state:
                visit(t)
        stack.pop()
        state[m] = "done"

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not circles, "import circles:\n" + "\n".join(circles)


def test_imports_inside_functions_are_optional_dependencies_only():
    bad = []
    for module, imports in IMPORTS.items():
        if layer_of(module) == "cli":
            continue
        for target, top, line in imports:
            if not top and target.split(".")[0] not in OPTIONAL:
                bad.append(f"{MODULES[module].relative_to(ROOT)}:{line}: {target}")
    assert not bad, "imports inside functions (move them to the top of the module):\n" + "\n".join(bad)


@pytest.mark.parametrize("package", sorted(RESTRICTED))
def test_third_party_frameworks_stay_in_their_layers(package):
    bad = [f"{MODULES[m].relative_to(ROOT)}:{line}" for m, imps in IMPORTS.items() for t, _top, line in imps
           if t.split(".")[0] == package and layer_of(m) not in RESTRICTED[package]]
    assert not bad, f"{package} imported outside {sorted(RESTRICTED[package])}: {bad}"


def test_the_rule_catches_a_backward_import(tmp_path):
    """The checker itself: a sim module importing training is caught; a circle is caught."""
    saved = dict(IMPORTS)
    try:
        IMPORTS["warp_terrain.sim.batch"] = [*saved["warp_terrain.sim.batch"], ("warp_terrain.training.loop", True, 1)]
        with pytest.raises(AssertionError, match="sim imports warp_terrain.training.loop"):
            test_imports_point_down_the_layers()
        IMPORTS["warp_terrain.sim.scan"] = [*saved["warp_terrain.sim.scan"], ("warp_terrain.sim.batch", True, 1)]
        with pytest.raises(AssertionError, match="import circles"):
            test_no_import_circles()
    finally:
        IMPORTS.clear()
        IMPORTS.update(saved)


def test_kernel_modules_compile_forward_only():
    """Nothing differentiates through the simulator: every kernel module is compiled without
    adjoints (less code, compile time 53 -> 21 s for all modules on this CPU)."""
    import importlib
    import pkgutil

    import warp as wp

    import warp_terrain.kernels as kernels

    names = [m.name for m in pkgutil.iter_modules(kernels.__path__)]
    assert len(names) >= 10
    for name in names:
        module = importlib.import_module(f"warp_terrain.kernels.{name}")
        assert wp.get_module(module.__name__).options["enable_backward"] is False, name
