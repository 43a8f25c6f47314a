"""Deterministic evaluation rollouts of a trained policy: the walking check and sim-to-sim.

    python -m ptrl_jax.evaluate ckpt=runs/go2_to_xbot/<stamp>/source.npz vx=0.5 seconds=20
    python -m ptrl_jax.evaluate ckpt=... sim=mujoco        # MJX and MuJoCo C, side by side
    python -m ptrl_jax.evaluate ckpt=... mcap=rollout.mcap # also write the rollout for Foxglove
    python -m ptrl_jax.evaluate ckpt=... schedule=fig6 plot=tracking.png   # paper Fig. 6
    python -m ptrl_jax.evaluate ckpt=... filmstrip=go2.png filmstrip_span=1.2   # Figs. 4, 8, 9
    python -m ptrl_jax.evaluate ckpt=... stochastic=true   # sampled actions, as in training
    python -m ptrl_jax.evaluate ckpt=... check=true        # the robot family's walking check
    python -m ptrl_jax.evaluate ckpt=... grid=true pushes=true   # every command of the training range

The policy's mean action is applied (no sampling; ``stochastic=true`` samples the actions from
the policy's Gaussian instead, as in training), the command is held fixed, and the episode
time limit is lifted, so the rollout ends only by a fall or after ``seconds``. ``sim=mjx`` (the
default) rolls out the training env; ``sim=mujoco`` also rolls out the same policy in the MuJoCo
C env (``envs.gym_env``: same model, observation and reward code, another physics engine) and
prints both results.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import sys
from pathlib import Path
from typing import Any, Mapping

import jax
import jax.numpy as jnp
import numpy as np

import envs
from envs.quadruped import QuadrupedEnv
from ptrl_jax import command_grid
from ptrl_jax.io.artifacts import CheckpointError, load_checkpoint
from ptrl_jax.io.checkpoints import warn_if_model_changed
from ptrl_jax.config import NetworkConfig
from ptrl_jax.io.figures import FIG6_SCHEDULE, schedule_commands
from ptrl_jax.core.networks import make_policy
from ptrl_jax.io.overrides import ConfigError, apply_overrides, coerce, flatten, parse_known_cli
from ptrl_jax.core.train import normalize_obs

SIMS = ("mjx", "mujoco")


@dataclasses.dataclass(frozen=True)
class WalkingCheck:
    """One deterministic rollout of the walking check: hold ``command`` for ``seconds``; it
    passes when the robot does not fall and its mean forward speed is within
    ``max_speed_error`` of the commanded vx."""

    name: str
    """What the rollout shows ("walk", "stand")."""
    command: tuple[float, float, float]
    """(vx, vy, yaw_rate) held throughout, m/s and rad/s."""
    seconds: float = 20.0
    """Rollout length, s."""
    max_speed_error: float = 0.15
    """Largest accepted |mean forward speed - commanded vx|, m/s."""


# Issue 3's checks. Quadrupeds: Go2's walking check (vx 0.5 for 20 s, no fall, within 0.15 m/s).
# Bipeds: stand 20 s at zero command and walk at vx 0.3 without falling; we hold both to the
# quadrupeds' 0.15 m/s speed tolerance, so that drifting away does not count as standing and
# standing still does not count as walking.
QUADRUPED_CHECKS = (WalkingCheck("walk", (0.5, 0.0, 0.0)),)
BIPED_CHECKS = (WalkingCheck("stand", (0.0, 0.0, 0.0)), WalkingCheck("walk", (0.3, 0.0, 0.0)))


def walking_checks(robot: str) -> tuple[WalkingCheck, ...]:
    """The checks of the robot's family."""
    return QUADRUPED_CHECKS if issubclass(envs.family(robot), QuadrupedEnv) else BIPED_CHECKS


def check_verdict(check: WalkingCheck, result: Mapping[str, Any]) -> dict[str, Any]:
    """``result`` (``summarize``'s fields) judged against ``check``: passed, and why not."""
    reasons = []
    if result["fell"]:
        reasons.append(f"fell at {result['time_survived_s']:.2f} s")
    error = result["forward_speed_error"]
    if not error <= check.max_speed_error:  # NaN (no step survived) fails too
        reasons.append(f"forward speed {result['mean_velocity'][0]:.3f} m/s, {error:.3f} m/s off the command, "
                       f"tolerance {check.max_speed_error}")
    return {"check": check.name, "command": list(check.command), "passed": not reasons,
            "why_not": "; ".join(reasons), **{k: result[k] for k in ("fell", "time_survived_s", "mean_velocity",
                                                                     "forward_speed_error")}}


