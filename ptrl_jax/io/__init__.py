"""The host-side edges that the commands share: files, reports and process settings.

Atomic files and checkpoints (``artifacts``), key=value overrides and YAML presets
(``overrides``), reports, curves and the freeze-ratio table (``summary``), Table IV and the
per-robot walking table (``transfer_table``, ``walking_table``), figures, MCAP and TensorBoard
logs, a run's progress bar (``progress``), resume state and its runtime fingerprint
(``resume``), and the XLA flags set before jax starts (``xla_flags``).

These run outside the jitted program. They may import ``ptrl_jax.core`` and ``ptrl_jax.config``,
never the command modules (``ptrl_jax.run``, ``evaluate``, ``export``, ``transfer``, ``batch``,
``command_grid``, ``cli``), which sit on top of both (tests/test_dependencies.py). Like
``brax.io``, the name is a package of the project's, not Python's ``io``.
"""
