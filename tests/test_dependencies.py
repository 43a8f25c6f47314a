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


class TestQuietImport:
    def test_importing_the_envs_prints_nothing_on_standard_output(self):
        """MJX's report of its absent Warp backend is swallowed (envs/__init__.py), so a command's
        standard output holds only its result (``evaluate ... | jq``)."""
        import subprocess
        import sys

        out = subprocess.run([sys.executable, "-c", "import envs"], cwd=ROOT, capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        assert out.stdout == ""