def run_walking_check(policy: Mapping[str, Any], seed: int = 0, sim: str = "mjx",
                      seconds: float | None = None) -> list[dict[str, Any]]:
    """Every check of the policy's robot family, each a deterministic rollout (mean action, no
    initial noise, no randomization); one verdict per check. ``seconds`` shortens the rollouts
    (the checks' own 20 s otherwise)."""
    verdicts = []
    for check in walking_checks(policy["robot"]):
        if seconds is not None:
            check = dataclasses.replace(check, seconds=float(seconds))
        result = evaluate_policy(robot=policy["robot"], env_cfg=policy["env"], params=policy["params"],
                                 normalizer=policy["normalizer"], network=policy["network"], command=check.command,
                                 seconds=check.seconds, seed=seed, sim=sim,
                                 normalize_observations=policy["normalize_observations"])
        verdicts.append(check_verdict(check, result))
    return verdicts


def run_grid(policy: Mapping[str, Any], grid: command_grid.CommandGrid, sim: str = "mjx",
             seed: int = 0) -> dict[str, Any]:
    """The policy's mean action over every command of ``grid`` (``command_grid``), on ``sim``,
    unpushed and, with ``grid.pushes``, pushed: the cells, summaries, the verdict against issue
    20's goals, and the family's walking checks read from their cells (each check's command is a
    cell of the default grid; with ``grid.seconds`` other than the check's 20 s it is the same
    measure over another length)."""
    if sim not in SIMS:
        raise ValueError(f"sim={sim!r}: choose one of {SIMS}")
    eval_cfg = fixed_command_config(policy["env"], (0.0, 0.0, 0.0), grid.seconds)
    actor = _actor_fn(policy["network"], policy["normalize_observations"], False)
    args = (policy["robot"], eval_cfg, actor, policy["params"], policy["normalizer"], grid, sim)
    summary = command_grid.summarize_grid(grid.commands(), command_grid.rollout_grid(*args, seed=seed), grid.settle_s)
    pushed = None
    if grid.pushes:
        pushed = command_grid.summarize_grid(grid.commands(), command_grid.rollout_grid(*args, pushes=True, seed=seed),
                                             grid.settle_s)
    checks = []
    for check in walking_checks(policy["robot"]):
        cell = command_grid.cell_for(summary, check.command)
        if cell is not None:
            checks.append(check_verdict(check, {"fell": cell["fell"], "time_survived_s": cell["time_up_s"],
                                                "mean_velocity": cell["mean_velocity"],
                                                "forward_speed_error": cell["error"][0]}))
    return {"robot": policy["robot"], "sim": sim, "grid": grid, "summary": summary, "pushed": pushed,
            "verdict": command_grid.verdict(grid, summary, pushed), "walking_check": checks}


def format_verdicts(robot: str, verdicts: list[dict[str, Any]]) -> str:
    lines = [f"walking check, {robot}:"]
    for v in verdicts:
        status = "pass" if v["passed"] else f"FAIL ({v['why_not']})"
        lines.append(f"  {v['check']:5s} vx {v['command'][0]:.2f}: survived {v['time_survived_s']:.2f} s, "
                     f"forward speed {v['mean_velocity'][0]:.3f} m/s: {status}")
    lines.append("passes" if all(v["passed"] for v in verdicts) else "fails")
    return "\n".join(lines)


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
    # Deterministic: no initial noise (joints, base velocity, heading) and no domain randomization
    # (pushes, gain draws).
    randomization = dataclasses.replace(env_cfg.randomization, enabled=False)
    return dataclasses.replace(env_cfg, commands=commands, episode_length_s=seconds + 1.0,
                               init_joint_noise=0.0, init_base_vel_noise=0.0, init_heading_range=0.0,
                               randomization=randomization)


