"""Paper Table IV from metrics: training time to a threshold with transfer and without.

Host-side only, pure functions of ``metrics.csv`` rows, so notebooks can rebuild the table
from finished runs. The rule, per target robot of an experiment:

- threshold = ``threshold_fraction`` x the scratch baseline's final reward (mean over seeds of
  the mean over the last ``final_window`` iterations), the same rule as report.md;
- for every seed, the env steps and the target-stage wall time at the first iteration whose mean
  episode reward reaches it, for the scratch run and for the transfer run (``transfer_preset``);
- saved = 1 - transfer / scratch, per seed (seeds are paired: same initialisation of the
  non-transferred layers and same env stream), then mean and std over the seeds where both
  reached the threshold.

In one program every variant runs in lockstep under ``vmap`` and shares one clock, so the wall
time of each run is the stage's time at that iteration, and the wall-time saving equals the
env-step saving up to the spread of iteration times. A frozen layer does not make an iteration
cheaper here: its gradient is computed and then masked.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from ptrl_jax.summary import curves_by_preset, fmt_number

PAPER_AVERAGE_SAVING = 0.20
"""Paper Table IV: training with transfer took about 20 % less time on average (Isaac Gym,
4096 envs, one RTX 4090). Its per-robot figures are not reproduced here."""

FIELDS = (
    "experiment", "source", "target", "transfer_preset", "seeds", "threshold",
    "scratch_final_reward", "transfer_final_reward",
    "scratch_steps_mean", "scratch_steps_std", "transfer_steps_mean", "transfer_steps_std",
    "scratch_wall_s_mean", "transfer_wall_s_mean",
    "steps_saved_mean", "steps_saved_std", "wall_saved_mean", "wall_saved_std",
    "seeds_both_reached",
)


def _first_reach(reward: np.ndarray, threshold: float) -> np.ndarray:
    """Per seed, the first iteration index with reward >= threshold (-1: never)."""
    reached = reward >= threshold
    return np.where(reached.any(axis=1), np.argmax(reached, axis=1), -1)


def _stats(values: Sequence[float]) -> tuple[float, float]:
    v = np.asarray([x for x in values if np.isfinite(x)], float)
    return (float(v.mean()), float(v.std())) if len(v) else (float("nan"), float("nan"))


def robot_row(
    experiment: str, source: str, target: str, rows: Sequence[Mapping[str, Any]], transfer_preset: str,
    threshold_fraction: float, final_window: int,
) -> dict[str, Any]:
    """One Table IV row from the target rows of one robot (both presets present)."""
    curves = curves_by_preset(rows)
    missing = [p for p in ("scratch", transfer_preset) if p not in curves]
    if missing:
        raise ValueError(f"{experiment} -> {target}: no metrics for preset(s) {missing} "
                         f"(Table IV needs 'scratch' and the transfer preset {transfer_preset!r})")
    scratch, transfer = curves["scratch"], curves[transfer_preset]
    final = {name: c["reward"][:, -final_window:].mean(axis=1) for name, c in
             (("scratch", scratch), ("transfer", transfer))}
    threshold = float(threshold_fraction * final["scratch"].mean())
    out = {"experiment": experiment, "source": source, "target": target, "transfer_preset": transfer_preset,
           "seeds": int(scratch["reward"].shape[0]), "threshold": threshold,
           "scratch_final_reward": float(final["scratch"].mean()),
           "transfer_final_reward": float(final["transfer"].mean())}
    firsts = {"scratch": _first_reach(scratch["reward"], threshold),
              "transfer": _first_reach(transfer["reward"], threshold)}
    per_seed = {}
    for name, c in (("scratch", scratch), ("transfer", transfer)):
        i = firsts[name]
        per_seed[f"{name}_steps"] = np.where(i >= 0, c["env_steps"][np.maximum(i, 0)], np.nan)
        per_seed[f"{name}_wall"] = np.where(i >= 0, c["wall_time_s"][np.maximum(i, 0)], np.nan)
    for name in ("scratch", "transfer"):
        out[f"{name}_steps_mean"], out[f"{name}_steps_std"] = _stats(per_seed[f"{name}_steps"])
        out[f"{name}_wall_s_mean"] = _stats(per_seed[f"{name}_wall"])[0]
    both = (firsts["scratch"] >= 0) & (firsts["transfer"] >= 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        steps_saved = 1.0 - per_seed["transfer_steps"] / per_seed["scratch_steps"]
        wall_saved = 1.0 - per_seed["transfer_wall"] / per_seed["scratch_wall"]
    out["steps_saved_mean"], out["steps_saved_std"] = _stats(np.where(both, steps_saved, np.nan))
    out["wall_saved_mean"], out["wall_saved_std"] = _stats(np.where(both, wall_saved, np.nan))
    out["seeds_both_reached"] = int(both.sum())
    return out


def experiment_rows(
    experiment: str, metrics: Sequence[Mapping[str, Any]], transfer_preset: str,
    threshold_fraction: float, final_window: int, source: str | None = None,
) -> list[dict[str, Any]]:
    """Table IV rows of one experiment's metrics.csv rows: one per target robot. ``source``
    names the source robot where the rows have no source stage (a ``source_checkpoint`` run)."""
    source = source or next((str(r["robot"]) for r in metrics if r["stage"] == "source"), "?")
    targets = list(dict.fromkeys(str(r["robot"]) for r in metrics if r["stage"] == "target"))
    return [robot_row(experiment, source, robot, [r for r in metrics if r["stage"] == "target" and r["robot"] == robot],
                      transfer_preset, threshold_fraction, final_window) for robot in targets]


def average_row(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The mean saving over robots (each robot's mean over seeds counts once)."""
    steps = [r["steps_saved_mean"] for r in rows]
    wall = [r["wall_saved_mean"] for r in rows]
    s_mean, s_std = _stats(steps)
    w_mean, w_std = _stats(wall)
    return {"experiment": "average", "target": f"{sum(np.isfinite(steps))} of {len(rows)} robots",
            "steps_saved_mean": s_mean, "steps_saved_std": s_std, "wall_saved_mean": w_mean, "wall_saved_std": w_std}


