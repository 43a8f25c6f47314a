"""Deterministic evaluation rollouts of a trained policy (the walking check).

    python -m ptrl_jax.evaluate ckpt=runs/go2_to_xbot/<stamp>/source.npz vx=0.5 seconds=20

The policy's mean action is applied (no sampling), the command is held fixed, and the episode
time limit is lifted, so the rollout ends only by a fall or after ``seconds``.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from typing import Any, Mapping

import jax
import jax.numpy as jnp
import numpy as np

import envs
from ptrl_jax.artifacts import load_checkpoint
from ptrl_jax.config import NetworkConfig
from ptrl_jax.networks import policy_apply
from ptrl_jax.overrides import ConfigError, apply_overrides, flatten, parse_cli
from ptrl_jax.train import normalize_obs


def fixed_command_config(env_cfg: Any, command: tuple[float, float, float], seconds: float) -> Any:
    c = env_cfg.commands
    commands = dataclasses.replace(
        c,
        lin_vel_x=(command[0], command[0]),
        lin_vel_y=(command[1], command[1]),
        yaw_rate=(command[2], command[2]),
        zero_below=0.0,
        resample_time_s=seconds + 1.0,
    )
    return dataclasses.replace(env_cfg, commands=commands, episode_length_s=seconds + 1.0,
                               init_joint_noise=0.0, init_base_vel_noise=0.0)


def evaluate_policy(
    robot: str,
    env_cfg: Any,
    params: Any,
    normalizer: Any,
    network: NetworkConfig,
    command: tuple[float, float, float] = (0.5, 0.0, 0.0),
    seconds: float = 20.0,
    seed: int = 0,
    normalize_observations: bool = True,
) -> dict[str, Any]:
    """Roll out one env for ``seconds`` under a fixed command; report tracking and falls."""
    env = envs.make(robot, fixed_command_config(env_cfg, command, seconds))
    steps = int(round(seconds / env.config.ctrl_dt))

    def step(carry, _):
        state, alive = carry
        obs = normalize_obs(normalizer, state.obs, normalize_observations)
        action = policy_apply(params, obs, network).mean
        nxt = env.step(state, action)
        data = nxt.pipeline_state
        vel = jnp.concatenate([env.base_lin_vel(data)[:2], env.base_ang_vel(data)[2:]])
        fell = nxt.info["termination"] > 0
        record = {"alive": alive, "velocity": vel, "height": data.qpos[2], "fell": fell & alive}
        return (nxt, alive & ~fell), record

    @jax.jit
    def rollout(key):
        state = env.reset(key)
        _, records = jax.lax.scan(step, (state, jnp.array(True)), None, length=steps)
        return records

    rec = jax.device_get(rollout(jax.random.PRNGKey(seed)))
    alive = rec["alive"].astype(bool)
    vel = rec["velocity"][alive]
    cmd = np.asarray(command, np.float32)
    mean_vel = vel.mean(axis=0) if len(vel) else np.full(3, np.nan)
    fell = bool(rec["fell"].any())
    return {
        "robot": robot,
        "command": [float(x) for x in cmd],
        "seconds": seconds,
        "fell": fell,
        "time_survived_s": float(alive.sum() * env.config.ctrl_dt),
        "mean_velocity": [float(x) for x in mean_vel],
        "forward_speed_error": float(abs(mean_vel[0] - cmd[0])),
        "tracking_rmse": float(np.sqrt(np.mean((vel - cmd) ** 2))) if len(vel) else float("nan"),
        "mean_base_height": float(rec["height"][alive].mean()) if alive.any() else float("nan"),
    }


def policy_from_checkpoint(path: str) -> dict[str, Any]:
    ckpt = load_checkpoint(path)
    meta = ckpt["meta"]
    robot = meta["robot"]
    env_cfg = apply_overrides(envs.default_config(robot), flatten(meta.get("env", {})))
    network = apply_overrides(NetworkConfig(), flatten(meta.get("network", {})))
    normalizer = {
        k: type_stats(v) for k, v in ckpt["normalizer"].items()
    }
    return {"robot": robot, "env": env_cfg, "network": network, "params": ckpt["params"],
            "normalizer": normalizer, "normalize_observations": meta.get("normalize_observations", True)}


def type_stats(d: Mapping[str, Any]):
    from ptrl_jax.normalization import RunningStats

    return RunningStats(mean=jnp.asarray(d["mean"]), m2=jnp.asarray(d["m2"]), count=jnp.asarray(d["count"]))


def main(argv: list[str] | None = None) -> int:
    try:
        args = parse_cli(sys.argv[1:] if argv is None else argv)
        if "ckpt" not in args:
            raise ConfigError("ckpt=PATH is required (a source.npz or target_*.npz of a run)")
        policy = policy_from_checkpoint(args.pop("ckpt"))
        command = (float(args.pop("vx", 0.5)), float(args.pop("vy", 0.0)), float(args.pop("yaw", 0.0)))
        seconds = float(args.pop("seconds", 20.0))
        sim = args.pop("sim", "mjx")
        if sim != "mjx":
            raise ConfigError(f"sim={sim!r}: only sim=mjx exists so far")
        if args:
            raise ConfigError(f"unknown argument(s) {sorted(args)}; known: ckpt, vx, vy, yaw, seconds, sim")
    except (ConfigError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    result = evaluate_policy(
        policy["robot"], policy["env"], policy["params"], policy["normalizer"], policy["network"],
        command, seconds, normalize_observations=policy["normalize_observations"],
    )
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