class Actor:
    """``act(raw observation dict, key) -> action``: the Gaussian's mean (the key is unused), or
    with ``stochastic`` a sample from the Gaussian, as the training rollouts act. ``step`` is
    the same with the key split inside, jitted once per network and mode and shared by every
    actor (policies evaluated one after another compile once)."""

    def __init__(self, params, normalizer, network: NetworkConfig, normalize_observations: bool, stochastic: bool):
        self.params, self.normalizer = params, normalizer
        self._apply = _actor_fn(network, normalize_observations, stochastic)
        self._step = _actor_step(network, normalize_observations, stochastic)

    def __call__(self, obs, key):
        return self._apply(self.params, self.normalizer, obs, key)

    def step(self, obs, key):
        """(action, next key) in one jitted dispatch."""
        return self._step(self.params, self.normalizer, obs, key)


@functools.lru_cache(maxsize=None)
def _actor_fn(network: NetworkConfig, normalize_observations: bool, stochastic: bool):
    def apply(params, normalizer, obs, key):
        policy = make_policy(params, network, deterministic=not stochastic)
        return policy(normalize_obs(normalizer, obs, normalize_observations), key)

    return apply


@functools.lru_cache(maxsize=None)
def _actor_step(network: NetworkConfig, normalize_observations: bool, stochastic: bool):
    apply = _actor_fn(network, normalize_observations, stochastic)

    @jax.jit
    def step(params, normalizer, obs, key):
        key, action_key = jax.random.split(key)
        return apply(params, normalizer, obs, action_key), key

    return step


def make_actor(params: Any, normalizer: Any, network: NetworkConfig, normalize_observations: bool = True,
               stochastic: bool = False) -> Actor:
    """``act(raw observation dict, key) -> action``: the Gaussian's mean (the key is unused), or
    with ``stochastic`` a sample from the Gaussian, as the training rollouts act.

    Why both: a policy can owe its motion to the exploration noise. Go2 trained for 240
    iterations stands under its mean action (0.075 m/s at vx = 0.5) but walks 0.40 to 0.49 m/s
    with sampled actions (README), so the deterministic check and the training reward disagree."""
    return Actor(params, normalizer, network, normalize_observations, stochastic)


@functools.lru_cache(maxsize=16)
def _gym_env(robot: str, env_cfg: Any):
    """The MuJoCo C view of a (robot, config), built once (its jitted code compiles once)."""
    return envs.LocomotionGymEnv(robot, env_cfg)


def rollout_mjx(robot: str, env_cfg: Any, actor, command, seconds: float, seed: int = 0,
                schedule=None) -> dict[str, Any]:
    """Records of a fixed-command rollout in the MJX env: each ``[T, ...]``; ``alive`` is False
    from the step after a fall (the env auto-resets; those steps are not counted). With a
    ``schedule`` (rows of [vx, vy, yaw_rate], ``figures.schedule_commands``) the command steps
    through its rows instead of holding ``command``."""
    env = envs.make(robot, fixed_command_config(env_cfg, command, seconds))
    steps = int(round(seconds / env.config.ctrl_dt))
    commands = None if schedule is None else jnp.asarray(schedule_commands(schedule, steps))

    def step(carry, command_now):
        state, alive, key = carry
        key, action_key = jax.random.split(key)
        if command_now is not None:
            state = state.replace(info={**state.info, "command": command_now})
        nxt = env.step(state, actor(state.obs, action_key))
        data = nxt.pipeline_state
        fell = nxt.info["termination"] > 0
        record = {
            "alive": alive, "fell": fell & alive,
            "velocity": jnp.concatenate([env.base_lin_vel(data)[:2], env.base_ang_vel(data)[2:]]),
            "height": data.qpos[2], "qpos": data.qpos, "qvel": data.qvel,
            "command": state.info["command"], "terms": nxt.metrics,
        }
        return (nxt, alive & ~fell, key), record

    @jax.jit
    def rollout(key):
        state = env.reset(key)
        action_key = jax.random.fold_in(key, 1)  # apart from the reset's key, which stays the seed's
        _, records = jax.lax.scan(step, (state, jnp.array(True), action_key), commands, length=steps)
        return records

    rec = jax.device_get(rollout(jax.random.PRNGKey(seed)))
    rec["dt"] = env.config.ctrl_dt
    rec["model"] = env.mj_model
    return rec


