"""The per-robot learning table of issue 3, point 5: robots trained from scratch, then the walking
check of each robot's family on every scratch checkpoint.

Host-side: a row is built from one experiment's ``metrics.csv`` rows (env steps, final reward)
and the verdicts of ``evaluate.run_walking_check`` on its checkpoints, so a notebook can rebuild
the table from finished runs. One row per (target robot, seed, check): a quadruped has one check
(walk at vx 0.5), a biped two (stand at vx 0, walk at vx 0.3).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ptrl_jax.io.summary import curves_by_preset, fmt_number

FIELDS = (
    "experiment", "robot", "seed", "iterations", "env_steps", "compile_s", "train_s", "final_reward",
    "check", "command_vx", "fell", "time_survived_s", "forward_speed", "speed_error", "passed", "why_not",
)

Checker = Callable[[Path], list[dict[str, Any]]]
"""Checkpoint path -> one verdict per check (``evaluate.run_walking_check``'s dicts)."""

GridChecker = Callable[[Path], dict[str, Any]]
"""Checkpoint path -> ``evaluate.run_grid``'s result (summary, pushed summary, verdict)."""

GRID_FIELDS = ("experiment", "robot", "seed", "sim", "cells", "error_vx", "error_vy", "error_yaw", "tracked_vx",
               "tracked_vy", "tracked_yaw", "cells_with_fall", "push_fall_rate", "passed", "why_not")


def scratch_checkpoint(run_dir: Path, robot: str, seed: int, multi_target: bool) -> Path:
    """The file ``outputs.save_outputs`` writes for a scratch run (``target_[<robot>_]scratch_seed<k>.npz``)."""
    return Path(run_dir) / (f"target_{robot}_scratch_seed{seed}.npz" if multi_target else f"target_scratch_seed{seed}.npz")


def experiment_rows(
    experiment: str, metrics: Sequence[Mapping[str, Any]], run_dir: Path, checker: Checker,
    final_window: int, compile_s: float = float("nan"), train_s: float = float("nan"),
) -> list[dict[str, Any]]:
    """Rows for every target robot and seed of one experiment's scratch runs."""
    target_rows = [r for r in metrics if r["stage"] == "target"]
    robots = list(dict.fromkeys(str(r["robot"]) for r in target_rows))
    out = []
    for robot in robots:
        curves = curves_by_preset([r for r in target_rows if r["robot"] == robot])
        if "scratch" not in curves:
            raise ValueError(f"{experiment} -> {robot}: no metrics for the 'scratch' preset "
                             f"(the walking-check table checks the scratch runs)")
        c = curves["scratch"]
        for seed in range(c["reward"].shape[0]):
            base = {"experiment": experiment, "robot": robot, "seed": seed,
                    "iterations": int(c["reward"].shape[1]), "env_steps": int(c["env_steps"][-1]),
                    "compile_s": compile_s, "train_s": train_s,
                    "final_reward": float(c["reward"][seed, -final_window:].mean())}
            for v in checker(scratch_checkpoint(run_dir, robot, seed, len(robots) > 1)):
                out.append({**base, "check": v["check"], "command_vx": float(v["command"][0]),
                            "fell": bool(v["fell"]), "time_survived_s": float(v["time_survived_s"]),
                            "forward_speed": float(v["mean_velocity"][0]),
                            "speed_error": float(v["forward_speed_error"]), "passed": bool(v["passed"]),
                            "why_not": v["why_not"]})
    return out


def grid_rows(experiment: str, metrics: Sequence[Mapping[str, Any]], run_dir: Path,
              grid_checker: GridChecker) -> list[dict[str, Any]]:
    """One row per target robot and seed of the experiment's scratch runs: the command grid's
    mean errors, falls and verdict (``command_grid``)."""
    target_rows = [r for r in metrics if r["stage"] == "target" and r["preset"] == "scratch"]
    robots = list(dict.fromkeys(str(r["robot"]) for r in target_rows))
    all_robots = {str(r["robot"]) for r in metrics if r["stage"] == "target"}
    out = []
    for robot in robots:
        seeds = sorted({int(r["seed"]) for r in target_rows if r["robot"] == robot})
        for seed in seeds:
            g = grid_checker(scratch_checkpoint(run_dir, robot, seed, len(all_robots) > 1))
            s, pushed = g["summary"], g["pushed"]
            out.append({"experiment": experiment, "robot": robot, "seed": seed, "sim": g["sim"],
                        "cells": len(s["cells"]), **{f"error_{a}": s["mean_error"][a] for a in ("vx", "vy", "yaw")},
                        **{f"tracked_{a}": s.get("tracked", {}).get(a, float("nan")) for a in ("vx", "vy", "yaw")},
                        "cells_with_fall": s["cells_with_fall"],
                        "push_fall_rate": pushed["fall_rate"] if pushed else float("nan"),
                        "passed": bool(g["verdict"]["passed"]), "why_not": g["verdict"]["why_not"]})
    return out


def format_grid_markdown(rows: Sequence[Mapping[str, Any]], notes: Sequence[str] = ()) -> str:
    lines = ["# Every robot from scratch: the command grid", ""]
    lines += [f"- {n}" for n in notes]
    lines += ["", "| robot | experiment | seed | sim | cells | mean error vx / vy (m/s) / yaw (rad/s) | "
                  "share of standing still's error removed, vx / vy / yaw | cells with a fall | "
                  "pushed rollouts fallen | result |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        result = "passes" if r["passed"] else f"fails: {r['why_not']}"
        tracked = " / ".join(fmt_number(r.get(f"tracked_{a}", float("nan")), "{:.0%}") for a in ("vx", "vy", "yaw"))
        lines.append(f"| {r['robot']} | {r['experiment']} | {r['seed']} | {r['sim']} | {r['cells']} | "
                     f"{r['error_vx']:.3f} / {r['error_vy']:.3f} / {r['error_yaw']:.3f} | {tracked} | {r['cells_with_fall']} | "
                     f"{fmt_number(r['push_fall_rate'], '{:.1%}')} | {result} |")
    lines += ["", f"**{sum(bool(r['passed']) for r in rows)} of {len(rows)} runs meet every goal of the grid.**"]
    return "\n".join(lines) + "\n"


def format_markdown(rows: Sequence[Mapping[str, Any]], notes: Sequence[str] = ()) -> str:
    lines = ["# Every robot from scratch: the walking check of its family", ""]
    lines += [f"- {n}" for n in notes]
    lines += [
        "",
        "| robot | experiment | seed | env steps | compile + training | final reward | check | fell | "
        "mean forward speed (error) | result |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        fell = f"at {r['time_survived_s']:.2f} s" if r["fell"] else "no"
        result = "passes" if r["passed"] else f"fails: {r['why_not']}"
        lines.append(
            f"| {r['robot']} | {r['experiment']} | {r['seed']} | {fmt_number(r['env_steps'], '{:,.0f}')} | "
            f"{fmt_number(r['compile_s'], '{:.0f}')} + {fmt_number(r['train_s'], '{:.0f}')} s | "
            f"{r['final_reward']:.2f} | {r['check']} vx {r['command_vx']:g} | {fell} | "
            f"{r['forward_speed']:.3f} m/s ({r['speed_error']:.3f}) | {result} |")
    by_robot: dict[str, bool] = {}
    for r in rows:
        key = f"{r['robot']} seed {r['seed']}"
        by_robot[key] = by_robot.get(key, True) and bool(r["passed"])
    passed = sum(by_robot.values())
    lines += ["", f"**{passed} of {len(by_robot)} runs pass every check of their family.**"]
    return "\n".join(lines) + "\n"


def passed_all(rows: Sequence[Mapping[str, Any]]) -> bool:
    return bool(rows) and bool(np.all([r["passed"] for r in rows]))
