"""How far apart the two physics engines drift: ``python experiments/engine_gap.py
[robots=a1,go2] [solver=4:4,8:4,4:30]``.

For each robot and each ``iterations:line_search_steps`` setting of the constraint solver, resets
4 envs from the same keys, holds zero actions for 10 control steps in MJX and in MuJoCo C
(``engine=mujoco``), and prints the largest joint/base position gap per step and the largest
reward gap. ``docs/engines.md`` gives what it printed and why the gap depends on the solver.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import envs  # noqa: E402
from ptrl_jax.io.overrides import parse_cli  # noqa: E402

STEPS = 10


def hold(env, keys):
    """(qpos, reward) per control step of a zero-action hold from ``keys``' resets."""
    zeros = jnp.zeros((len(keys), env.action_size))

    @jax.jit
    def run(keys):
        def step(state, _):
            nxt = jax.vmap(env.step)(state, zeros)
            return nxt, (nxt.pipeline_state.qpos, nxt.reward)
        return jax.lax.scan(step, jax.vmap(env.reset)(keys), None, length=STEPS)[1]

    return tuple(np.asarray(x) for x in run(keys))


def main(argv):
    args = parse_cli(argv)
    robots = str(args.get("robots", "a1,go2")).strip("[]").split(",")
    settings = [tuple(int(v) for v in s.split(":")) for s in str(args.get("solver", "4:4,8:4")).strip("[]").split(",")]
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    for robot in robots:
        for iterations, ls in settings:
            cfg = dataclasses.replace(envs.default_config(robot), solver_iterations=iterations, ls_iterations=ls)
            (q0, r0), (q1, r1) = (hold(envs.make(robot, dataclasses.replace(cfg, engine=e)), keys) for e in ("mjx", "mujoco"))
            per_step = np.abs(q0 - q1).max(axis=(1, 2))
            print(f"{robot:10s} solver {iterations}:{ls}: max |qpos gap| {per_step.max():.1e} (per step "
                  f"{' '.join(f'{d:.0e}' for d in per_step)}), max |reward gap| {np.abs(r0 - r1).max():.1e}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