def rollout_mujoco(robot: str, env_cfg: Any, actor, command, seconds: float, seed: int = 0) -> dict[str, Any]:
    """The same rollout in the MuJoCo C env (``envs.gym_env``), with the same records."""
    gym_env = _gym_env(robot, fixed_command_config(env_cfg, command, seconds))
    steps = int(round(seconds / gym_env.config.ctrl_dt))
    if isinstance(actor, Actor):
        act = actor.step  # one dispatch per step: the key split runs inside the jitted call
    else:
        @jax.jit
        def act(obs, key):
            key, action_key = jax.random.split(key)
            return actor(obs, action_key), key

    key = jax.random.fold_in(jax.random.PRNGKey(seed), 1)
    obs, info = gym_env.reset(seed=seed, options={"command": command})
    full_obs = {"state": obs, "privileged_state": info["privileged_state"]}
    keys = ("alive", "fell", "velocity", "height", "qpos", "qvel", "command")
    rec: dict[str, list] = {k: [] for k in keys}
    terms: dict[str, list] = {}
    alive = True
    for _ in range(steps):
        if alive:
            action, key = act(full_obs, key)
            action = np.asarray(action)
        else:
            action = np.zeros(gym_env.action_space.shape, np.float32)
        cmd = info["command"]
        obs, _, terminated, _, info = gym_env.step(action)
        d = gym_env.data
        rot = d.xmat[1].reshape(3, 3)
        rec["alive"].append(alive)
        rec["fell"].append(alive and terminated)
        rec["velocity"].append(np.concatenate([(rot.T @ d.qvel[:3])[:2], d.qvel[5:6]]))
        rec["height"].append(d.qpos[2])
        rec["qpos"].append(d.qpos.copy())
        rec["qvel"].append(d.qvel.copy())
        rec["command"].append(cmd)
        for k, v in info.items():
            if k.startswith("reward/"):
                terms.setdefault(k, []).append(v)
        alive = alive and not terminated
        full_obs = {"state": obs, "privileged_state": info["privileged_state"]}
    out: dict[str, Any] = {k: np.asarray(v) for k, v in rec.items()}
    out["terms"] = {k: np.asarray(v) for k, v in terms.items()}
    out["dt"] = gym_env.config.ctrl_dt
    out["model"] = gym_env.model
    return out


def summarize(rec: Mapping[str, Any], robot: str, command, seconds: float, sim: str) -> dict[str, Any]:
    """Tracking metrics over the steps before any fall."""
    alive = np.asarray(rec["alive"]).astype(bool)
    vel = np.asarray(rec["velocity"])[alive]
    cmd = np.asarray(command, np.float32)
    mean_vel = vel.mean(axis=0) if len(vel) else np.full(3, np.nan)
    return {
        "robot": robot,
        "sim": sim,
        "command": [float(x) for x in cmd],
        "seconds": seconds,
        "fell": bool(np.asarray(rec["fell"]).any()),
        "time_survived_s": float(alive.sum() * rec["dt"]),
        "mean_velocity": [float(x) for x in mean_vel],
        "forward_speed_error": float(abs(mean_vel[0] - cmd[0])),
        "tracking_rmse": float(np.sqrt(np.mean((vel - cmd) ** 2))) if len(vel) else float("nan"),
        "mean_base_height": float(np.asarray(rec["height"])[alive].mean()) if alive.any() else float("nan"),
    }


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
    sim: str = "mjx",
    mcap_path: str | None = None,
    schedule=None,
    plot_path: str | None = None,
    filmstrip_path: str | None = None,
    filmstrip_span_s: float | None = None,
    stochastic: bool = False,
) -> dict[str, Any]:
    """Roll out one env for ``seconds`` under a fixed command (or a ``schedule`` of commands,
    MJX only); report tracking and falls. Optionally write the rollout as MCAP, the velocity
    tracking figure (Fig. 6) and a filmstrip (Figs. 4, 8, 9). ``stochastic`` samples the
    actions (``make_actor``); ``seed`` then also picks the samples."""
    if sim not in SIMS:
        raise ValueError(f"sim={sim!r}: choose one of {SIMS}")
    if schedule is not None and sim != "mjx":
        raise ValueError("a command schedule needs sim=mjx (the MuJoCo C env holds one command)")
    actor = make_actor(params, normalizer, network, normalize_observations, stochastic)
    if sim == "mjx":
        rec = rollout_mjx(robot, env_cfg, actor, tuple(float(c) for c in command), seconds, seed, schedule)
    else:
        rec = rollout_mujoco(robot, env_cfg, actor, tuple(float(c) for c in command), seconds, seed)
    if mcap_path is not None:
        write_mcap(mcap_path, rec)
    title = f"{robot} ({sim})"
    if plot_path is not None:
        from ptrl_jax.io.figures import plot_velocity_tracking

        plot_velocity_tracking(plot_path, rec, f"{title}: commanded and actual base velocity")
    if filmstrip_path is not None:
        from ptrl_jax.io.figures import save_filmstrip

        save_filmstrip(filmstrip_path, rec, title, span_s=filmstrip_span_s)
    result = summarize(rec, robot, command, seconds, sim)
    result["actions"] = "sampled" if stochastic else "mean"
    if schedule is not None:
        # Per-step tracking against the commands actually given (the fixed-command fields above
        # compare with ``command``, which a schedule replaces).
        alive = np.asarray(rec["alive"]).astype(bool)
        err = np.asarray(rec["velocity"])[alive] - np.asarray(rec["command"])[alive]
        result["command"] = "schedule"
        result["forward_speed_error"] = float(np.mean(np.abs(err[:, 0]))) if alive.any() else float("nan")
        result["tracking_rmse"] = float(np.sqrt(np.mean(err ** 2))) if alive.any() else float("nan")
    return result


