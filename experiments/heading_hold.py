"""Does a policy hold the heading it observes? ``python experiments/heading_hold.py ckpt=<checkpoint>``.

Two probes in MuJoCo C (``engine=mujoco``), each rollout with the mean action and no pushes:

1. ``start``: the robot starts turned by 0, +-0.5 and 1.5 rad, commands zero or vx 0.3, and the
   heading is printed at 1, 2, 4, 6 and 10 s. A policy that ignores its heading keeps the one it
   started with; one that holds it turns back to 0.
2. ``blind``: the heading input (base_euler's yaw, every stacked frame) is held at 0 and the
   policy plays a yaw grid (vx 0 and 0.3, yaw -0.3 to 0.3): what it does without it.

The bipeds observe their heading, and every episode starts at 0 unless ``init_heading_range`` is
set, so a policy can learn to hold heading 0 against every yaw command (docs/command_grid.md,
stop 55: TRON1 turned back from 1.5 rad within a second; XBot-L, which follows yaw, kept any
start heading). For the quadrupeds, which do not observe a heading, ``blind`` is refused.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from ptrl_jax import command_grid, evaluate  # noqa: E402
from ptrl_jax.io.overrides import parse_cli  # noqa: E402

STARTS = (0.0, 0.5, -0.5, 1.5)
MARKS_S = (1, 2, 4, 6, 10)


def heading_entries(env) -> np.ndarray:
    """Indices of the heading in the actor's observation, one per stacked frame."""
    entries = [e for b in env.observation_blocks()["state"] for e in b.entries]
    idx = [i for i, e in enumerate(entries) if e.quantity == "heading"]
    if not idx:
        raise SystemExit(f"{env.config.asset}: the actor observes no heading; nothing to probe")
    return np.asarray(idx)


def start_probe(policy, env, actor) -> None:
    dt = env.config.ctrl_dt
    steps = int(round(max(MARKS_S) / dt))

    def rollout(params, norm, command, heading):
        state = env.reset_with_command(jax.random.PRNGKey(0), command)
        d = state.pipeline_state
        turn = jnp.array([jnp.cos(heading / 2), 0.0, 0.0, jnp.sin(heading / 2)])
        state = state.replace(pipeline_state=d.replace(qpos=d.qpos.at[3:7].set(turn)))

        def step(state, _):
            nxt = env.step(state, actor(params, norm, state.obs, jax.random.PRNGKey(1)))
            return nxt, (env.base_ang_vel(nxt.pipeline_state)[2], nxt.info["termination"] > 0)

        return jax.lax.scan(step, state, None, length=steps)[1]

    run = jax.jit(jax.vmap(rollout, in_axes=(None, None, None, 0)))
    for command in ((0.0, 0.0, 0.0), (0.3, 0.0, 0.0)):
        yaw_rate, fell = jax.device_get(run(policy["params"], policy["normalizer"], jnp.array(command), jnp.array(STARTS)))
        for h, w, f in zip(STARTS, np.asarray(yaw_rate), np.asarray(fell)):
            heading = h + np.cumsum(w) * dt
            marks = " ".join(f"{heading[int(round(t / dt)) - 1]:+.2f}" for t in MARKS_S)
            print(f"start heading {h:+.2f}, command {command}: heading at {', '.join(map(str, MARKS_S))} s: {marks}; "
                  f"peak |yaw rate| {np.abs(w).max():.2f} rad/s; fell {bool(f.any())}")


def blind_probe(policy, env, actor) -> None:
    idx = jnp.asarray(heading_entries(env))

    def blind(params, norm, obs, key):
        return actor(params, norm, dict(obs, state=obs["state"].at[..., idx].set(0.0)), key)

    one = command_grid.make_rollout(env, blind, 20.0, False, 8.0, 0.0)
    commands = jnp.array([[vx, 0.0, w] for vx in (0.0, 0.3) for w in (-0.3, -0.15, 0.0, 0.15, 0.3)])
    rec = jax.device_get(jax.jit(jax.vmap(one, in_axes=(None, None, 0, None)))(
        policy["params"], policy["normalizer"], commands, jax.random.PRNGKey(0)))
    for c, alive, v in zip(np.asarray(commands), np.asarray(rec["alive"]), np.asarray(rec["velocity"])):
        m = v[alive].mean(axis=0)
        print(f"heading held at 0, command ({c[0]:.1f}, {c[1]:.1f}, {c[2]:+.2f}): up {alive.sum() * env.config.ctrl_dt:4.1f} s, "
              f"vx {m[0]:+.3f} vy {m[1]:+.3f} yaw rate {m[2]:+.3f}")


def main(argv) -> int:
    args = parse_cli(argv)
    if "ckpt" not in args:
        raise SystemExit("usage: python experiments/heading_hold.py ckpt=<checkpoint> [probes=start,blind]")
    policy = evaluate.policy_from_checkpoint(str(args["ckpt"]))
    env = command_grid.grid_env(policy["robot"], evaluate.fixed_command_config(policy["env"], (0.0, 0.0, 0.0), 20.0),
                                "mujoco")
    actor = evaluate._actor_fn(policy["network"], policy["normalize_observations"], False)
    probes = str(args.get("probes", "start,blind")).strip("[]").split(",")
    for name in probes:
        if name not in ("start", "blind"):
            raise SystemExit(f"probes: unknown probe {name!r}; choose from start, blind")
        print(f"{policy['robot']}, {args['ckpt']}: {name}")
        (start_probe if name == "start" else blind_probe)(policy, env, actor)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
