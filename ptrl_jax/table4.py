"""Table IV from finished runs, several programs merged: time to threshold per variant and seed.

    python -m ptrl_jax.table4 runs=[runs/go2_to_anymal_b/<stamp>,runs/go2_to_anymal_b_axis/<stamp>]
    python -m ptrl_jax.table4 runs=[...] metric=step_reward/tracking_lin_vel out=docs/results/anymal_b

A variant that ran in another program (a control with another ``transfer.knee``, a second seed
root, a freeze-ratio sweep on the same source) is compared with the scratch runs of the first,
seed by seed. That pairing holds because every program gives seed ``k`` of seed root ``seed``
the same keys whatever variants it holds (``ptrl_jax.core.program``). Runs are grouped by
(source robot, target robot); within a group:

- every run must train its target with the same settings (``target.ppo`` and ``target.env``),
  or the steps to a threshold would not be comparable; a difference is refused, naming the key
  (a key that an older run's config lacks is not compared: it came later, with a default that
  keeps the old behaviour);
- seeds are labelled by (seed root, index), so seed 0 of ``seed=1`` is a seed of its own;
- where the runs' transfer settings (``transfer.*``) differ, each semantic variant's name gets
  the settings that differ (``L2@semantic_actor [knee=axis]``); a transferring variant (the
  paper's included) that ran from sources trained with different settings (``source.*``) gets
  those too (``L2@semantic_output [source.ppo.num_iterations=1400]``: one target stage, two
  sources). A source loaded from another run's ``source.npz`` has that run's settings where its
  folder is still there, else the loading run's config's. The same variant and seed in two runs
  is refused, naming both;
- the threshold is ``fraction`` x the mean over every scratch seed of the last ``window``
  iterations of ``metric`` (report.md's rule).

It prints the Table IV rows (``ptrl_jax.io.transfer_table``; the paper's transfer shows 'not
run' unless ``transfer_preset`` ran) and a table of every variant. Wall times come from
different programs, sharing the cores with whatever else ran, so compare env steps. ``out=DIR``
writes table4.md, table4.csv and variants.csv there (a folder that holds them is refused unless
``overwrite=true``). Where a pair holds freeze-ratio variants (``rho<r>``, of any transfer mode),
the tables gain that mode's curve: each of its variants at its frozen share of L1 and L2 (whole
layers included: 'L2' at 0.20), and ``out=`` draws it, freeze_ratio_<source>_<target>_<mode>.png.
Keys: ``runs``, ``metric`` (default: the first run's
``report.threshold_metric``), ``fraction`` and ``window`` (likewise), ``transfer_preset`` (L2),
``semantic`` (the semantic column's variant, named before the runs: default the first run's
``report.semantic_preset``; ``semantic=best`` takes the best semantic variant, chosen after the
runs; a merged name with its settings, ``semantic="L2@semantic_output [source.ppo.num_iterations=1400]"``,
picks one of several; ``transfer_preset`` likewise), ``out``, ``overwrite``.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, Mapping, Sequence

import yaml

from ptrl_jax.config import ReportConfig, TransferConfig
from ptrl_jax.core.freeze import is_semantic, variant
from ptrl_jax.io import artifacts, figures, transfer_table
from ptrl_jax.io.overrides import ConfigError, coerce, flatten, parse_known_cli, to_dict

KEYS = ("runs", "metric", "fraction", "window", "transfer_preset", "semantic", "out", "overwrite")
OUTPUTS = ("table4.md", "table4.csv", "variants.csv")


def read_run(run_dir: Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """A finished run's config.yaml (as a dict) and metrics.csv rows; a folder without them is
    refused, naming what is missing."""
    run_dir = Path(run_dir)
    missing = [n for n in ("config.yaml", "metrics.csv") if not (run_dir / n).is_file()]
    if missing:
        raise ConfigError(f"runs: {run_dir} has no {' or '.join(missing)} (is it a finished run folder?)")
    with open(run_dir / "config.yaml") as f:
        cfg = yaml.safe_load(f) or {}
    return cfg, artifacts.read_metrics_csv(run_dir / "metrics.csv")


# ``transfer.*`` defaults as a run's config.yaml writes them.
TRANSFER_DEFAULTS = flatten(to_dict(TransferConfig()), "transfer.")


def _target_settings(cfg: Mapping[str, Any], robot: str) -> dict[str, Any]:
    """The settings a target stage trains with: target.ppo and target.env (the first target; an
    extra target robot trains with target.ppo and its registry env, named by robot)."""
    target = cfg.get("target", {})
    if target.get("robot") == robot:
        return flatten({"ppo": target.get("ppo", {}), "env": target.get("env", {})}, "target.")
    return flatten({"ppo": target.get("ppo", {})}, "target.") | {"target.env": f"registry default of {robot}"}


def _source_of(run_dir: Path, cfg: Mapping[str, Any]) -> str:
    ckpt = cfg.get("source_checkpoint") or ""
    return f"loaded from {ckpt}" if ckpt else f"trained in {run_dir}"


def transfers(name: str) -> bool:
    """Whether the variant ``name`` starts from the source (every variant but scratch)."""
    return variant(name).transfer


def source_settings(cfg: Mapping[str, Any], _depth: int = 0) -> dict[str, Any]:
    """The settings a run's source was trained with, flat (``source.ppo.num_iterations``, ...):
    its config's ``source`` section, or, where it loaded the ``source.npz`` of another run folder
    that is still there, that run's (followed through its own loads)."""
    ckpt = str(cfg.get("source_checkpoint") or "")
    origin = Path(ckpt).parent / "config.yaml"
    if ckpt and Path(ckpt).name == "source.npz" and origin.is_file() and _depth < 8:
        with open(origin) as f:
            first = yaml.safe_load(f) or {}
        if first.get("source", {}).get("robot") == cfg.get("source", {}).get("robot"):
            return source_settings(first, _depth + 1)
    return flatten(cfg.get("source", {}), "source.")