def write_mcap(path: str, rec: Mapping[str, Any]) -> dict[str, int]:
    from ptrl_jax.io.mcap_log import write_rollout

    alive = np.asarray(rec["alive"]).astype(bool)
    return write_rollout(
        path, rec["model"], rec["dt"], np.asarray(rec["qpos"])[alive], np.asarray(rec["qvel"])[alive],
        np.asarray(rec["command"])[alive], {k: np.asarray(v)[alive] for k, v in rec["terms"].items()},
    )


def policy_from_checkpoint(path: str) -> dict[str, Any]:
    ckpt = load_checkpoint(path)
    meta = ckpt["meta"]
    robot = meta.get("robot")
    if robot not in envs.ROBOTS:
        raise CheckpointError(f"checkpoint {path}: robot {robot!r} is not one of {envs.robot_names()}")
    env_cfg = apply_overrides(envs.default_config(robot), flatten(meta.get("env", {})))
    network = apply_overrides(NetworkConfig(), flatten(meta.get("network", {})))
    normalizer = {k: type_stats(v) for k, v in ckpt["normalizer"].items()}
    check_policy_fits_robot(path, ckpt["params"], robot, env_cfg)
    warn_if_model_changed(path, meta, env_cfg.asset)
    return {"robot": robot, "env": env_cfg, "network": network, "params": ckpt["params"],
            "normalizer": normalizer, "normalize_observations": meta.get("normalize_observations", True),
            "asset_sha256": meta.get("asset_sha256")}


def check_policy_fits_robot(path: str, params: Any, robot: str, env_cfg: Any) -> None:
    """Refuse weights whose input or output size is not this robot's (another robot's policy)."""
    try:
        actor = params["actor"]
        w_in = np.asarray(actor["layer_0"]["w"])
        w_out = np.asarray(actor[f"layer_{len(actor) - 1}"]["w"])
    except (KeyError, TypeError):
        raise CheckpointError(f"checkpoint {path}: no actor/layer_0 ... weights in it") from None
    env = envs.make(robot, env_cfg)
    obs_size = int(jax.eval_shape(env.reset, jax.random.PRNGKey(0)).obs["state"].shape[-1])
    if w_in.shape[0] != obs_size:
        raise CheckpointError(f"checkpoint {path}: actor/layer_0/w takes {w_in.shape[0]} inputs, but robot "
                              f"{robot!r} observations have {obs_size} (weights of another robot?)")
    if w_out.shape[1] != env.action_size:
        raise CheckpointError(f"checkpoint {path}: the actor outputs {w_out.shape[1]} actions, but robot "
                              f"{robot!r} has {env.action_size} (weights of another robot?)")


def type_stats(d: Mapping[str, Any]):
    from ptrl_jax.core.normalization import RunningStats

    return RunningStats(mean=jnp.asarray(d["mean"]), m2=jnp.asarray(d["m2"]), count=jnp.asarray(d["count"]))


KNOWN_ARGS = ("ckpt", "vx", "vy", "yaw", "seconds", "sim", "seed", "mcap", "plot", "filmstrip", "filmstrip_span",
              "schedule", "stochastic", "check", "grid", "grid_vx", "grid_vy", "grid_yaw", "settle", "pushes",
              "push_seeds", "push_interval", "push_vel", "out", "overwrite")
GRID_ARGS = ("grid_vx", "grid_vy", "grid_yaw", "settle", "pushes", "push_seeds", "push_interval", "push_vel", "out",
             "overwrite")
