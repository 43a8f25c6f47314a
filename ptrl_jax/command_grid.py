"""Evaluation over a grid of joystick commands, with optional pushes (issue 20).

    python -m ptrl_jax.evaluate ckpt=<run>/source.npz grid=true                 # the robot's default grid
    python -m ptrl_jax.evaluate ckpt=... grid=true sim=mujoco pushes=true out=go2_grid
    python -m ptrl_jax.evaluate ckpt=... grid=true grid_vx=[0,0.5,1] grid_vy=[0] grid_yaw=[-0.5,0,0.5]

Every (vx, vy, yaw rate) of the grid is held for ``seconds`` by the policy's mean action, all
rollouts in one vmapped, jitted scan, on MJX or on MuJoCo C (the env's ``engine=mujoco``). A
cell's error per axis is |mean velocity - command| over the steps the robot is up (the walking
check's measure, ``evaluate.summarize``; the within-stride swing is reported apart, as the RMS of
the per-step error). With ``pushes`` the same grid is rolled again, ``push_seeds`` times per
cell, with the base's planar velocity kicked by U(-v, v) per axis every ``push_interval_s``
(legged_gym's push), and the share of those rollouts that fall is counted.

Host side: ``summarize_grid`` turns the records into cells and a grid summary, ``verdict``
judges them against issue 20's goals, ``format_markdown`` / ``write_outputs`` write the table,
CSV, JSON and heat map.
"""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path
from typing import Any, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

import envs

AXES = ("vx", "vy", "yaw")
"""The command's axes: forward and sideways speed (m/s) and yaw rate (rad/s), base heading frame."""


@dataclasses.dataclass(frozen=True)
class CommandGrid:
    """What a grid evaluation rolls out and the goals it is judged by (issue 20's acceptance)."""

    vx: tuple[float, ...]
    """Forward speed commands, m/s."""
    vy: tuple[float, ...]
    """Sideways speed commands, m/s."""
    yaw: tuple[float, ...]
    """Yaw rate commands, rad/s."""
    seconds: float = 20.0
    """Length of every rollout, s (the walking check's 20 s)."""
    settle_s: float = 0.0
    """Steps before this time are left out of the tracking error (0: all, as the walking check)."""
    pushes: bool = False
    """Also roll the grid with pushes and count the falls."""
    push_seeds: int = 4
    """Pushed rollouts per cell, each with its own push directions."""
    push_interval_s: float = 8.0
    """A push every this many seconds (legged_gym: pushes every 15 s at up to 1 m/s; issue 20: 8 s)."""
    max_push_vel: float = 0.5
    """Each push adds U(-v, v) m/s to the base's world-frame x and y velocity."""
    max_vx_error: float = 0.1
    """Goal: mean over the grid of |mean vx - command|, m/s."""
    max_vy_error: float = 0.1
    """Goal: mean over the grid of |mean vy - command|, m/s."""
    max_yaw_error: float = 0.2
    """Goal: mean over the grid of |mean yaw rate - command|, rad/s."""
    max_push_fall_rate: float = 0.05
    """Goal: the largest share of pushed rollouts that may fall."""

    def __post_init__(self):
        for axis in AXES:
            values = getattr(self, axis)
            if not isinstance(values, tuple) or not values:
                raise ValueError(f"grid {axis}: give at least one value, e.g. grid_{axis}=[0,0.5], got {values!r}")
            if not all(np.isfinite(v) for v in values):
                raise ValueError(f"grid {axis}: every value must be finite, got {values!r}")
        if self.seconds <= 0:
            raise ValueError(f"grid seconds={self.seconds}: must be > 0")
        if not 0 <= self.settle_s < self.seconds:
            raise ValueError(f"grid settle_s={self.settle_s}: must be >= 0 and below seconds={self.seconds}")
        if self.push_seeds < 1:
            raise ValueError(f"grid push_seeds={self.push_seeds}: must be >= 1")
        if self.push_interval_s <= 0 or self.max_push_vel < 0:
            raise ValueError(f"grid pushes: push_interval_s={self.push_interval_s} must be > 0 and "
                             f"max_push_vel={self.max_push_vel} >= 0")

    def goals(self) -> dict[str, float]:
        """The mean-error goal per axis."""
        return {"vx": self.max_vx_error, "vy": self.max_vy_error, "yaw": self.max_yaw_error}

    def commands(self) -> np.ndarray:
        """[cells, 3] every (vx, vy, yaw) of the grid, vx slowest... yaw fastest."""
        mesh = np.meshgrid(self.vx, self.vy, self.yaw, indexing="ij")
        return np.stack([m.reshape(-1) for m in mesh], axis=-1).astype(np.float32)