def merge_runs(runs: Sequence[tuple[Path, Mapping[str, Any], Sequence[Mapping[str, Any]]]]
               ) -> dict[tuple[str, str], dict[str, Any]]:
    """{(source robot, target robot): {"rows": merged target rows, "seeds": [(run, root, index)],
    "notes": [...]}} from ``(run_dir, config dict, metrics rows)`` triples; see the module doc."""
    groups: dict[tuple[str, str], dict[str, Any]] = {}
    for run_dir, cfg, rows in runs:
        source = str(cfg.get("source", {}).get("robot", "?"))
        targets = list(dict.fromkeys(str(r["robot"]) for r in rows if r["stage"] == "target"))
        if not targets:
            raise ConfigError(f"runs: {run_dir} has no target rows in its metrics.csv")
        for robot in targets:
            g = groups.setdefault((source, robot), {"rows": [], "settings": None, "transfer": [], "source": []})
            settings = _target_settings(cfg, robot)
            if g["settings"] is None:
                g["settings"], g["settings_run"] = settings, run_dir
            else:
                # A key one config lacks was added to the project after that run, with a default
                # that keeps the old behaviour: only keys both configs hold are compared.
                differ = sorted(k for k in set(settings) & set(g["settings"])
                                if settings[k] != g["settings"][k])
                if differ:
                    k = differ[0]
                    raise ConfigError(
                        f"runs: {run_dir} and {g['settings_run']} train {robot} differently ({k}: "
                        f"{settings.get(k)!r} against {g['settings'].get(k)!r}"
                        + (f", and {len(differ) - 1} more key(s)" if len(differ) > 1 else "")
                        + "), so their steps to a threshold are not comparable")
            # A key an older run's config lacks came later, with a default that keeps the old behaviour.
            g["transfer"].append({**TRANSFER_DEFAULTS, **flatten(cfg.get("transfer", {}), "transfer.")})
            g["source"].append(source_settings(cfg))
            g["rows"].append((run_dir, cfg, [r for r in rows if r["stage"] == "target" and str(r["robot"]) == robot]))
    out = {}
    for key, g in groups.items():
        # The transfer settings that differ between the runs name the semantic variants.
        keys = sorted({k for t in g["transfer"] for k in t})
        varying = [k for k in keys if len({repr(t.get(k)) for t in g["transfer"]}) > 1]
        # Source settings are compared between the runs that transfer from a source, where each
        # config gives them (an older run may lack a key); a variant is labelled with them only
        # where it ran from more than one source setting.
        sources = [s for (_, cfg, rows), s in zip(g["rows"], g["source"])
                   if not cfg.get("init_checkpoint") and any(transfers(str(r["preset"])) for r in rows)]
        shared = set.intersection(*(set(s) for s in sources)) if sources else set()
        source_varying = [k for k in sorted(shared) if len({repr(s[k]) for s in sources}) > 1]
        transfer_label = {}  # (run index, variant) -> name with the differing transfer settings
        from_sources: dict[str, set] = {}  # that name -> the source settings it ran from
        for i, ((_, cfg, rows), tcfg, scfg) in enumerate(zip(g["rows"], g["transfer"], g["source"])):
            suffix = ", ".join(f"{k.split('.', 1)[1]}={tcfg.get(k)}" for k in varying)
            for name in dict.fromkeys(str(r["preset"]) for r in rows):
                label = f"{name} [{suffix}]" if suffix and is_semantic(name) else name
                transfer_label[(i, name)] = label
                if transfers(name) and not cfg.get("init_checkpoint"):
                    from_sources.setdefault(label, set()).add(tuple(repr(scfg.get(k)) for k in source_varying))
        seen: dict[tuple[str, tuple[int, int]], Path] = {}
        seed_ids: dict[tuple[int, int], int] = {}
        merged = []
        for i, ((run_dir, cfg, rows), scfg) in enumerate(zip(g["rows"], g["source"])):
            root = int(cfg.get("seed", 0))
            source_parts = ", ".join(f"{k}={scfg.get(k)}" for k in source_varying)
            for r in rows:
                label = transfer_label[(i, str(r["preset"]))]
                if len(from_sources.get(label, ())) > 1:
                    label = f"{label[:-1]}, {source_parts}]" if label.endswith("]") else f"{label} [{source_parts}]"
                seed = (root, int(r["seed"]))
                if (label, seed) in seen and seen[(label, seed)] != run_dir:
                    raise ConfigError(f"runs: {label!r} seed {seed[1]} of seed root {root} is in both "
                                      f"{seen[(label, seed)]} and {run_dir}; give each run once")
                seen[(label, seed)] = run_dir
                sid = seed_ids.setdefault(seed, len(seed_ids))
                merged.append({**r, "preset": label, "seed": sid})
        notes = [f"{run_dir}: seed root {int(cfg.get('seed', 0))}, {cfg.get('seeds', 1)} seed(s), variants "
                 f"{sorted({str(r['preset']) for r in rows})}; source {_source_of(run_dir, cfg)}"
                 for run_dir, cfg, rows in g["rows"]]
        order = sorted(seed_ids, key=seed_ids.get)
        notes.append("seeds, in the tables' order (seed root, index): " + ", ".join(f"({a}, {b})" for a, b in order))
        out[key] = {"rows": merged, "notes": notes, "seeds": order}
    return out