def format_markdown(rows: Sequence[Mapping[str, Any]], notes: Sequence[str] = ()) -> str:
    def f(v, fmt="{:.0f}"):
        return fmt_number(v, fmt)

    def pct(m, s):
        return "not reached" if not np.isfinite(m) else f"{100 * m:+.1f} % ± {100 * s:.1f}"

    lines = ["# Table IV: training to threshold with transfer and from scratch", ""]
    lines += [f"- {n}" for n in notes]
    lines += [
        "",
        "| source -> target | transfer preset | seeds | threshold | final reward scratch / transfer | "
        "env steps to threshold: scratch | transfer | wall s: scratch | transfer | "
        "steps saved (mean ± std) | wall time saved | seeds (both reached) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['source']} -> {r['target']} | {r['transfer_preset']} | {r['seeds']} | {f(r['threshold'], '{:.2f}')} | "
            f"{f(r['scratch_final_reward'], '{:.2f}')} / {f(r['transfer_final_reward'], '{:.2f}')} | "
            f"{f(r['scratch_steps_mean'])} ± {f(r['scratch_steps_std'])} | "
            f"{f(r['transfer_steps_mean'])} ± {f(r['transfer_steps_std'])} | "
            f"{f(r['scratch_wall_s_mean'], '{:.1f}')} | {f(r['transfer_wall_s_mean'], '{:.1f}')} | "
            f"{pct(r['steps_saved_mean'], r['steps_saved_std'])} | {pct(r['wall_saved_mean'], r['wall_saved_std'])} | "
            f"{r['seeds_both_reached']}/{r['seeds']} |"
        )
    avg = average_row(rows)
    lines += [
        "",
        f"**Average over {avg['target']}:** env steps saved {pct(avg['steps_saved_mean'], avg['steps_saved_std'])}, "
        f"wall time saved {pct(avg['wall_saved_mean'], avg['wall_saved_std'])} (± = spread over robots). "
        f"**Paper (Table IV):** about {100 * PAPER_AVERAGE_SAVING:.0f} % less training time on average "
        f"(Isaac Gym, 4096 envs, RTX 4090); its per-robot figures are not reproduced here.",
    ]
    return "\n".join(lines) + "\n"