"""Arguments of ``grid=true`` only."""
ROLLOUT_ARGS = ("vx", "vy", "yaw", "seconds", "mcap", "plot", "filmstrip", "filmstrip_span", "schedule", "stochastic")
"""Arguments of a single rollout, which ``check=true`` replaces by the family's fixed checks."""


def parse_schedule(text: str):
    """``schedule=fig6`` (``figures.FIG6_SCHEDULE``) or ``schedule=[[vx,vy,yaw],...]``."""
    if text == "fig6":
        return FIG6_SCHEDULE
    import yaml

    try:
        rows = yaml.safe_load(text)
        schedule_commands(rows, 1)
    except Exception:
        raise ConfigError(f"schedule={text!r}: give fig6 or a list of [vx,vy,yaw_rate] rows, "
                          f"e.g. schedule=[[0.3,0,0],[0.6,0,0.3]]") from None
    return tuple(tuple(float(x) for x in row) for row in rows)


def parse_values(key: str, text: str) -> tuple[float, ...]:
    """``grid_vx=[0,0.5,1]`` (or one number) as a tuple of floats."""
    import yaml

    try:
        values = yaml.safe_load(text)
        values = [values] if isinstance(values, (int, float)) else values
        out = tuple(float(v) for v in values)
    except Exception:
        raise ConfigError(f"{key}={text!r}: give a list of numbers, e.g. {key}=[-0.5,0,0.5]") from None
    if not out:
        raise ConfigError(f"{key}={text!r}: give at least one value")
    return out


def grid_from_args(args: Mapping[str, str], policy: Mapping[str, Any], seconds: float) -> command_grid.CommandGrid:
    """The default grid of the policy's robot (``command_grid.default_grid``) with the CLI's
    ``grid_*``, ``settle``, ``pushes``, ``push_seeds``, ``push_interval`` (s) and ``push_vel``
    (m/s) in place."""
    fields: dict[str, Any] = {"seconds": seconds,
                              "pushes": coerce(args.get("pushes", "false"), bool, "pushes")}
    if "settle" in args:
        fields["settle_s"] = coerce(args["settle"], float, "settle")
    if "push_seeds" in args:
        fields["push_seeds"] = coerce(args["push_seeds"], int, "push_seeds")
    if "push_interval" in args:
        fields["push_interval_s"] = coerce(args["push_interval"], float, "push_interval")
    if "push_vel" in args:
        fields["max_push_vel"] = coerce(args["push_vel"], float, "push_vel")
    for axis in command_grid.AXES:
        if f"grid_{axis}" in args:
            fields[axis] = parse_values(f"grid_{axis}", args[f"grid_{axis}"])
    try:
        return command_grid.default_grid(policy["env"], [c.command for c in walking_checks(policy["robot"])], **fields)
    except ValueError as e:
        raise ConfigError(str(e)) from None


