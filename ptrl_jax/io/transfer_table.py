"""Paper Table IV from metrics: training time to a threshold with transfer and without.

Host-side only, pure functions of ``metrics.csv`` rows, so notebooks can rebuild the table
from finished runs. The rule, per target robot of an experiment:

- threshold = ``threshold_fraction`` x the scratch baseline's final value of the threshold
  metric (the episode reward, or the reward term ``report.threshold_metric`` names; mean over
  seeds of the mean over the last ``final_window`` iterations), the same rule as report.md;
- for every seed, the env steps and the target-stage wall time at the first iteration whose mean
  episode reward reaches it, for the scratch run and for the transfer run (``transfer_preset``);
- saved = 1 - transfer / scratch, per seed (seeds are paired: same initialisation of the
  non-transferred layers and same env stream), then mean and std over the seeds where both
  reached the threshold;
- the same for the semantic transfer (``ptrl_jax/core/semantic.py``): the variant named before the
  runs (``report.semantic_preset``, the preset rule; 'not run' where the runs lack it), or, where
  none is named, the best of the variants named ``<preset>@semantic[_actor|_input|_output]`` by
  mean env steps to the threshold, a choice made after the fact on the same seeds it is reported
  on. Each row names its variant and how it was chosen (``semantic_choice``).

In one program every variant runs in lockstep under ``vmap`` and shares one clock, so the wall
time of each run is the stage's time at that iteration, and the wall-time saving equals the
env-step saving up to the spread of iteration times. A frozen layer does not make an iteration
cheaper here: its gradient is computed and then masked.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from ptrl_jax.core.freeze import is_semantic
from ptrl_jax.io.summary import curves_by_preset, fmt_number

PAPER_AVERAGE_SAVING = 0.20
"""Paper Table IV: training with transfer took about 20 % less time on average (Isaac Gym,
4096 envs, one RTX 4090)."""

PAPER_HOURS: dict[str, tuple[float, float]] = {
    "xbot_l": (2.5, 3.0), "mit_humanoid": (8 / 60, 12 / 60), "cassie": (8 / 60, 11.5 / 60),
    "tron1": (3.0, 3.38), "go2": (1.5, 1.75), "a1": (8 / 60, 12 / 60),
    "anymal_b": (3 / 60, 3.3 / 60), "anymal_c": (3 / 60, 3.3 / 60),
}
"""Paper Table IV per target robot: (hours with transfer, hours without), 4096 envs on one RTX
4090; the paper gives no seeds, thresholds or env steps."""

NAMED_BEFORE = "named before the runs"
"""``semantic_choice`` of a row whose semantic variant ``report.semantic_preset`` named."""

FIELDS = (
    "experiment", "source", "target", "transfer_preset", "seeds", "threshold", "threshold_metric",
    "scratch_final_reward", "transfer_final_reward",
    "scratch_steps_mean", "scratch_steps_std", "transfer_steps_mean", "transfer_steps_std",
    "scratch_wall_s_mean", "transfer_wall_s_mean",
    "steps_saved_mean", "steps_saved_std", "wall_saved_mean", "wall_saved_std",
    "seeds_both_reached",
    "semantic_preset", "semantic_final_reward", "semantic_steps_mean", "semantic_steps_std",
    "semantic_wall_s_mean", "semantic_steps_saved_mean", "semantic_steps_saved_std",
    "semantic_wall_saved_mean", "semantic_wall_saved_std", "semantic_seeds_both_reached", "semantic_choice",
    "paper_hours_transfer", "paper_hours_scratch", "paper_saved",
)


def _first_reach(reward: np.ndarray, threshold: float) -> np.ndarray:
    """Per seed, the first iteration index with reward >= threshold (-1: never)."""
    reached = reward >= threshold
    return np.where(reached.any(axis=1), np.argmax(reached, axis=1), -1)


def _stats(values: Sequence[float]) -> tuple[float, float]:
    v = np.asarray([x for x in values if np.isfinite(x)], float)
    return (float(v.mean()), float(v.std())) if len(v) else (float("nan"), float("nan"))


def _time_to(curve: Mapping[str, np.ndarray], threshold: float) -> dict[str, np.ndarray]:
    """Per seed: env steps and wall time at the first iteration reaching ``threshold`` (NaN: never)."""
    i = _first_reach(curve["metric"], threshold)
    seeds = curve.get("seeds", np.arange(curve["metric"].shape[0]))
    return {"seeds": np.asarray(seeds, int),
            "steps": np.where(i >= 0, curve["env_steps"][np.maximum(i, 0)], np.nan),
            "wall": np.where(i >= 0, curve["wall_time_s"][np.maximum(i, 0)], np.nan)}


def _threshold(curves: Mapping[str, Mapping[str, np.ndarray]], threshold_fraction: float, final_window: int) -> float:
    """``threshold_fraction`` x scratch's final value of the metric (mean over its seeds of the
    last ``final_window`` iterations)."""
    return float(threshold_fraction * curves["scratch"]["metric"][:, -final_window:].mean())


def _compare(scratch: Mapping[str, np.ndarray], other: Mapping[str, np.ndarray]) -> dict[str, Any]:
    """Savings of ``other`` against ``scratch``, per paired seed (the seed ids both ran), over the
    seeds where both reached; ``other``'s own steps over all of its seeds."""
    _, i_s, i_o = np.intersect1d(scratch["seeds"], other["seeds"], return_indices=True)
    s_steps, o_steps = scratch["steps"][i_s], other["steps"][i_o]
    both = np.isfinite(s_steps) & np.isfinite(o_steps)
    with np.errstate(divide="ignore", invalid="ignore"):
        steps_saved = 1.0 - o_steps / s_steps
        wall_saved = 1.0 - other["wall"][i_o] / scratch["wall"][i_s]
    out = {}
    out["steps_mean"], out["steps_std"] = _stats(other["steps"])
    out["wall_s_mean"] = _stats(other["wall"])[0]
    out["steps_saved_mean"], out["steps_saved_std"] = _stats(np.where(both, steps_saved, np.nan))
    out["wall_saved_mean"], out["wall_saved_std"] = _stats(np.where(both, wall_saved, np.nan))
    out["seeds_both_reached"] = int(both.sum())
    return out