def build(run_dirs: Sequence[Path], metric: str | None = None, fraction: float | None = None,
          window: int | None = None, transfer_preset: str = "L2", semantic: str | None = None) -> dict[str, Any]:
    """The merged tables of ``run_dirs``: {"table": Table IV rows, "variants": every variant's
    rows, "notes": [...], "markdown": str}. ``semantic``: the semantic column's variant (None: the
    first run's ``report.semantic_preset``; ``best``: the best semantic variant)."""
    if not run_dirs:
        raise ConfigError("runs=[DIR,...]: name at least one finished run folder")
    runs = [(Path(d), *read_run(Path(d))) for d in run_dirs]
    report = runs[0][1].get("report", {})
    metric = metric or str(report.get("threshold_metric", "episode_reward"))
    fraction = float(fraction if fraction is not None else report.get("threshold_fraction", 0.9))
    window = int(window if window is not None else report.get("final_window", 10))
    semantic = str(report.get("semantic_preset", "") if semantic is None else semantic)
    semantic = "" if semantic == "best" else semantic
    if semantic:
        try:  # a merged name carries its differing settings after the variant: "<variant> [k=v, ...]"
            ReportConfig(semantic_preset=semantic.split(" [", 1)[0])
        except ValueError as e:
            raise ConfigError(f"semantic={semantic!r}: {e}") from None
    for run_dir, _, rows in runs:
        if rows and metric not in rows[0]:
            raise ConfigError(f"metric={metric!r}: {run_dir}/metrics.csv has no such column")
    table, variants, notes = [], [], [
        f"Threshold: {fraction:g} x scratch's final {metric} (mean over its seeds of the last {window} iterations)",
        "Wall times come from separate programs that may have shared the cores: compare env steps",
        (f"Semantic column: {semantic}, named before the runs (report.semantic_preset, or semantic=)" if semantic else
         "Semantic column: each row's best semantic variant, chosen after the runs on the seeds it reports")]
    experiment = "+".join(sorted({d.parent.name for d, _, _ in runs}))
    hidden = tuple(runs[0][1].get("network", {}).get("actor_hidden", (512, 256, 128)))
    ratios = []  # per pair: (scratch's variant row, its freeze-ratio curves, their figure names)
    for (source, target), g in merge_runs(runs).items():
        try:
            table.append(transfer_table.robot_row(experiment, source, target, g["rows"], transfer_preset, fraction, window, metric,
                                                  require_transfer=False, semantic_preset=semantic))
            variants.append(transfer_table.variant_rows(source, target, g["rows"], fraction, window, metric))
        except ValueError as e:
            raise ConfigError(f"runs: {e}") from None
        curves = transfer_table.ratio_curves(variants[-1], hidden)
        if curves:
            ratios.append((variants[-1][0], curves, [ratio_figure_name(source, target, c, k) for k, c in enumerate(curves)]))
        notes += [f"{source} -> {target}: {n}" for n in g["notes"]]
    head = transfer_table.format_markdown(table, notes) + "".join("\n" + transfer_table.format_variants(v)
                                                                 for v in variants)

    def with_ratios(figures: bool) -> str:
        return head + "".join("\n" + transfer_table.format_ratio_curves(c, scratch, png if figures else ())
                              for scratch, c, png in ratios)

    return {"table": table, "variants": variants, "notes": notes, "ratios": ratios, "markdown": with_ratios(False),
            "markdown_with_figures": with_ratios(True)}