def axis_values(low: float, high: float, points: int, include: Sequence[float] = ()) -> tuple[float, ...]:
    """``points`` evenly spaced values over [low, high], plus zero where the range holds it and
    any ``include`` value inside it, sorted, without duplicates (to 1e-6)."""
    values = list(np.linspace(low, high, points)) if points > 1 and high > low else [0.5 * (low + high)]
    for v in (0.0, *include):
        if low - 1e-9 <= v <= high + 1e-9:
            values.append(v)
    out: list[float] = []
    for v in sorted(float(round(x, 6)) for x in values):
        if not out or abs(v - out[-1]) > 1e-6:
            out.append(v)
    return tuple(out)


def default_grid(env_cfg: Any, walking_commands: Sequence[Sequence[float]] = (), points: tuple[int, int, int] = (5, 3, 3),
                 **fields: Any) -> CommandGrid:
    """The grid over the robot's training command ranges (``env_cfg.commands``), zero and the
    walking check's commands included, so that check is one cell of the grid. ``fields`` set
    any other field of ``CommandGrid``, axes included (then taken as given)."""
    c = env_cfg.commands
    ranges = (c.lin_vel_x, c.lin_vel_y, c.yaw_rate)
    axes = {axis: axis_values(lo, hi, n, [cmd[i] for cmd in walking_commands])
            for i, (axis, (lo, hi), n) in enumerate(zip(AXES, ranges, points))}
    return CommandGrid(**{**axes, **fields})


def push_schedule(steps: int, ctrl_dt: float, interval_s: float, max_vel: float, key: jax.Array) -> jax.Array:
    """[steps, 2] world-frame (x, y) base velocity changes, applied before the control step of
    that index: U(-max_vel, max_vel) per axis at every step index that is a positive multiple of
    ``interval_s / ctrl_dt``, zero elsewhere (the env's own push, ``LeggedEnv._push``, keeps the
    same period)."""
    every = max(int(round(interval_s / ctrl_dt)), 1)
    t = jnp.arange(steps)
    due = (t > 0) & (t % every == 0)
    kicks = jax.random.uniform(key, (steps, 2), minval=-1.0, maxval=1.0) * max_vel
    return jnp.where(due[:, None], kicks, 0.0)


def grid_env(robot: str, eval_cfg: Any, sim: str):
    """The env every grid rollout runs in: ``eval_cfg`` (the caller's evaluation config: no
    randomization, no initial noise, no command resampling or time limit within the rollout;
    ``evaluate.fixed_command_config``) on ``sim``'s engine (``mjx`` or ``mujoco``)."""
    return envs.make(robot, dataclasses.replace(eval_cfg, engine=sim))


def make_rollout(env, actor, seconds: float, pushes: bool, push_interval_s: float, max_push_vel: float):
    """``rollout(params, normalizer, command [3], key) -> records`` of one rollout (``alive``,
    ``fell``, ``velocity`` [T, 3]: base vx, vy in the heading frame and yaw rate), pure and
    vmappable. ``actor(params, normalizer, obs, key) -> action``."""
    steps = int(round(seconds / env.config.ctrl_dt))

    def rollout(params, normalizer, command, key):
        reset_key, push_key, action_key = jax.random.split(key, 3)
        state = env.reset_with_command(reset_key, command)
        kicks = (push_schedule(steps, env.config.ctrl_dt, push_interval_s, max_push_vel, push_key) if pushes
                 else jnp.zeros((steps, 2)))

        def step(carry, kick):
            state, alive, key = carry
            key, k = jax.random.split(key)
            data = state.pipeline_state
            state = state.replace(pipeline_state=data.replace(qvel=data.qvel.at[:2].add(kick)))
            nxt = env.step(state, actor(params, normalizer, state.obs, k))
            fell = nxt.info["termination"] > 0
            data = nxt.pipeline_state
            velocity = jnp.concatenate([env.base_lin_vel(data)[:2], env.base_ang_vel(data)[2:]])
            record = {"alive": alive & ~fell, "fell": fell & alive, "velocity": velocity}
            return (nxt, alive & ~fell, key), record

        _, records = jax.lax.scan(step, (state, jnp.array(True), action_key), kicks)
        return records

    return rollout


