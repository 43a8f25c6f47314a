"""Figures of evaluation rollouts (host-side only): velocity tracking (paper Fig. 6) and
filmstrips of a robot's motion (paper Figs. 4, 8, 9).

Both take the records of ``evaluate.rollout_mjx`` / ``rollout_mujoco`` (``velocity``,
``command``, ``alive``, ``qpos``, ``dt`` and ``model``), so they work for either engine.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

# A command schedule like Fig. 6's: held segments that step forward speed, then add sideways
# speed and a yaw rate. Each row is (vx, vy, yaw rate), held for an equal share of the rollout.
FIG6_SCHEDULE = (
    (0.3, 0.0, 0.0),
    (0.6, 0.0, 0.0),
    (0.9, 0.0, 0.0),
    (0.5, 0.2, 0.0),
    (0.5, 0.0, 0.4),
    (0.0, 0.0, 0.0),
)


def schedule_commands(schedule, steps: int) -> np.ndarray:
    """[steps, 3] commands: the schedule's rows held for equal shares of ``steps``."""
    rows = np.asarray(schedule, np.float32)
    if rows.ndim != 2 or rows.shape[1] != 3 or len(rows) == 0:
        raise ValueError(f"a command schedule is a list of [vx, vy, yaw_rate] rows, got shape {rows.shape}")
    segment = np.minimum((np.arange(steps) * len(rows)) // steps, len(rows) - 1)
    return rows[segment]


def standing_steps(rec: Mapping[str, Any]) -> np.ndarray:
    """Per step, whether the robot is up: alive, and not the fall's own step (whose record
    already holds the auto-reset state)."""
    return np.asarray(rec["alive"]).astype(bool) & ~np.asarray(rec["fell"]).astype(bool)


def plot_velocity_tracking(path: Path, rec: Mapping[str, Any], title: str) -> None:
    """Three panels (vx, vy, yaw rate): commanded (dashed) against the base's actual velocity in
    its heading frame, over time. A fall is marked and the curve stops there."""
    from matplotlib.figure import Figure  # no pyplot: leaves a notebook's backend alone

    fell = np.asarray(rec["fell"]).astype(bool)
    standing = standing_steps(rec)
    t = np.arange(len(standing)) * rec["dt"]
    vel = np.where(standing[:, None], np.asarray(rec["velocity"]), np.nan)
    cmd = np.asarray(rec["command"])
    labels = ("forward vx (m/s)", "sideways vy (m/s)", "yaw rate (rad/s)")
    fig = Figure(figsize=(8, 6.5))
    axes = fig.subplots(3, 1, sharex=True)
    for i, (ax, label) in enumerate(zip(axes, labels)):
        ax.plot(t, cmd[:, i], "--", color="k", lw=1.2, label="commanded")
        ax.plot(t, vel[:, i], color="tab:blue", lw=1.0, label="actual")
        if fell.any():
            ax.axvline(t[np.argmax(fell)], color="tab:red", lw=1, label="fall")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", ncol=3, fontsize=8)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def frame_steps(rec: Mapping[str, Any], frames: int, span_s: float | None = None) -> np.ndarray:
    """The steps to draw: ``frames`` evenly spaced over the rollout up to a fall, or over its
    last ``span_s`` seconds (a gait cycle or two of steady walking, or the fall itself)."""
    if frames < 1:
        raise ValueError(f"frames={frames}: must be >= 1")
    last = max(int(standing_steps(rec).sum()) - 1, 0)  # the step before a fall
    first = 0 if span_s is None else max(last - int(round(span_s / rec["dt"])), 0)
    return np.linspace(first, last, frames).round().astype(int)


def render_frames(rec: Mapping[str, Any], frames: int = 6, width: int = 320, height: int = 240,
                  span_s: float | None = None) -> list[np.ndarray]:
    """RGB images at ``frame_steps``, from a side camera that tracks the base. MuJoCo's
    offscreen renderer (``MUJOCO_GL=egl`` on headless machines)."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    import mujoco

    model = rec["model"]
    picks = frame_steps(rec, frames, span_s)
    data = mujoco.MjData(model)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_TRACKING
    cam.trackbodyid = 1
    cam.distance = 1.5 * max(float(model.stat.extent), 0.5)
    cam.azimuth, cam.elevation = 90.0, -12.0  # from the robot's left: the gait in profile
    images = []
    with mujoco.Renderer(model, height, width) as renderer:
        for i in picks:
            data.qpos[:] = np.asarray(rec["qpos"])[i]
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera=cam)
            images.append(renderer.render().copy())
    return images


def save_filmstrip(path: Path, rec: Mapping[str, Any], title: str, frames: int = 6,
                   span_s: float | None = None) -> None:
    """A row of rendered frames with their times (paper Figs. 4, 8, 9)."""
    from matplotlib.figure import Figure  # no pyplot: leaves a notebook's backend alone

    images = render_frames(rec, frames, span_s=span_s)
    times = frame_steps(rec, frames, span_s) * rec["dt"]
    fig = Figure(figsize=(2.4 * frames, 2.2))
    axes = fig.subplots(1, frames)
    for ax, img, t in zip(np.atleast_1d(axes), images, times):
        ax.imshow(img)
        ax.set_title(f"t = {t:.1f} s", fontsize=9)
        ax.axis("off")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def plot_command_grid(path: Path, grid: Any, summary: Mapping[str, Any], pushed: Mapping[str, Any] | None,
                      title: str) -> None:
    """The command grid's heat map (``command_grid``): a column of panels per sideways command,
    a row per error axis (and one for the share of pushed rollouts that fell); each panel puts
    forward speed across and yaw rate up, colours the cell's error from 0 (green) to twice the
    goal (red) and marks a fall with a red cross."""
    from matplotlib.figure import Figure  # no pyplot: leaves a notebook's backend alone

    vx, vy, yaw = (np.asarray(v, float) for v in (grid.vx, grid.vy, grid.yaw))
    shape = (len(vx), len(vy), len(yaw))
    cells = summary["cells"]
    error = np.array([c["error"] for c in cells]).reshape(*shape, 3)
    fell = np.array([c["fell"] for c in cells]).reshape(shape)
    rows = [("|vx error| (m/s)", error[..., 0], grid.max_vx_error), ("|vy error| (m/s)", error[..., 1], grid.max_vy_error),
            ("|yaw error| (rad/s)", error[..., 2], grid.max_yaw_error)]
    if pushed is not None:
        rows.append(("falls under pushes", np.array([c["fall_rate"] for c in pushed["cells"]]).reshape(shape),
                     grid.max_push_fall_rate))
    fig = Figure(figsize=(1.2 + 0.55 * len(vx) * len(vy) + 1.0 * len(vy), 1.0 + 0.45 * len(yaw) * len(rows) + 0.6 * len(rows)))
    axes = np.asarray(fig.subplots(len(rows), len(vy), squeeze=False))
    for r, (label, values, goal) in enumerate(rows):
        for j in range(len(vy)):
            ax = axes[r, j]
            img = values[:, j, :].T  # yaw up, vx across
            im = ax.imshow(img, origin="lower", cmap="RdYlGn_r", vmin=0.0, vmax=max(2 * goal, 1e-9), aspect="auto")
            for a in range(len(vx)):
                for b in range(len(yaw)):
                    text = "nan" if not np.isfinite(img[b, a]) else (f"{img[b, a]:.0%}" if pushed is not None and r == 3
                                                                       else f"{img[b, a]:.2f}")
                    ax.text(a, b, text, ha="center", va="center", fontsize=6)
                    if fell[a, j, b] and r < 3:
                        ax.plot(a, b, "x", color="darkred", ms=10, mew=1.5)
            ax.set_xticks(range(len(vx)), [f"{v:g}" for v in vx], fontsize=7)
            ax.set_yticks(range(len(yaw)), [f"{v:g}" for v in yaw], fontsize=7)
            if r == len(rows) - 1:
                ax.set_xlabel("vx command (m/s)", fontsize=8)
            if j == 0:
                ax.set_ylabel(f"{label}\nyaw command (rad/s)", fontsize=8)
            if r == 0:
                ax.set_title(f"vy command {vy[j]:g} m/s", fontsize=8)
        fig.colorbar(im, ax=list(axes[r]), shrink=0.8, label=f"goal {goal:g}")
    fig.suptitle(f"{title}: tracking error per command (x: fell)", fontsize=10)
    fig.savefig(path, dpi=110)


def plot_ratio_curve(path: Path, curve: Mapping[str, Any], scratch: Mapping[str, Any], title: str) -> None:
    """One freeze-ratio curve of ``transfer_table.ratio_curves`` (merged runs): env steps to the
    threshold and final reward against the frozen share of L1 and L2, the ``rho<r>`` variants as
    a line, whole-layer presets ('L2', 'L1') as labelled squares, scratch as a dashed line."""
    from matplotlib.figure import Figure  # no pyplot: leaves a notebook's backend alone

    fig = Figure(figsize=(10, 3.8))
    axes = fig.subplots(1, 2)
    for ax, (key, label, scale) in zip(axes, [("steps", "env steps to threshold (M)", 1e-6),
                                              ("final_reward", "final episode reward", 1.0)]):
        for is_ratio, style in ((True, dict(marker="o", ls="-")), (False, dict(marker="s", ls="none"))):
            points = [p for p in curve["points"] if p["ratio"] == is_ratio]
            if not points:
                continue
            x = np.array([p["share"] for p in points])
            y = np.array([p[f"{key}_mean"] for p in points], float) * scale
            err = np.array([p[f"{key}_std"] for p in points], float) * scale
            ax.errorbar(x, y, yerr=err, capsize=3, label="freeze ratio rho" if is_ratio else "whole layers", **style)
            if not is_ratio:
                for xi, yi, p in zip(x, y, points):
                    ax.annotate(p["preset"].split("@")[0], (xi, yi), textcoords="offset points", xytext=(5, 5))
        if np.isfinite(scratch[f"{key}_mean"]):
            ax.axhline(scratch[f"{key}_mean"] * scale, color="k", ls="--", lw=1, label="scratch")
        ax.set_xlabel("frozen share of L1 and L2")
        ax.set_ylabel(label)
        ax.set_xlim(-0.05, 1.05)
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
