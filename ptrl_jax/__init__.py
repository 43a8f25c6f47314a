"""ptrl_jax: Prior Transfer RL (PTRL) for legged robots as one pure-JAX program.

The trainer (this package) is pure functions over named pytrees. Environments live in the
top-level ``envs`` package and never import the trainer; presets live in ``experiments/``
and nothing here imports them.
"""

__version__ = "0.1.0"