def ratio_figure_name(source: str, target: str, curve: Mapping[str, Any], index: int) -> str:
    """The file ``out=`` writes a freeze-ratio curve to: freeze_ratio_<source>_<target>_<mode>.png
    (with ``_<index>`` where a merged settings label tells two curves of one mode apart)."""
    return f"freeze_ratio_{source}_{target}_{curve['mode']}" + (f"_{index}" if curve["label"] else "") + ".png"


def write(out: Path, result: Mapping[str, Any], overwrite: bool = False) -> None:
    out = Path(out)
    pngs = [name for _, _, png in result["ratios"] for name in png]
    present = [n for n in (*OUTPUTS, *pngs) if (out / n).exists()]
    if present and not overwrite:
        raise ConfigError(f"out={out} already holds {', '.join(present)}; pass overwrite=true to replace them")
    out.mkdir(parents=True, exist_ok=True)
    for scratch, curves, png in result["ratios"]:
        for curve, name in zip(curves, png):
            title = (f"{scratch['source']} -> {scratch['target']}, {curve['mode']} transfer"
                     + (f" [{curve['label']}]" if curve["label"] else ""))
            figures.plot_ratio_curve(out / name, curve, scratch, title)
    rows = [{k: r.get(k, "") for k in transfer_table.FIELDS} for r in result["table"]]
    artifacts.write_metrics_csv(out / "table4.csv", rows + [transfer_table.average_row(result["table"])])
    flat = [{k: (" ".join(f"{x:g}" for x in r[k]) if k == "steps_per_seed" else r[k])
             for k in transfer_table.VARIANT_FIELDS} for v in result["variants"] for r in v]
    artifacts.write_metrics_csv(out / "variants.csv", flat)
    artifacts.atomic_write_text(out / "table4.md", result["markdown_with_figures"])


def _run_list(value: str) -> list[Path]:
    items = [s.strip() for s in value.strip().strip("[]").split(",") if s.strip()]
    return [Path(s) for s in items]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(f"{__doc__}\nkeys: {', '.join(KEYS)}")
        return 0
    try:
        args = parse_known_cli(argv, KEYS)
        if "runs" not in args:
            raise ConfigError("runs=[DIR,...] is required (finished run folders, each with config.yaml and metrics.csv)")
        result = build(_run_list(args["runs"]), args.get("metric"),
                       coerce(args["fraction"], float, "fraction") if "fraction" in args else None,
                       coerce(args["window"], int, "window") if "window" in args else None,
                       args.get("transfer_preset", "L2"), args.get("semantic"))
        if "out" in args:
            write(Path(args["out"]), result, coerce(args.get("overwrite", "false"), bool, "overwrite"))
        print(result["markdown"])
        return 0
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
