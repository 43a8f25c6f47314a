"""Everything a finished run writes into its folder: metrics.csv (one row per iteration per stage,
variant and seed), the checkpoints, curves, freeze-ratio plots, TensorBoard events and report.md
with its zero-shot section. Host-side, after the program has run; the walking check of the
zero-shot section is passed in (``checker``), so this module needs no simulator of its own."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable

import jax
import numpy as np

from ptrl_jax.config import ExperimentConfig
from ptrl_jax.core.freeze import TRANSFER_MODES, variant
from ptrl_jax.core.program import ProgramOutput, target_run_id
from ptrl_jax.io import artifacts, summary
from ptrl_jax.io.checkpoints import save_checkpoints
from ptrl_jax.io.tensorboard import write_events  # light: tensorboardX loads only when it writes


def metric_rows(
    cfg: ExperimentConfig, out: ProgramOutput, times: dict, stage_start: dict | None = None
) -> list[dict[str, Any]]:
    """One row per iteration per stage, preset and seed. ``wall_time_s`` counts from the start
    of that row's stage (the target stage starts when the source stage ends)."""
    stage_start = stage_start or {}
    rows = []
    skip = ("iteration", "env_steps")

    def add(stage, robot, preset, seed, run_id, metrics):
        n = len(metrics["iteration"])
        for i in range(n):
            it = int(metrics["iteration"][i])
            row = {
                "stage": stage, "robot": robot, "preset": preset, "seed": seed, "iteration": it,
                "env_steps": int(metrics["env_steps"][i]),
                "wall_time_s": times.get((stage, run_id, it), float("nan")) - stage_start.get(stage, 0.0),
            }
            row.update({k: float(v[i]) for k, v in metrics.items() if k not in skip})
            rows.append(row)

    src = jax.device_get(out.source_metrics)
    add("source", cfg.source.robot, "source", 0, 0, src)
    for k, robot in enumerate(cfg.targets):
        tgt = jax.device_get(out.target_metrics[robot])
        for p, preset in enumerate(cfg.variants):
            for s in range(cfg.seeds):
                add("target", robot, preset, s, target_run_id(cfg, k, p, s), jax.tree.map(lambda x: x[p, s], tgt))
    return rows


def save_outputs(
    cfg: ExperimentConfig, run_dir: Path, out: ProgramOutput, times: dict, extra_notes=(), stage_start=None,
    initial: dict | None = None, checker: Callable[[dict], list] | None = None,
    source_checker: Callable[[Path], list] | None = None,
) -> dict:
    """Every file of the run folder. ``source_checker(path) -> verdicts``, when given, checks the
    written ``source.npz`` (the family's walking check of the source policy) for the report's
    source line. ``initial``: ``Program.initial_weights`` of the final state,
    for the zero-shot walking checks (none without it), which ``checker(policy) -> verdicts``
    runs (``ptrl_jax.run`` passes the family's walking check in MuJoCo C)."""
    rows = metric_rows(cfg, out, times, stage_start)
    multi = len(cfg.targets) > 1  # several target robots: file names carry the robot
    artifacts.write_metrics_csv(run_dir / "metrics.csv", rows)
    if cfg.tensorboard:
        write_events(run_dir / "tensorboard", rows, start_time=time.time() - max(
            (float(r.get("wall_time_s", 0.0)) for r in rows), default=0.0))
    if cfg.checkpoint:
        save_checkpoints(cfg, run_dir, out)
    source_curve = [(r["env_steps"], r["episode_reward"]) for r in rows if r["stage"] == "source"]
    transfers = cfg.trains_source or bool(cfg.source_checkpoint)
    if cfg.init_checkpoint:
        source_note = f"Transferring variants start from {cfg.init_checkpoint} (init_checkpoint)"
    elif cfg.source_checkpoint:
        source_note = f"Source {cfg.source.robot}: loaded from {cfg.source_checkpoint} (not trained in this run)"
    elif not transfers:
        source_note = "No source: every variant trains from scratch (no transfer), so none was trained"
    else:
        src_final = np.mean([r for _, r in source_curve][-cfg.report.final_window:])
        source_note = (f"Source {cfg.source.robot}: {cfg.source.ppo.num_iterations} iterations x "
                       f"{cfg.source.ppo.env_steps_per_iteration} env steps, final mean episode reward {src_final:.3f}")
    if source_checker is not None and transfers and not cfg.init_checkpoint:
        if not cfg.checkpoint:
            source_note += "; its walking check not run (checkpoint=false: no source.npz to check)"
        else:
            try:
                source_note += "; " + format_source_checks(source_checker(run_dir / "source.npz"),
                                                           cfg.report.zero_shot_seconds)
            except Exception as e:  # the report and the checkpoints matter more than this line
                source_note += f"; its walking check failed to run ({type(e).__name__}: {e})"
    common = [
        source_note,
        f"Final reward = mean over the last {cfg.report.final_window} iterations; AUC = reward "
        f"integrated over env steps / steps (a mean reward over training); wall time counts from "
        f"the start of the target stage, all presets running together under vmap",
        *extra_notes,
    ]
    sections, tables = [], {}
    for robot in cfg.targets:
        robot_rows = [r for r in rows if r["stage"] == "source" or r["robot"] == robot]
        curves = summary.curves_by_preset(robot_rows, cfg.report.threshold_metric)
        table, threshold = summary.preset_summary(curves, cfg.report.threshold_fraction, cfg.report.final_window)
        route = f"{cfg.source.robot} -> {robot}" if transfers else f"{robot} from scratch"
        title = f"{cfg.name}: {route} ({cfg.scale})"
        png = f"curves_{robot}.png" if multi else "curves.png"
        summary.plot_curves(run_dir / png, curves, title, source_curve)
        notes = [f"Target {robot}: {cfg.target.ppo.num_iterations} iterations x "
                 f"{cfg.target.ppo.env_steps_per_iteration} env steps per run, {cfg.seeds} seed(s) per preset"]
        if multi:
            notes.append(f"All {len(cfg.targets)} target robots ran in the same program, one iteration "
                         f"each per step of the target loop; wall times are shared")
        text = summary.format_report(title, table, threshold, common[:1] + notes + common[1:], cfg.report.threshold_metric)
        for mode in TRANSFER_MODES:
            ratio_rows = summary.ratio_table(table, mode)
            if ratio_rows:
                stem = "freeze_ratio" + ("" if mode == "paper" else f"_{mode}")
                png = f"{stem}_{robot}.png" if multi else f"{stem}.png"
                scratch = next((r for r in table if r["preset"] == "scratch"), None)
                summary.plot_freeze_ratio(run_dir / png, ratio_rows, scratch, f"{title}, {mode} transfer")
                text += "\n" + summary.format_ratio_table(ratio_rows, png, mode)
        if transfers or cfg.init_checkpoint:
            zero = zero_shot_rows(cfg, robot, rows, None if initial is None else initial[robot], checker)
            text += "\n" + format_zero_shot(zero, cfg.report.zero_shot_seconds)
        sections.append(text)
        tables[robot] = (table, threshold)
    artifacts.atomic_write_text(run_dir / "report.md", "\n".join(sections))
    table, threshold = tables[cfg.target.robot]
    return {"rows": rows, "summary": table, "threshold": threshold,
            "summaries": {robot: t for robot, (t, _) in tables.items()}}


