"""XLA compile settings for compile-bound runs (``scale=smoke`` and the test suite).

A smoke run spends nearly all its time compiling: XLA's CPU backend optimises the program's
LLVM code for speed that a few iterations of 16 envs never use back. Measured on the 2-core CPU
(``experiments/bench.py``'s machine, 2026-11-22), the go2_to_xbot smoke program's XLA compile
took 120 s by default, 56 s at backend optimisation level 0, and 43 s with the legacy (non-thunk)
CPU runtime as well; tracing (about 30 s) is unchanged.

XLA reads these flags once, when jax creates its CPU backend, so they must be set before
anything runs a jax computation (importing brax or MJX already does). ``python -m ptrl_jax.run``
sets them for ``scale=smoke`` before its imports; ``tests/conftest.py`` sets them for the suite.
This module imports nothing from jax.
"""

from __future__ import annotations

import os

FAST_COMPILE_FLAGS = ("--xla_backend_optimization_level=0", "--xla_cpu_use_thunk_runtime=false")
"""Appended to XLA_FLAGS, unless the user's XLA_FLAGS already names the setting."""


def use_fast_compile() -> None:
    """Add ``FAST_COMPILE_FLAGS`` to the XLA_FLAGS environment variable (a no-op for flags the
    variable already sets). Effective only before jax's backend exists."""
    current = os.environ.get("XLA_FLAGS", "")
    extra = [f for f in FAST_COMPILE_FLAGS if f.split("=")[0] not in current]
    os.environ["XLA_FLAGS"] = " ".join(filter(None, [current, *extra]))
