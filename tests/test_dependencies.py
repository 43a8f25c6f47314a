"""The design's dependency rules: no flax/optax in our code, envs never import the trainer,
nothing imports experiments, and no import cycle among our modules (lazy imports in function
bodies count too)."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def imports(pkg: str):
    for path in (ROOT / pkg).rglob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    yield path, a.name.split(".")[0]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                yield path, node.module.split(".")[0]


class TestDependencies:
    def test_no_flax_or_optax(self):
        bad = [(str(p), m) for pkg in ("ptrl_jax", "envs", "experiments") for p, m in imports(pkg) if m in ("flax", "optax")]
        assert not bad, bad

    def test_envs_never_import_the_trainer(self):
        bad = [(str(p), m) for p, m in imports("envs") if m == "ptrl_jax"]
        assert not bad, bad

    def test_nothing_imports_experiments(self):
        bad = [(str(p), m) for pkg in ("ptrl_jax", "envs") for p, m in imports(pkg) if m == "experiments"]
        assert not bad, bad


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def module_graph() -> dict[str, set[str]]:
    """Our module -> our modules it imports anywhere in its file (``from ptrl_jax.core import x``
    counts as importing ``ptrl_jax.core.x`` when that is a module). Packages' ``__init__`` files
    import nothing of ours, so they are left out."""
    paths = {module_name(p): p for pkg in ("ptrl_jax", "envs") for p in (ROOT / pkg).rglob("*.py")
             if p.name != "__init__.py"}
    ours = set(paths)
    graph: dict[str, set[str]] = {}
    for name, path in paths.items():
        tree = ast.parse(path.read_text())
        deps = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                deps |= {a.name for a in node.names if a.name in ours}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                if node.module in ours:
                    deps.add(node.module)
                deps |= {f"{node.module}.{a.name}" for a in node.names if f"{node.module}.{a.name}" in ours}
        graph[name] = deps - {name}
    return graph


def layer(module: str) -> int:
    """0: envs; 1: the jitted core and the shared config; 2: the host-side edges (ptrl_jax.io);
    3: the commands and their drivers (ptrl_jax.run, evaluate, export, transfer, batch, ...)."""
    if module.startswith("envs"):
        return 0
    if module.startswith("ptrl_jax.core.") or module == "ptrl_jax.config":
        return 1
    if module.startswith("ptrl_jax.io."):
        return 2
    return 3


def test_dependencies_point_from_the_edges_to_the_core():
    """The folders show the architecture: the core imports no edge and no command, an edge no
    command (lazy imports in function bodies count too)."""
    graph = module_graph()
    assert {"ptrl_jax.core.train", "ptrl_jax.io.artifacts", "ptrl_jax.run"} <= set(graph)
    upward = sorted(f"{m} imports {d}" for m, deps in graph.items() for d in deps if layer(d) > layer(m))
    assert not upward, upward


def test_no_import_cycle():
    graph = module_graph()
    assert "ptrl_jax.batch" in graph["ptrl_jax.run"]  # imported inside run.main: lazy imports are read
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(node, path):
        state[node] = 1
        for dep in sorted(graph[node]):
            if state.get(dep) == 1:
                raise AssertionError("import cycle: " + " -> ".join(path[path.index(dep):] + [dep]))
            if dep not in state:
                visit(dep, path + [dep])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])


class TestQuietImport:
    def test_importing_the_envs_prints_nothing_on_standard_output(self):
        """MJX's report of its absent Warp backend is swallowed (envs/__init__.py), so a command's
        standard output holds only its result (``evaluate ... | jq``)."""
        import subprocess
        import sys

        out = subprocess.run([sys.executable, "-c", "import envs"], cwd=ROOT, capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        assert out.stdout == ""