def zero_shot_rows(cfg: ExperimentConfig, robot: str, rows, initial: Any,
                   checker: Callable[[dict], list] | None = None) -> list[dict[str, Any]]:
    """Per distinct initialisation of ``robot``'s targets (scratch, paper, semantic, init
    checkpoint: the first variant of each): the first rollout's mean reward per env step over
    seeds (the policy before any update acted in it, with its exploration noise), and with
    ``initial`` (``Program.initial_weights`` of the robot) the family's walking check
    of seed 0's deterministic policy, run by ``checker(policy) -> verdicts`` (required with
    ``initial``)."""
    if initial is not None and checker is None:
        raise ValueError("zero_shot_rows: initial policies to check, but no checker")
    kinds = {}
    for p, name in enumerate(cfg.variants):
        kinds.setdefault(variant(name).mode_index, (p, name))
    out = []
    for mode, (p, name) in sorted(kinds.items()):
        first = [r["step_reward"] for r in rows if r["stage"] == "target" and r["robot"] == robot
                 and r["preset"] == name and r["iteration"] == 1]
        row = {"variant": name, "initialisation": ("checkpoint" if cfg.init_checkpoint and mode else
                                                    ("scratch", *TRANSFER_MODES)[mode]),
               "first_reward_mean": float(np.mean(first)), "first_reward_std": float(np.std(first)),
               "checks": None}
        if initial is not None:
            pick = lambda x: np.asarray(x[p, 0])  # noqa: E731
            stage = cfg.targets[robot]
            policy = {"robot": robot, "env": stage.env, "network": cfg.network,
                      "params": jax.tree.map(pick, initial.params),
                      "normalizer": jax.tree.map(pick, initial.normalizer),
                      "normalize_observations": stage.ppo.normalize_observations}
            row["checks"] = checker(policy)
        out.append(row)
    return out


def format_checks(verdicts: list[dict[str, Any]]) -> str:
    """One policy's walking-check verdicts on one line: per check, time survived, forward speed
    and pass or fail."""
    return "; ".join(f"{v['check']} vx {v['command'][0]:g}: {v['time_survived_s']:.1f} s, "
                     f"{v['mean_velocity'][0]:.2f} m/s, {'pass' if v['passed'] else 'fail'}" for v in verdicts)


def format_source_checks(verdicts: list[dict[str, Any]], seconds: float = 20.0) -> str:
    """The report's verdict on the source policy: whether it passes its family's walking check
    (a source that stands carries no gait to the target), with every check's line."""
    verdict = "passes" if all(v["passed"] for v in verdicts) else "FAILS"
    return (f"the source {verdict} its walking check (MuJoCo C, mean action, {seconds:g} s per command: "
            f"{format_checks(verdicts)})")


def format_zero_shot(rows: list[dict[str, Any]], seconds: float = 20.0) -> str:
    lines = ["## Zero-shot: the initialisations before any fine-tuning", "",
             "First rollout: mean reward per env step over seeds, sampled actions (the first iteration's "
             "rollout, before its update). Check: the family's walking check of seed 0's mean action "
             f"(MuJoCo C, {seconds:g} s per command; `python -m ptrl_jax.evaluate ckpt=... check=true`).", "",
             "| initialisation (variant) | first rollout, reward per step | walking check (survived, forward speed) |",
             "|---|---|---|"]
    for r in rows:
        checks = ("not run (report.zero_shot_check=false)" if r["checks"] is None
                  else format_checks(r["checks"]))
        lines.append(f"| {r['initialisation']} ({r['variant']}) | {r['first_reward_mean']:.4f} ± "
                     f"{r['first_reward_std']:.4f} | {checks} |")
    return "\n".join(lines) + "\n"