def _one_named(curves: Mapping[str, Any], name: str, key: str, experiment: str, target: str) -> str:
    """The variant of ``curves`` that ``name`` names: itself, or the one merged name that carries
    settings after it ("L2@semantic_actor [knee=flexion]", from runs with different transfer or
    source settings); ``name`` unchanged where none does. Several: refused, naming one to give."""
    if name in curves:
        return name
    found = [p for p in curves if p.startswith(name + " [")]
    if len(found) > 1:
        raise ValueError(f"{experiment} -> {target}: {key}={name!r} matches {len(found)} variants {found}; "
                         f"name one with its settings, {key}='{found[0]}' (runs with different transfer or "
                         f"source settings)")
    return found[0] if found else name


def robot_row(
    experiment: str, source: str, target: str, rows: Sequence[Mapping[str, Any]], transfer_preset: str,
    threshold_fraction: float, final_window: int, metric: str = "episode_reward", require_transfer: bool = True,
    semantic_preset: str = "",
) -> dict[str, Any]:
    """One Table IV row from the target rows of one robot (scratch and ``transfer_preset``
    present; the semantic columns are filled when a semantic variant ran, ``is_semantic``).
    ``metric``: the column whose curve reaches the threshold (``report.threshold_metric``).
    ``require_transfer=False``: a missing ``transfer_preset`` leaves the paper's columns empty
    (``transfer_ran`` False, shown as 'not run') instead of refusing the row. ``semantic_preset``:
    the semantic column's variant, named before the runs; empty: the best semantic variant."""
    curves = curves_by_preset(rows, metric)
    transfer_preset = _one_named(curves, transfer_preset, "transfer_preset", experiment, target)
    needed = ("scratch", transfer_preset) if require_transfer else ("scratch",)
    missing = [p for p in needed if p not in curves]
    if missing:
        raise ValueError(f"{experiment} -> {target}: no metrics for preset(s) {missing} "
                         f"(Table IV needs 'scratch'" + (f" and the transfer preset {transfer_preset!r})"
                                                         if require_transfer else ")"))
    final = {name: c["reward"][:, -final_window:].mean(axis=1) for name, c in curves.items()}
    threshold = _threshold(curves, threshold_fraction, final_window)
    ran = transfer_preset in curves
    out: dict[str, Any] = {
        "experiment": experiment, "source": source, "target": target, "transfer_preset": transfer_preset,
        "transfer_ran": ran,
        "seeds": int(curves["scratch"]["reward"].shape[0]), "threshold": threshold, "threshold_metric": metric,
        "scratch_final_reward": float(final["scratch"].mean()),
        "transfer_final_reward": float(final[transfer_preset].mean()) if ran else float("nan")}
    times = {name: _time_to(c, threshold) for name, c in curves.items()}
    out["scratch_steps_mean"], out["scratch_steps_std"] = _stats(times["scratch"]["steps"])
    out["scratch_wall_s_mean"] = _stats(times["scratch"]["wall"])[0]
    nan = float("nan")
    paper = (_compare(times["scratch"], times[transfer_preset]) if ran else
             {"steps_mean": nan, "steps_std": nan, "wall_s_mean": nan, "steps_saved_mean": nan,
              "steps_saved_std": nan, "wall_saved_mean": nan, "wall_saved_std": nan, "seeds_both_reached": 0})
    out.update({"transfer_steps_mean": paper["steps_mean"], "transfer_steps_std": paper["steps_std"],
                "transfer_wall_s_mean": paper["wall_s_mean"],
                **{k: paper[k] for k in ("steps_saved_mean", "steps_saved_std", "wall_saved_mean",
                                         "wall_saved_std", "seeds_both_reached")}})
    semantic = [p for p in curves if is_semantic(p)]
    choice = f"best of {len(semantic)} semantic variant(s), chosen after the runs"
    if semantic_preset:
        semantic_preset = _one_named(curves, semantic_preset, "semantic", experiment, target)
        semantic = [semantic_preset] if semantic_preset in curves else []
        choice = NAMED_BEFORE
        if not semantic:
            out.update({"semantic_choice": choice, "semantic_missing": semantic_preset})
    if semantic:
        def rank(p):  # fewest mean steps to threshold; a seed that never reaches counts as never
            steps = times[p]["steps"]
            return (int(np.isnan(steps).sum()), float(np.nanmean(steps)) if np.isfinite(steps).any() else np.inf)

        best = min(semantic, key=rank)
        sem = _compare(times["scratch"], times[best])
        out.update({"semantic_preset": best, "semantic_final_reward": float(final[best].mean()),
                    "semantic_choice": choice, **{f"semantic_{k}": v for k, v in sem.items()}})
    hours = PAPER_HOURS.get(target)
    if hours:
        out.update({"paper_hours_transfer": hours[0], "paper_hours_scratch": hours[1],
                    "paper_saved": 1.0 - hours[0] / hours[1]})
    return out


