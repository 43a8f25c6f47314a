"""TensorBoard event files from a run's metrics rows (``tensorboard=true``): host-side, outside
the jitted program, written when the run writes ``metrics.csv``.

One event folder per run of the program, ``tensorboard/<stage>_<robot>_<preset>_seed<k>``, so
TensorBoard overlays the variants and seeds; every numeric column of ``metrics.csv`` is a scalar
(``episode_reward``, ``episode_reward/tracking_lin_vel``, ``loss/value``, ...) against env steps,
with the row's wall time. Open with ``tensorboard --logdir runs/<exp>/<stamp>/tensorboard``.
"""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path
from typing import Any, Mapping, Sequence

IDENTIFIERS = ("stage", "robot", "preset", "seed", "iteration", "env_steps", "wall_time_s")
"""Columns that name a row or place it in time rather than measure it."""


def run_name(row: Mapping[str, Any]) -> str:
    preset = str(row["preset"]).replace("@", "_at_")
    return f"{row['stage']}_{row['robot']}_{preset}_seed{int(row['seed'])}"


def write_events(log_dir: Path, rows: Sequence[Mapping[str, Any]], start_time: float = 0.0) -> list[Path]:
    """Write ``rows`` (metrics.csv rows) as event files under ``log_dir``; returns the folders.
    ``start_time``: the run's start (seconds since the epoch), added to each row's wall time."""
    from tensorboardX import SummaryWriter  # a dependency of brax; imported only when used

    by_run: dict[str, list[Mapping[str, Any]]] = defaultdict(list)
    for row in rows:
        by_run[run_name(row)].append(row)
    folders = []
    for name, run_rows in by_run.items():
        folder = Path(log_dir) / name
        with SummaryWriter(str(folder)) as writer:
            for row in sorted(run_rows, key=lambda r: int(r["iteration"])):
                step = int(row["env_steps"])
                wall = start_time + float(row.get("wall_time_s", 0.0))
                for key, value in row.items():
                    if key in IDENTIFIERS or isinstance(value, str):
                        continue
                    value = float(value)
                    if math.isfinite(value):
                        writer.add_scalar(key, value, step, walltime=wall)
        folders.append(folder)
    return folders