def rollout_grid(robot: str, eval_cfg: Any, actor, params: Any, normalizer: Any, grid: CommandGrid, sim: str,
                 pushes: bool = False, seed: int = 0) -> dict[str, np.ndarray]:
    """Records of every cell (and, with ``pushes``, every push seed): ``alive`` and ``fell``
    [cells, seeds, T], ``velocity`` [cells, seeds, T, 3], in one jitted call. ``eval_cfg``: see
    ``grid_env``."""
    env = grid_env(robot, eval_cfg, sim)
    one = make_rollout(env, actor, grid.seconds, pushes, grid.push_interval_s, grid.max_push_vel)
    seeds = grid.push_seeds if pushes else 1
    per_seed = jax.vmap(one, in_axes=(None, None, None, 0))
    per_cell = jax.vmap(per_seed, in_axes=(None, None, 0, None))
    keys = jax.random.split(jax.random.PRNGKey(seed), seeds)
    records = jax.jit(per_cell)(params, normalizer, jnp.asarray(grid.commands()), keys)
    out = {k: np.asarray(v) for k, v in jax.device_get(records).items()}
    out["dt"] = float(env.config.ctrl_dt)
    return out


def summarize_grid(commands: np.ndarray, records: Mapping[str, Any], settle_s: float = 0.0) -> dict[str, Any]:
    """Cells and a summary from ``rollout_grid``'s records.

    Per cell: the mean velocity over the steps the robot is up (after ``settle_s``), over all
    its seeds' such steps; the error per axis, |mean - command|; the RMS of the per-step error
    (the stride's swing); whether any seed fell and the share that fell; the mean time up.
    Summary: the mean error per axis over the cells (cells with no step up count as NaN and
    are left out of the mean, their falls counted); ``standing_error``, the mean a robot that
    stood still would score over the same cells (the mean |command|), and ``tracked``, the share
    of that error the policy removes (1 - mean error / standing error; NaN on an axis the grid
    never commands); the number of cells with a fall and the share of all rollouts that fell."""
    commands = np.asarray(commands, np.float64)
    up = np.asarray(records["alive"]).astype(bool)          # [cells, seeds, T]
    fell = np.asarray(records["fell"]).astype(bool)
    vel = np.asarray(records["velocity"], np.float64)       # [cells, seeds, T, 3]
    dt = float(records["dt"])
    counted = up & (np.arange(up.shape[-1]) * dt >= settle_s - 1e-9)
    cells = []
    for i, cmd in enumerate(commands):
        mask = counted[i]
        n = int(mask.sum())
        mean_vel = vel[i][mask].mean(axis=0) if n else np.full(3, np.nan)
        rms = np.sqrt(((vel[i][mask] - cmd) ** 2).mean(axis=0)) if n else np.full(3, np.nan)
        fell_seeds = fell[i].any(axis=-1)
        cells.append({
            "command": [float(x) for x in cmd],
            "mean_velocity": [float(x) for x in mean_vel],
            "error": [float(x) for x in np.abs(mean_vel - cmd)],
            "rms_error": [float(x) for x in rms],
            "fell": bool(fell_seeds.any()),
            "fall_rate": float(fell_seeds.mean()),
            "time_up_s": float(up[i].sum(axis=-1).mean() * dt),
        })
    errors = np.array([c["error"] for c in cells])
    with np.errstate(invalid="ignore"):
        mean_error = np.nanmean(errors, axis=0) if np.isfinite(errors).any() else np.full(3, np.nan)
        # the same mean for a robot that stands still (velocity 0): the mean |command| over the cells counted
        standing = np.array([np.abs(commands[np.isfinite(errors[:, a]), a]).mean() if np.isfinite(errors[:, a]).any()
                             else np.nan for a in range(3)])
        tracked = np.where(standing > 0, 1.0 - mean_error / np.where(standing > 0, standing, 1.0), np.nan)
    rollouts = fell.shape[0] * fell.shape[1]
    return {
        "cells": cells,
        "mean_error": {axis: float(e) for axis, e in zip(AXES, mean_error)},
        "standing_error": {axis: float(e) for axis, e in zip(AXES, standing)},
        "tracked": {axis: float(t) for axis, t in zip(AXES, tracked)},
        "cells_with_fall": int(sum(c["fell"] for c in cells)),
        "fall_rate": float(fell.any(axis=-1).sum() / rollouts),
        "rollouts": int(rollouts),
    }


