"""Turn per-iteration metrics into curves and a report (paper Fig. 5 style). Host-side only."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np


def fmt_number(v: Any, fmt: str = "{:.3f}") -> str:
    """A number for a markdown table; None and NaN read 'n/a'."""
    return "n/a" if v is None or (isinstance(v, float) and not np.isfinite(v)) else fmt.format(v)


def curves_by_preset(rows: Sequence[Mapping[str, Any]], metric: str = "episode_reward") -> dict[str, dict[str, np.ndarray]]:
    """{preset: {"seeds": [S] (the seed ids, sorted; rows of the arrays below), "env_steps": [T],
    "wall_time_s": [T], "reward": [S, T], "metric": [S, T]}}
    for target rows: "reward" is the episode reward, "metric" the column that time-to-threshold
    reads (``metric``: the episode reward itself, or one of its logged terms such as
    ``episode_reward/tracking_lin_vel``)."""
    grouped: dict[str, dict[int, list]] = defaultdict(lambda: defaultdict(list))
    for r in rows:
        if r["stage"] != "target":
            continue
        grouped[r["preset"]][int(r["seed"])].append(r)
    out = {}
    for preset, seeds in grouped.items():
        runs = [sorted(v, key=lambda r: r["iteration"]) for _, v in sorted(seeds.items())]
        out[preset] = {
            "seeds": np.array(sorted(int(k) for k in seeds), int),
            "env_steps": np.array([r["env_steps"] for r in runs[0]], float),
            "wall_time_s": np.array([r["wall_time_s"] for r in runs[0]], float),
            "reward": np.array([[r["episode_reward"] for r in run] for run in runs], float),
            "metric": np.array([[r[metric] for r in run] for run in runs], float),
        }
    return out


def preset_summary(
    curves: Mapping[str, Mapping[str, np.ndarray]], threshold_fraction: float, final_window: int
) -> tuple[list[dict[str, Any]], float | None]:
    """Per preset: final reward, normalised area under the curve, time and steps to threshold.

    The threshold is ``threshold_fraction`` x the scratch baseline's final value of the curves'
    "metric" (the episode reward unless another was chosen; without a scratch run, of the best
    preset's). Seeds that never reach it count as not reached.
    """
    finals = {p: c["reward"][:, -final_window:].mean(axis=1) for p, c in curves.items()}
    metric_finals = {p: c["metric"][:, -final_window:].mean(axis=1) for p, c in curves.items()}
    reference = "scratch" if "scratch" in curves else max(finals, key=lambda p: finals[p].mean())
    threshold = float(threshold_fraction * metric_finals[reference].mean()) if curves else None
    rows = []
    for preset, c in curves.items():
        reward = c["reward"]
        steps, wall = c["env_steps"], c["wall_time_s"]
        auc = np.trapezoid(reward, steps, axis=1) / max(steps[-1] - steps[0], 1.0) if len(steps) > 1 else reward[:, 0]
        reached = c["metric"] >= threshold
        first = [int(np.argmax(r)) if r.any() else None for r in reached]
        t_steps = [steps[i] if i is not None else np.nan for i in first]
        t_wall = [wall[i] if i is not None else np.nan for i in first]
        rows.append(
            {
                "preset": preset,
                "seeds": reward.shape[0],
                "final_reward_mean": float(finals[preset].mean()),
                "final_reward_std": float(finals[preset].std()),
                "auc_mean": float(np.mean(auc)),
                "auc_std": float(np.std(auc)),
                "steps_to_threshold_mean": float(np.nanmean(t_steps)) if not np.all(np.isnan(t_steps)) else None,
                "steps_to_threshold_std": float(np.nanstd(t_steps)) if not np.all(np.isnan(t_steps)) else None,
                "wall_s_to_threshold_mean": float(np.nanmean(t_wall)) if not np.all(np.isnan(t_wall)) else None,
                "seeds_reaching_threshold": int(sum(i is not None for i in first)),
            }
        )
    return rows, threshold


def ratio_table(summary: Sequence[Mapping[str, Any]], mode: str = "paper") -> list[dict[str, Any]]:
    """The freeze-ratio variants (``rho<r>``, or ``rho<r>@semantic`` for ``mode='semantic'``)
    of a preset summary, with ``rho``, sorted by it. The presets 'none' and 'L1+L2' (of the same
    mode) are the ends rho = 0 and rho = 1 (the same masks), and stand in for them when the sweep
    does not list them itself. Empty without any ratio variant of that mode."""
    from ptrl_jax.core.freeze import MODE_SEPARATOR, RATIO_PREFIX

    suffix = "" if mode == "paper" else MODE_SEPARATOR + mode

    def of_mode(name: str) -> str | None:
        base, sep, m = name.partition(MODE_SEPARATOR)
        return base if (sep + m) == suffix else None

    rows = [{**r, "rho": float(of_mode(r["preset"])[len(RATIO_PREFIX):])} for r in summary
            if of_mode(r["preset"]) is not None and of_mode(r["preset"]).startswith(RATIO_PREFIX)]
    if not rows:
        return []
    for rho, preset in ((0.0, "none" + suffix), (1.0, "L1+L2" + suffix)):
        end = next((r for r in summary if r["preset"] == preset), None)
        if end is not None and all(r["rho"] != rho for r in rows):
            rows.append({**end, "rho": rho})
    return sorted(rows, key=lambda r: r["rho"])


def plot_freeze_ratio(path: Path, rows: Sequence[Mapping[str, Any]], scratch: Mapping[str, Any] | None,
                      title: str) -> None:
    """Final reward, AUC and env steps to threshold against the freeze ratio rho (mean and std
    over seeds); the scratch baseline as a dashed line."""
    from matplotlib.figure import Figure  # no pyplot: leaves a notebook's backend alone

    rho = np.array([r["rho"] for r in rows])
    panels = [("final_reward", "final episode reward"), ("auc", "AUC (mean reward over training)"),
              ("steps_to_threshold", "env steps to threshold")]
    fig = Figure(figsize=(13, 3.8))
    axes = fig.subplots(1, 3)
    for ax, (key, label) in zip(axes, panels):
        mean = np.array([np.nan if r[f"{key}_mean"] is None else r[f"{key}_mean"] for r in rows], float)
        std = np.array([np.nan if r[f"{key}_std"] is None else r[f"{key}_std"] for r in rows], float)
        ax.errorbar(rho, mean, yerr=std, marker="o", capsize=3, label="transfer, freeze ratio rho")
        if scratch is not None and scratch.get(f"{key}_mean") is not None:
            ax.axhline(scratch[f"{key}_mean"], color="k", ls="--", lw=1, label="scratch")
        ax.set_xlabel("freeze ratio rho (frozen share of L1, L2)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def format_ratio_table(rows: Sequence[Mapping[str, Any]], png: str, mode: str = "paper") -> str:
    title = "## Freeze ratio" + ("" if mode == "paper" else f" ({mode} transfer)")
    lines = [title, "", f"![freeze ratio]({png})", "",
             "| rho | final reward (mean ± std) | AUC (mean ± std) | env steps to threshold (mean ± std) | seeds reaching |",
             "|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['rho']:g}{'' if r['preset'].startswith('rho') else ' (' + r['preset'].split('@')[0] + ')'} | {fmt_number(r['final_reward_mean'])} ± {fmt_number(r['final_reward_std'])} | "
            f"{fmt_number(r['auc_mean'])} ± {fmt_number(r['auc_std'])} | {fmt_number(r['steps_to_threshold_mean'], '{:.0f}')} ± "
            f"{fmt_number(r['steps_to_threshold_std'], '{:.0f}')} | {r['seeds_reaching_threshold']}/{r['seeds']} |"
        )
    return "\n".join(lines) + "\n"


def plot_curves(
    path: Path, curves: Mapping[str, Mapping[str, np.ndarray]], title: str, source_curve=()
) -> list:
    """Target reward per preset (mean and spread over seeds), and the source curve beside it.
    Without a source curve (a loaded source, or scratch only) the target panel stands alone.
    Returns the figure's axes (the target's last)."""
    from matplotlib.figure import Figure  # no pyplot: leaves a notebook's backend alone

    if source_curve:
        fig = Figure(figsize=(11, 4.2))
        ax_src, ax = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1, 1.6]})
        xs, ys = zip(*source_curve)
        ax_src.plot(np.array(xs) / 1e6, ys, color="k")
        ax_src.set_xlabel("source env steps (millions)")
        ax_src.set_ylabel("mean episode reward")
        ax_src.set_title("source (SLRT)")
        ax_src.grid(alpha=0.3)
    else:
        fig = Figure(figsize=(7, 4.2))
        ax = fig.subplots()
    for preset, c in curves.items():
        x = c["env_steps"] / 1e6
        mean, std = c["reward"].mean(axis=0), c["reward"].std(axis=0)
        style = "--" if preset == "scratch" else "-"
        ax.plot(x, mean, style, label=preset)
        ax.fill_between(x, mean - std, mean + std, alpha=0.2)
    ax.set_xlabel("target env steps (millions)")
    ax.set_ylabel("mean episode reward")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(title="freeze preset")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return fig.axes


def format_report(
    title: str, summary: Sequence[Mapping[str, Any]], threshold: float | None, notes: Sequence[str],
    metric: str = "episode_reward",
) -> str:
    lines = [f"# {title}", ""]
    lines += [f"- {n}" for n in notes]
    lines += [
        f"- Threshold for 'time to threshold': {fmt_number(threshold)} ({metric})",
        "",
        "| preset | seeds | final reward (mean ± std) | AUC (mean ± std) | env steps to threshold | wall s to threshold | seeds reaching |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in summary:
        lines.append(
            f"| {r['preset']} | {r['seeds']} | {fmt_number(r['final_reward_mean'])} ± {fmt_number(r['final_reward_std'])} | "
            f"{fmt_number(r['auc_mean'])} ± {fmt_number(r['auc_std'])} | {fmt_number(r['steps_to_threshold_mean'], '{:.0f}')} | "
            f"{fmt_number(r['wall_s_to_threshold_mean'], '{:.1f}')} | {r['seeds_reaching_threshold']}/{r['seeds']} |"
        )
    return "\n".join(lines) + "\n"