def experiment_rows(
    experiment: str, metrics: Sequence[Mapping[str, Any]], transfer_preset: str,
    threshold_fraction: float, final_window: int, source: str | None = None, metric: str = "episode_reward",
    semantic_preset: str = "",
) -> list[dict[str, Any]]:
    """Table IV rows of one experiment's metrics.csv rows: one per target robot. ``source``
    names the source robot where the rows have no source stage (a ``source_checkpoint`` run);
    ``semantic_preset``: as ``robot_row``."""
    source = source or next((str(r["robot"]) for r in metrics if r["stage"] == "source"), "?")
    targets = list(dict.fromkeys(str(r["robot"]) for r in metrics if r["stage"] == "target"))
    return [robot_row(experiment, source, robot, [r for r in metrics if r["stage"] == "target" and r["robot"] == robot],
                      transfer_preset, threshold_fraction, final_window, metric, semantic_preset=semantic_preset)
            for robot in targets]


def average_row(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The mean saving over robots (each robot's mean over seeds counts once), per transfer."""
    steps = [r["steps_saved_mean"] for r in rows]
    wall = [r["wall_saved_mean"] for r in rows]
    s_mean, s_std = _stats(steps)
    w_mean, w_std = _stats(wall)
    out = {"experiment": "average", "target": f"{int(sum(np.isfinite(steps)))} of {len(rows)} robots",
           "steps_saved_mean": s_mean, "steps_saved_std": s_std, "wall_saved_mean": w_mean, "wall_saved_std": w_std}
    sem = [r.get("semantic_steps_saved_mean", np.nan) for r in rows]
    if any(np.isfinite(sem)):
        out["semantic_steps_saved_mean"], out["semantic_steps_saved_std"] = _stats(sem)
        out["semantic_wall_saved_mean"], out["semantic_wall_saved_std"] = _stats(
            [r.get("semantic_wall_saved_mean", np.nan) for r in rows])
        out["semantic_robots"] = f"{sum(np.isfinite(sem))} of {len(rows)} robots"
    paper = [r.get("paper_saved", np.nan) for r in rows]
    if any(np.isfinite(paper)):
        out["paper_saved"] = _stats(paper)[0]
    return out


def format_markdown(rows: Sequence[Mapping[str, Any]], notes: Sequence[str] = ()) -> str:
    def f(v, fmt="{:.0f}"):
        return fmt_number(v, fmt)

    def pct(m, s):
        return "not reached" if not np.isfinite(m) else f"{100 * m:+.1f} % ± {100 * s:.1f}"

    def steps(m, s):
        return f"{f(m / 1e6, '{:.2f}')} ± {f(s / 1e6, '{:.2f}')} M" if np.isfinite(m) else "not reached"

    def hours(h):
        return f"{h:.2f} h" if h >= 1 else f"{60 * h:.1f} min"

    has_sem = any(r.get("semantic_choice") for r in rows)
    named = [r for r in rows if r.get("semantic_choice") == NAMED_BEFORE]
    lines = ["# Table IV: training to threshold with transfer and from scratch", ""]
    lines += [f"- {n}" for n in notes]
    head = ("| source -> target | seeds | threshold | scratch: env steps to threshold | paper transfer "
            "(preset): steps | saved | ")
    rule = "|---|---|---|---|---|---|"
    if has_sem:
        head += ("semantic transfer (preset named before the runs): steps | saved | " if len(named) == len(rows)
                 else "semantic transfer (preset; how chosen): steps | saved | ")
        rule += "---|---|"
    head += "final reward scratch / paper / semantic | wall s to threshold scratch / paper / semantic | paper's hours with / without (saved) |"
    rule += "---|---|---|"
    lines += ["", head, rule]
    for r in rows:
        sem = bool(r.get("semantic_preset"))
        how = "" if len(named) == len(rows) else f"; {r.get('semantic_choice', '')}"
        line = (f"| {r['source']} -> {r['target']} | {r['seeds']} | {f(r['threshold'], '{:.3g}')} | "
                f"{steps(r['scratch_steps_mean'], r['scratch_steps_std'])} | ")
        line += (f"{steps(r['transfer_steps_mean'], r['transfer_steps_std'])} ({r['transfer_preset']}) | "
                 f"{pct(r['steps_saved_mean'], r['steps_saved_std'])} ({r['seeds_both_reached']}/{r['seeds']}) | "
                 if r.get("transfer_ran", True) else f"not run ({r['transfer_preset']}) | | ")
        if has_sem:
            line += (f"{steps(r['semantic_steps_mean'], r['semantic_steps_std'])} ({r['semantic_preset']}{how}) | "
                     f"{pct(r['semantic_steps_saved_mean'], r['semantic_steps_saved_std'])} "
                     f"({r['semantic_seeds_both_reached']}/{r['seeds']}) | " if sem
                     else f"not run ({r['semantic_missing']}, {r['semantic_choice']}) | | " if r.get("semantic_missing")
                     else "not run | | ")
        line += (f"{f(r['scratch_final_reward'], '{:.2f}')} / {f(r['transfer_final_reward'], '{:.2f}')} / "
                 f"{f(r.get('semantic_final_reward', np.nan), '{:.2f}')} | "
                 f"{f(r['scratch_wall_s_mean'], '{:.0f}')} / {f(r['transfer_wall_s_mean'], '{:.0f}')} / "
                 f"{f(r.get('semantic_wall_s_mean', np.nan), '{:.0f}')} | ")
        line += (f"{hours(r['paper_hours_transfer'])} / {hours(r['paper_hours_scratch'])} "
                 f"({100 * r['paper_saved']:.0f} %) |" if r.get("paper_hours_scratch") else "|")
        lines.append(line)
    avg = average_row(rows)
    if any(r.get("transfer_ran", True) for r in rows):
        lines += [
            "",
            f"**Average over {avg['target']}:** env steps saved with the paper's transfer "
            f"{pct(avg['steps_saved_mean'], avg['steps_saved_std'])}, wall time "
            f"{pct(avg['wall_saved_mean'], avg['wall_saved_std'])} (± = spread over robots)."]
    else:
        lines += ["", f"**Average over {len(rows)} robots:** the paper's transfer did not run in these runs."]
    if "semantic_steps_saved_mean" in avg:
        lines.append(f"With the semantic transfer (over {avg['semantic_robots']}): env steps saved "
                     f"{pct(avg['semantic_steps_saved_mean'], avg['semantic_steps_saved_std'])}, wall time "
                     f"{pct(avg['semantic_wall_saved_mean'], avg['semantic_wall_saved_std'])}.")
    paper = f" ({100 * avg['paper_saved']:.0f} % over these robots' rows)" if "paper_saved" in avg else ""
    lines.append(f"**Paper (Table IV):** about {100 * PAPER_AVERAGE_SAVING:.0f} % less training time on "
                 f"average{paper} (Isaac Gym, 4096 envs, RTX 4090; hours, no seeds or env steps given).")
    return "\n".join(lines) + "\n"


VARIANT_FIELDS = ("source", "target", "preset", "seeds", "threshold", "threshold_metric", "steps_per_seed",
                  "steps_mean", "steps_std", "steps_saved_mean", "steps_saved_std", "seeds_both_reached",
                  "final_reward_mean", "final_reward_std")


def variant_rows(source: str, target: str, rows: Sequence[Mapping[str, Any]], threshold_fraction: float,
                 final_window: int, metric: str = "episode_reward") -> list[dict[str, Any]]:
    """Every variant of one robot's target rows against its scratch baseline (the threshold rule of
    ``robot_row``): env steps to the threshold per seed (NaN: never), their mean and std, the
    saving per paired seed, and the final reward. Scratch first, then the variants by name."""
    curves = curves_by_preset(rows, metric)
    if "scratch" not in curves:
        raise ValueError(f"{source} -> {target}: no metrics for preset 'scratch' (the baseline every saving is "
                         f"measured against); presets present: {sorted(curves)}")
    threshold = _threshold(curves, threshold_fraction, final_window)
    times = {name: _time_to(c, threshold) for name, c in curves.items()}
    out = []
    for name in ["scratch"] + sorted(p for p in curves if p != "scratch"):
        final = curves[name]["reward"][:, -final_window:].mean(axis=1)
        cmp = _compare(times["scratch"], times[name])
        out.append({"source": source, "target": target, "preset": name, "seeds": int(final.shape[0]),
                    "threshold": threshold, "threshold_metric": metric,
                    "steps_per_seed": [float(x) for x in times[name]["steps"]],
                    "steps_mean": cmp["steps_mean"], "steps_std": cmp["steps_std"],
                    "steps_saved_mean": cmp["steps_saved_mean"] if name != "scratch" else float("nan"),
                    "steps_saved_std": cmp["steps_saved_std"] if name != "scratch" else float("nan"),
                    "seeds_both_reached": cmp["seeds_both_reached"],
                    "final_reward_mean": float(final.mean()), "final_reward_std": float(final.std())})
    return out


def format_variants(rows: Sequence[Mapping[str, Any]]) -> str:
    """A markdown table of ``variant_rows`` (one robot pair)."""
    if not rows:
        return ""
    first = rows[0]

    def m(v):
        return "never" if not np.isfinite(v) else f"{v / 1e6:.2f}"

    lines = [f"## {first['source']} -> {first['target']}: every variant", "",
             f"Threshold {first['threshold']:.4g} ({first['threshold_metric']}); env steps in millions, per seed "
             "in the seeds' order; saved = 1 - variant / scratch per paired seed, mean ± std over the seeds "
             "where both reached it.", "",
             "| variant | seeds | env steps to threshold, per seed | mean ± std | saved | final reward |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        saved = ("-" if r["preset"] == "scratch" else
                 "not reached" if not np.isfinite(r["steps_saved_mean"]) else
                 f"{100 * r['steps_saved_mean']:+.1f} % ± {100 * r['steps_saved_std']:.1f} "
                 f"({r['seeds_both_reached']}/{r['seeds']})")
        lines.append(f"| {r['preset']} | {r['seeds']} | {', '.join(m(x) for x in r['steps_per_seed'])} | "
                     f"{_millions(r['steps_mean'], r['steps_std'])} | "
                     f"{saved} | {r['final_reward_mean']:.2f} ± {r['final_reward_std']:.2f} |")
    return "\n".join(lines) + "\n"


def ratio_curves(variants: Sequence[Mapping[str, Any]], actor_hidden: tuple[int, ...] = (512, 256, 128)
                 ) -> list[dict[str, Any]]:
    """The freeze-ratio curves in one robot pair's ``variant_rows``: per transfer mode (and merged
    settings label, ``"... [k=v]"``) that holds a ``rho<r>`` variant, that mode's variants with
    their frozen share of L1 and L2 (``freeze.frozen_share``: ``rho<r>`` at r, 'L2' at 0.20, 'L1'
    at 0.80 for the paper's sizes, 'none' at 0 and 'L1+L2' at 1), sorted by it:
    ``[{"mode", "label", "points": [{**variant row, "share", "ratio": bool}]}]``, where ``ratio``
    is False for a whole-layer preset. Scratch stays out (it is every curve's baseline)."""
    from ptrl_jax.core.freeze import MODE_SEPARATOR, RATIO_PREFIX, frozen_share, variant

    series: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in variants:
        name, _, label = str(r["preset"]).partition(" [")
        base, _, mode = name.partition(MODE_SEPARATOR)
        preset = variant(name)
        if not preset.transfer:
            continue
        point = {**r, "share": frozen_share(preset, actor_hidden), "ratio": base.startswith(RATIO_PREFIX)}
        series.setdefault((mode or "paper", label.rstrip("]")), []).append(point)
    return [{"mode": mode, "label": label, "points": sorted(points, key=lambda p: (p["share"], not p["ratio"]))}
            for (mode, label), points in series.items() if any(p["ratio"] for p in points)]


def format_ratio_curves(curves: Sequence[Mapping[str, Any]], scratch: Mapping[str, Any], png: Sequence[str] = ()) -> str:
    """Markdown of ``ratio_curves`` for one robot pair: per curve, each variant's frozen share of
    L1 and L2, env steps to the threshold and saving against ``scratch`` (its variant row), and
    final reward; ``png``: the figure file of each curve, linked above its table."""
    out = []
    for k, c in enumerate(curves):
        lines = [f"## {scratch['source']} -> {scratch['target']}: freeze ratio, {c['mode']} transfer"
                 + (f" [{c['label']}]" if c["label"] else ""), ""]
        if k < len(png):
            lines += [f"![freeze ratio]({png[k]})", ""]
        lines += [f"Frozen share of L1's and L2's parameters; threshold {scratch['threshold']:.4g} ({scratch['threshold_metric']}); "
                  f"scratch: {_millions(scratch['steps_mean'], scratch['steps_std'])}, final reward "
                  f"{scratch['final_reward_mean']:.2f}.", "",
                  "| variant | frozen share | env steps to threshold | saved | final reward |", "|---|---|---|---|---|"]
        for p in c["points"]:
            saved = ("not reached" if not np.isfinite(p["steps_saved_mean"]) else
                     f"{100 * p['steps_saved_mean']:+.1f} % ± {100 * p['steps_saved_std']:.1f} ({p['seeds_both_reached']}/{p['seeds']})")
            lines.append(f"| {p['preset']} | {p['share']:.2f} | {_millions(p['steps_mean'], p['steps_std'])} | {saved} | "
                         f"{p['final_reward_mean']:.2f} ± {p['final_reward_std']:.2f} |")
        out.append("\n".join(lines) + "\n")
    return "\n".join(out)


def _millions(mean: float, std: float) -> str:
    return f"{mean / 1e6:.2f} ± {std / 1e6:.2f} M" if np.isfinite(mean) else "not reached"