def verdict(grid: CommandGrid, summary: Mapping[str, Any], pushed: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Issue 20's goals: no fall on the grid, the mean errors within the goals, and with
    pushes at most ``max_push_fall_rate`` of the pushed rollouts fallen. ``passed`` and the
    reasons it is not."""
    reasons = []
    if summary["cells_with_fall"]:
        reasons.append(f"fell in {summary['cells_with_fall']} of {len(summary['cells'])} cells")
    for axis, goal in grid.goals().items():
        err = summary["mean_error"][axis]
        if not err <= goal:  # NaN fails
            reasons.append(f"mean |{axis} error| {err:.3f} > {goal}")
    if pushed is not None and not pushed["fall_rate"] <= grid.max_push_fall_rate:
        reasons.append(f"{pushed['fall_rate']:.1%} of pushed rollouts fell > {grid.max_push_fall_rate:.0%}")
    return {"passed": not reasons, "why_not": "; ".join(reasons), "caveats": goal_caveats(grid, summary)}


def goal_caveats(grid: CommandGrid, summary: Mapping[str, Any]) -> list[str]:
    """The axes whose goal a robot that ignores that axis would meet on this grid: where the
    goal is at least the standing error (yaw rates {-0.3, 0, 0.3} give a standing error of
    exactly 0.2, the yaw goal). Meeting such a goal says nothing of tracking; read ``tracked``."""
    out = []
    for axis, goal in grid.goals().items():
        standing = summary.get("standing_error", {}).get(axis, float("nan"))
        if standing <= goal:
            tracked = summary.get("tracked", {}).get(axis, float("nan"))
            out.append(f"the {axis} goal ({goal:g}) is met by a robot that ignores {axis} on this grid "
                       f"(standing error {standing:.3f}); this policy removes {tracked:.0%} of it")
    return out


def cell_for(summary: Mapping[str, Any], command: Sequence[float]) -> dict[str, Any] | None:
    """The cell of ``command``, or None."""
    for c in summary["cells"]:
        if np.allclose(c["command"], command, atol=1e-6):
            return c
    return None


def format_markdown(robot: str, sim: str, grid: CommandGrid, summary: Mapping[str, Any],
                    pushed: Mapping[str, Any] | None, judged: Mapping[str, Any],
                    walking_check: Sequence[Mapping[str, Any]] = ()) -> str:
    """The grid as a markdown table, one row per command, with the summary, the walking
    checks read from their cells, and the verdict."""
    push_cols = " falls under pushes |" if pushed else ""
    lines = [
        f"# Command grid: {robot} ({sim}), {grid.seconds:g} s per command, mean action", "",
        f"| vx | vy | yaw | measured vx | vy | yaw | error vx | vy | yaw | fell |{push_cols}",
        "|---|---|---|---|---|---|---|---|---|---|" + ("---|" if pushed else ""),
    ]
    for k, c in enumerate(summary["cells"]):
        fell = f"at {c['time_up_s']:.1f} s" if c["fell"] else "no"
        row = ("| " + " | ".join(f"{x:g}" for x in c["command"]) + " | "
               + " | ".join(f"{x:.3f}" for x in c["mean_velocity"]) + " | "
               + " | ".join(f"{x:.3f}" for x in c["error"]) + f" | {fell} |")
        if pushed:
            row += f" {pushed['cells'][k]['fall_rate']:.0%} |"
        lines.append(row)
    m = summary["mean_error"]
    lines += ["", f"Mean error over the grid: vx {m['vx']:.3f} m/s (goal {grid.max_vx_error}), "
                  f"vy {m['vy']:.3f} m/s (goal {grid.max_vy_error}), yaw {m['yaw']:.3f} rad/s (goal {grid.max_yaw_error}). "
                  f"Cells with a fall: {summary['cells_with_fall']} of {len(summary['cells'])}."]
    if "standing_error" in summary:
        st, tr = summary["standing_error"], summary["tracked"]
        lines.append("Standing still would score " + ", ".join(f"{a} {st[a]:.3f}" for a in AXES)
                     + "; this policy removes " + ", ".join(f"{a} {tr[a]:.0%}" for a in AXES) + " of that error.")
    if pushed:
        lines.append(f"With pushes (U(-{grid.max_push_vel:g}, {grid.max_push_vel:g}) m/s per axis every "
                     f"{grid.push_interval_s:g} s, {grid.push_seeds} per cell): {pushed['fall_rate']:.1%} of "
                     f"{pushed['rollouts']} rollouts fell (goal at most {grid.max_push_fall_rate:.0%}).")
    for v in walking_check:
        lines.append(f"Walking check '{v['check']}' (its cell, vx {v['command'][0]:g}): "
                     + ("passes" if v["passed"] else f"fails ({v['why_not']})") + ".")
    lines += ["", "**passes**" if judged["passed"] else f"**fails**: {judged['why_not']}"]
    lines += [f"Caveat: {c}." for c in judged.get("caveats", ())]
    return "\n".join(lines) + "\n"


def write_outputs(out_dir: Path, robot: str, sim: str, grid: CommandGrid, summary: Mapping[str, Any],
                  pushed: Mapping[str, Any] | None, judged: Mapping[str, Any],
                  walking_check: Sequence[Mapping[str, Any]] = (), asset: str | None = None,
                  trained_on: str | None = None) -> list[Path]:
    """``grid.md``, ``grid.csv`` (a row per cell), ``grid.json`` (everything) and ``grid.png``
    (the heat map) in ``out_dir``; the paths written. ``grid.json``'s ``model`` names the MJCF
    graded on (``asset``, the robot's default when None) by its ``envs.asset_sha256``, and the
    version the policy was trained on (``trained_on``, from its checkpoint; None when it does not
    say); where the two differ, ``grid.md`` says so."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / f"grid.{ext}" for ext in ("md", "csv", "json", "png")]
    asset = asset or envs.default_config(robot).asset
    model = {"asset": asset, "graded_on": envs.asset_sha256(asset), "trained_on": trained_on}
    if trained_on is not None and trained_on != model["graded_on"]:
        judged = {**judged, "caveats": [*judged.get("caveats", ()),
                                        f"the policy was trained on another version of {asset} (sha256 "
                                        f"{trained_on}) than the one graded on ({model['graded_on']})"]}
    paths[0].write_text(format_markdown(robot, sim, grid, summary, pushed, judged, walking_check))
    with open(paths[1], "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["cmd_vx", "cmd_vy", "cmd_yaw", "vx", "vy", "yaw", "error_vx", "error_vy", "error_yaw",
                    "rms_vx", "rms_vy", "rms_yaw", "fell", "time_up_s"] + (["push_fall_rate"] if pushed else []))
        for k, c in enumerate(summary["cells"]):
            w.writerow([*c["command"], *c["mean_velocity"], *c["error"], *c["rms_error"], int(c["fell"]),
                        c["time_up_s"]] + ([pushed["cells"][k]["fall_rate"]] if pushed else []))
    paths[2].write_text(json.dumps({"robot": robot, "sim": sim, "model": model,
                                    "grid": dataclasses.asdict(grid),
                                    "summary": summary, "pushed": pushed, "verdict": judged,
                                    "walking_check": list(walking_check)}, indent=2))
    from ptrl_jax.io.figures import plot_command_grid

    plot_command_grid(paths[3], grid, summary, pushed, f"{robot} ({sim})")
    return paths
