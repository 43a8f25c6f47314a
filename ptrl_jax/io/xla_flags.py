"""XLA compile settings for compile-bound runs (``scale=smoke`` and the test suite).

A smoke run spends nearly all its time compiling: XLA's CPU backend optimises the program's
LLVM code for speed that a few iterations of 16 envs never use back. Measured on the 2-core CPU
(``experiments/bench.py``'s machine, 2026-11-22), the go2_to_xbot smoke program's XLA compile
took 120 s by default and 56 s at backend optimisation level 0; tracing (about 30 s) is unchanged.

The legacy (non-thunk) CPU runtime, ``--xla_cpu_use_thunk_runtime=false``, took that compile to
43 s on the jaxlib of the time. The jaxlib this project now installs (0.8) has dropped it: its
flag parser keeps the name only to print "is no longer supported" and sets nothing (XLA's
debug_options_flags.cc), so the flag is no longer passed. The thunk runtime is the only one.

XLA reads these flags once, when jax creates its CPU backend, so they must be set before
anything runs a jax computation (importing brax or MJX already does). ``python -m ptrl_jax.run``
sets them for ``scale=smoke`` before its imports; ``tests/conftest.py`` sets them for the suite.
A resumed run (``resume=DIR``) takes the XLA flags its state was computed with from the saved
state (``flags_of_saved_run``), whatever its command line says: other flags compile another
program, whose float results can differ in the last bits.
This module imports nothing from jax.
"""

from __future__ import annotations

import os

FAST_COMPILE_FLAGS = ("--xla_backend_optimization_level=0",)
"""Appended to XLA_FLAGS, unless the user's XLA_FLAGS already names the setting."""


def use_fast_compile() -> None:
    """Add ``FAST_COMPILE_FLAGS`` to the XLA_FLAGS environment variable (a no-op for flags the
    variable already sets). Effective only before jax's backend exists."""
    current = os.environ.get("XLA_FLAGS", "")
    extra = [f for f in FAST_COMPILE_FLAGS if f.split("=")[0] not in current]
    os.environ["XLA_FLAGS"] = " ".join(filter(None, [current, *extra]))


def flags_of_saved_run(argv: list[str]) -> str | None:
    """The XLA_FLAGS recorded in ``resume=DIR``'s saved state, when ``argv`` resumes a run and
    the state records them (None otherwise). Reads the state with numpy only."""
    import json
    from pathlib import Path

    run_dir = next((a.split("=", 1)[1] for a in argv if a.startswith("resume=")), None)
    if run_dir is None:
        return None
    try:
        import numpy as np

        with np.load(Path(run_dir) / "resume_state.npz") as z:
            meta = json.loads(bytes(z["__meta__"]).decode())
        return meta.get("runtime", {}).get("xla_flags")
    except Exception:  # no or damaged state: run.resume names the problem
        return None


def configure_from_argv(argv: list[str]) -> None:
    """What ``python -m ptrl_jax.run`` does before its imports: a resumed run gets its saved
    XLA flags, a ``scale=smoke`` run the fast-compile flags."""
    saved = flags_of_saved_run(argv)
    if saved is not None:
        if "XLA_FLAGS" not in os.environ:
            os.environ["XLA_FLAGS"] = saved
        return
    if "scale=smoke" in argv:
        use_fast_compile()
