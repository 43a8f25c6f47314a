"""Only what pyproject.toml cannot say: the data-only packages ``envs.assets`` (assets/) and
``ptrl_jax.presets`` (experiments/) ship their data files, not the scripts beside them
(experiments/bench.py and the like stay tools of the checkout)."""

from setuptools import setup
from setuptools.command.build_py import build_py

DATA_ONLY = ("envs.assets", "ptrl_jax.presets")


class BuildPy(build_py):
    def find_package_modules(self, package, package_dir):
        return [] if package in DATA_ONLY else super().find_package_modules(package, package_dir)


setup(cmdclass={"build_py": BuildPy})
