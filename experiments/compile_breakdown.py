"""Where a program's compile time goes (not a test):
``python experiments/compile_breakdown.py exp=xbot_to_all [scale=smoke] [key=value ...]``.

Prints, for the experiment's one compiled program (with the smoke run's XLA flags): building
the envs, tracing (``init``'s shapes, which trace every stage), lowering ``advance`` to
StableHLO, the StableHLO's size, and XLA's compile. The suite's budget is set by these numbers:
each MJX pipeline in a program adds its trace and its share of the XLA compile.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ptrl_jax.io.xla_flags import use_fast_compile  # noqa: E402

use_fast_compile()  # before jax creates its backend, as for scale=smoke and the suite

import jax  # noqa: E402
import numpy as np  # noqa: E402

from ptrl_jax.io.overrides import load_experiment, parse_cli  # noqa: E402
from ptrl_jax.core.program import make_program  # noqa: E402


def main(argv: list[str]) -> None:
    args = parse_cli(argv)
    exp = args.pop("exp", "go2_to_xbot")
    overrides = {"scale": "smoke", **args}
    cfg = load_experiment(exp, [f"{k}={v}" for k, v in overrides.items()])
    if cfg.source_checkpoint:
        raise SystemExit("compile_breakdown: leave out source_checkpoint (the program would need its file)")

    def stamp(label, t0, extra=""):
        print(f"{label:<32} {time.monotonic() - t0:7.1f} s {extra}", flush=True)

    print(f"{exp} ({overrides}), jax {jax.__version__}, {jax.devices()[0].platform}")
    t = time.monotonic()
    program = make_program(cfg, None)
    stamp("build envs and trainers", t)
    key = jax.random.PRNGKey(0)
    t = time.monotonic()
    shapes = jax.eval_shape(jax.jit(program.init), key, None)
    stamp("trace (init's shapes)", t)
    t = time.monotonic()
    lowered = jax.jit(program.advance).lower(shapes, np.int32(1))
    text = lowered.as_text()
    stamp("lower advance to StableHLO", t, f"({len(text) / 1e6:.1f} MB, {text.count(chr(10)):,} lines)")
    t = time.monotonic()
    lowered.compile()
    stamp("XLA compile", t)


if __name__ == "__main__":
    main(sys.argv[1:])
