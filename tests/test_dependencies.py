"""The design's dependency rules: no flax/optax in our code, envs never import the trainer,
nothing imports experiments."""

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
