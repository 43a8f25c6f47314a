"""The jitted core: what runs inside the one compiled PTRL program.

Pure functions over named pytrees: the networks (``nn``, ``networks``, ``distributions``), the
observation normaliser, the hand-written Adam (``optim``), GAE and the PPO loss (``losses``),
freeze masks and the paper's transfer (``freeze``), the semantic transfer (``semantic``), the
trainer (``train``: ``make_train(env, ppo, net) -> Trainer``), the source -> transfer -> targets
chain (``program``) and its device sharding (``sharding``).

Nothing here reads or writes files, argv, clocks or the environment, and nothing here imports
``ptrl_jax.io`` or the command modules: those edges import the core, never the reverse
(tests/test_dependencies.py). The shared config dataclasses live in ``ptrl_jax.config``.
"""