def grid_out_dir(args: Mapping[str, str], sim: str) -> Path:
    """``out=`` or ``<checkpoint stem>_grid_<sim>/`` beside the checkpoint; a folder that
    already holds a grid is refused unless ``overwrite=true`` (nothing written is lost)."""
    ckpt = Path(args["ckpt"])
    out = Path(args["out"]) if "out" in args else ckpt.with_name(f"{ckpt.stem}_grid_{sim}")
    if (out / "grid.json").exists() and not coerce(args.get("overwrite", "false"), bool, "overwrite"):
        raise ConfigError(f"out={out}: it already holds a grid (grid.json); give another out= or overwrite=true")
    if not out.parent.exists():
        raise ConfigError(f"out={out}: folder {out.parent} does not exist")
    return out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(f"{__doc__}\nkeys: {', '.join(KNOWN_ARGS)}")
        return 0
    try:
        args = parse_known_cli(argv, KNOWN_ARGS)
        if "ckpt" not in args:
            raise ConfigError("ckpt=PATH is required (a source.npz or target_*.npz of a run)")
        command = (float(args.get("vx", 0.5)), float(args.get("vy", 0.0)), float(args.get("yaw", 0.0)))
        seconds = float(args.get("seconds", 20.0))
        seed = int(args.get("seed", 0))
        sim = args.get("sim", "mjx")
        if sim not in SIMS:
            raise ConfigError(f"sim={sim!r}: choose one of {', '.join(SIMS)}")
        if seconds <= 0:
            raise ConfigError(f"seconds={seconds}: must be > 0")
        schedule = parse_schedule(args["schedule"]) if "schedule" in args else None
        stochastic = coerce(args.get("stochastic", "false"), bool, "stochastic")
        check = coerce(args.get("check", "false"), bool, "check")
        grid = coerce(args.get("grid", "false"), bool, "grid")
        if not grid and set(args) & set(GRID_ARGS):
            raise ConfigError(f"{', '.join(sorted(set(args) & set(GRID_ARGS)))}: only with grid=true")
        single = set(ROLLOUT_ARGS) - {"seconds"}
        if grid and (check or set(args) & single):
            raise ConfigError(f"grid=true rolls out the whole grid (its cells hold the walking check); drop "
                              f"{', '.join(sorted((set(args) & single) | ({'check'} if check else set())))}")
        if check and set(args) & set(ROLLOUT_ARGS):
            raise ConfigError(f"check=true runs the robot family's fixed rollouts; drop "
                              f"{', '.join(sorted(set(args) & set(ROLLOUT_ARGS)))}")
        span = float(args["filmstrip_span"]) if "filmstrip_span" in args else None
        if span is not None and span <= 0:
            raise ConfigError(f"filmstrip_span={span}: must be > 0 (seconds before the rollout's end or fall)")
        if schedule is not None and sim != "mjx":
            raise ConfigError("schedule=... needs sim=mjx (the MuJoCo C env holds one command)")
        for key in ("plot", "filmstrip", "mcap"):
            if key in args and not Path(args[key]).parent.exists():
                raise ConfigError(f"{key}={args[key]}: folder {Path(args[key]).parent} does not exist")
        policy = policy_from_checkpoint(args["ckpt"])
        if grid:
            spec = grid_from_args(args, policy, seconds)
            out_dir = grid_out_dir(args, sim)
    except (ConfigError, CheckpointError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if grid:  # exit status 0 when the grid meets every goal, 1 when not
        result = run_grid(policy, spec, sim=sim, seed=seed)
        paths = command_grid.write_outputs(out_dir, result["robot"], sim, spec, result["summary"], result["pushed"],
                                           result["verdict"], result["walking_check"], policy["env"].asset,
                                           policy.get("asset_sha256"))
        print(paths[0].read_text())
        if result["walking_check"]:
            print(format_verdicts(policy["robot"], result["walking_check"]))
        print("wrote " + ", ".join(str(p) for p in paths))
        return 0 if result["verdict"]["passed"] else 1
    if check:  # exit status 0 when every check passes, 1 when one fails
        verdicts = run_walking_check(policy, seed=seed, sim=sim)
        print(json.dumps(verdicts, indent=2))
        print(format_verdicts(policy["robot"], verdicts))
        return 0 if all(v["passed"] for v in verdicts) else 1
    common = dict(robot=policy["robot"], env_cfg=policy["env"], params=policy["params"],
                  normalizer=policy["normalizer"], network=policy["network"], command=command,
                  seconds=seconds, seed=seed, normalize_observations=policy["normalize_observations"],
                  stochastic=stochastic)
    results = [evaluate_policy(**common, sim="mjx", mcap_path=args.get("mcap") if sim == "mjx" else None,
                               schedule=schedule, plot_path=args.get("plot"), filmstrip_path=args.get("filmstrip"),
                               filmstrip_span_s=span)]
    if sim == "mujoco":
        results.append(evaluate_policy(**common, sim="mujoco", mcap_path=args.get("mcap")))
        print(format_side_by_side(results))
    print(json.dumps(results if len(results) > 1 else results[0], indent=2))
    for key in ("mcap", "plot", "filmstrip"):
        if key in args:
            print(f"wrote {args[key]}")
    return 0


def format_side_by_side(results: list[dict[str, Any]]) -> str:
    rows = [("metric", *[r["sim"] for r in results])]
    for key in ("actions", "fell", "time_survived_s", "mean_velocity", "forward_speed_error", "tracking_rmse", "mean_base_height"):
        fmt = lambda v: ", ".join(f"{x:.3f}" for x in v) if isinstance(v, list) else (f"{v:.3f}" if isinstance(v, float) else str(v))  # noqa: E731
        rows.append((key, *[fmt(r[key]) for r in results]))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(row, widths)) for row in rows)


if __name__ == "__main__":
    raise SystemExit(main())
