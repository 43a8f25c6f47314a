"""Batches: several experiments run by one command, then one table over them.

A batch preset (``experiments/table4.yaml``) names its experiments under ``batch:``, settings
for all of them under ``overrides:`` and per scale under ``scales:``, and the table to build.
``python -m ptrl_jax.run exp=table4 [scale=...] [key=value ...]`` then runs every experiment as
a normal run in ``runs/table4/<stamp>/<experiment>/`` and writes ``table4.csv`` and
``table4.md`` beside them, rewritten after each experiment so a later failure loses nothing.

Two tables (``table:``):
- ``table4``: paper Table IV, time to threshold with transfer and from scratch
  (``transfer_table.py``);
- ``walking_checks``: after each experiment, the walking check of the robot's family on every
  scratch checkpoint (``walking_table.py``; ``exp=from_scratch``, issue 3's per-robot table).

Command-line keys apply to every experiment of the batch, and ``<experiment>.<key>=value`` to
that one only; ``batch=[a,b]`` replaces the list of experiments (``go2_to_xbot.source_checkpoint=runs/.../source.npz``). Every experiment's config
is built and validated before the first one starts.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Mapping

from ptrl_jax.io import artifacts, hosts, transfer_table, walking_table
from ptrl_jax.config import SCALES, ExperimentConfig
from ptrl_jax.io.overrides import ConfigError, flatten, load_experiment, read_preset

BATCH_KEYS = ("batch", "overrides", "scales", "table", "transfer_preset")
TABLES = ("table4", "walking_checks")
"""What a batch can build: paper Table IV, or the walking checks of its scratch runs."""


def is_batch(exp: str) -> bool:
    return "batch" in read_preset(exp)


def batch_configs(exp: str, cli: Mapping[str, Any]) -> tuple[dict[str, ExperimentConfig], dict[str, Any]]:
    """({experiment: its config}, batch settings) for a batch preset and command-line keys."""
    spec = read_preset(exp)
    unknown = sorted(set(spec) - set(BATCH_KEYS))
    if unknown:
        raise ConfigError(f"batch preset {exp}: unknown key(s) {unknown}; a batch has {list(BATCH_KEYS)}")
    cli = dict(cli)
    children = cli.pop("batch", spec["batch"])  # batch=[a,b] on the command line runs a subset
    if isinstance(children, str):
        children = [c.strip() for c in children.strip("[]").split(",") if c.strip()]
    children = list(children or [])
    if not children:
        raise ConfigError(f"batch preset {exp}: 'batch' lists no experiments")
    scale = str(cli.pop("scale", "cpu"))
    if scale not in SCALES:
        raise ConfigError(f"scale must be one of {SCALES}, got {scale!r}")
    table = spec.get("table", "table4")
    if table not in TABLES:
        raise ConfigError(f"batch preset {exp}: table={table!r} is not one of {list(TABLES)}")
    settings = {"name": Path(exp).stem, "scale": scale, "table": table,
                "transfer_preset": str(cli.pop("transfer_preset", spec.get("transfer_preset", "L2"))),
                "runs_dir": str(cli.pop("runs_dir", "runs"))}
    shared = {**flatten(spec.get("overrides") or {}), **flatten((spec.get("scales") or {}).get(scale) or {})}
    per_child: dict[str, dict] = {c: {} for c in children}
    common = {}
    for key, value in cli.items():
        head, _, rest = key.partition(".")
        if head in per_child and rest:
            per_child[head][rest] = value
        else:
            common[key] = value
    configs = {}
    for child in children:
        overrides = {**shared, **common, **per_child[child], "scale": scale}
        try:
            cfg = load_experiment(child, overrides)
        except ConfigError as e:
            raise ConfigError(f"{exp} -> {child}: {e}") from None
        if table == "walking_checks":
            if "scratch" not in cfg.variants:
                raise ConfigError(f"{exp} -> {child}: the walking-check table checks the 'scratch' runs; "
                                  f"the variants are {list(cfg.variants)}")
        elif "scratch" not in cfg.variants or settings["transfer_preset"] not in cfg.variants:
            raise ConfigError(f"{exp} -> {child}: the table compares 'scratch' with transfer_preset="
                              f"{settings['transfer_preset']!r}; the variants are {list(cfg.variants)}")
        configs[child] = cfg
    return configs, settings


def run_batch(exp: str, cli: Mapping[str, Any], run: Callable[..., dict[str, Any]], show_progress: bool | None = None,
              checker: walking_table.Checker | None = None,
              grid_checker: walking_table.GridChecker | None = None) -> dict[str, Any]:
    """Run every experiment of the batch in turn and build its table. Returns the batch folder,
    the table (``table_path``), its rows and each experiment's run result. A ``walking_checks``
    batch also evaluates every scratch checkpoint on its command grid (``command_grids.md``).
    ``run(cfg, run_dir=..., show_progress=...)`` runs one experiment (``ptrl_jax.run.run``, passed
    in so that this module does not import the CLI that imports it). ``checker`` and
    ``grid_checker`` replace the MJX walking check and the MuJoCo C grid (tests)."""
    configs, settings = batch_configs(exp, cli)
    main = hosts.is_main()  # over several processes (ptrl_jax/io/hosts.py) only process 0 writes
    batch_dir = (artifacts.new_run_dir(settings["runs_dir"], settings["name"]) if main
                 else Path(settings["runs_dir"]) / settings["name"] / f"process{hosts.process_index()}-writes-nothing")
    table_rows: list[dict[str, Any]] = []
    grid_table: list[dict[str, Any]] = []
    results = {}
    for child, cfg in configs.items():
        result = run(cfg, run_dir=batch_dir / child, show_progress=show_progress)
        results[child] = result
        if result["interrupted"]:
            break
        if not main:
            continue
        if settings["table"] == "walking_checks":
            table_rows += walking_table.experiment_rows(
                child, result["rows"], result["run_dir"], checker or mjx_walking_check, cfg.report.final_window,
                compile_s=result["compile_s"], train_s=result["run_s"])
            write_walking_table(batch_dir, settings, configs, table_rows)
            grid_table += walking_table.grid_rows(child, result["rows"], result["run_dir"], grid_checker or mujoco_grid)
            write_grid_table(batch_dir, grid_table)
        else:
            table_rows += transfer_table.experiment_rows(
                child, result["rows"], settings["transfer_preset"], cfg.report.threshold_fraction,
                cfg.report.final_window, source=cfg.source.robot, metric=cfg.report.threshold_metric,
                semantic_preset=cfg.report.semantic_preset)
            write_table(batch_dir, settings, configs, table_rows)
    return {"run_dir": batch_dir, "table_path": batch_dir / f"{settings['table']}.md", "rows": table_rows,
            "results": results, "interrupted": any(r["interrupted"] for r in results.values())}


def mjx_walking_check(checkpoint: Path) -> list[dict[str, Any]]:
    """The family's walking check (deterministic 20 s MJX rollouts) of one checkpoint."""
    from ptrl_jax import evaluate

    return evaluate.run_walking_check(evaluate.policy_from_checkpoint(str(checkpoint)))


def mujoco_grid(checkpoint: Path) -> dict[str, Any]:
    """The robot's default command grid with pushes (``command_grid``), MuJoCo C, of one
    checkpoint; its files go beside it (``<checkpoint>_grid_mujoco/``)."""
    from ptrl_jax import command_grid, evaluate

    policy = evaluate.policy_from_checkpoint(str(checkpoint))
    grid = command_grid.default_grid(policy["env"], [c.command for c in evaluate.walking_checks(policy["robot"])],
                                     pushes=True)
    result = evaluate.run_grid(policy, grid, sim="mujoco")
    command_grid.write_outputs(checkpoint.with_name(f"{checkpoint.stem}_grid_mujoco"), result["robot"], "mujoco", grid,
                               result["summary"], result["pushed"], result["verdict"], result["walking_check"])
    return result


def write_grid_table(batch_dir: Path, rows: list[dict[str, Any]]) -> None:
    artifacts.write_metrics_csv(batch_dir / "command_grids.csv", [{k: r.get(k, "") for k in walking_table.GRID_FIELDS}
                                                                 for r in rows])
    notes = ["Each scratch checkpoint's default grid (its training command ranges, 20 s per command, mean action) "
             "in MuJoCo C, then the same grid pushed 4 times per command (U(-0.5, 0.5) m/s per axis every 8 s); "
             "goals: no fall, mean |vx| and |vy| error <= 0.1 m/s, mean |yaw| error <= 0.2 rad/s, <= 5 % of pushed "
             "rollouts fallen (`python -m ptrl_jax.evaluate ckpt=... grid=true sim=mujoco pushes=true`; each "
             "checkpoint's table and heat map are in `<checkpoint>_grid_mujoco/`)"]
    artifacts.atomic_write_text(batch_dir / "command_grids.md", walking_table.format_grid_markdown(rows, notes))


def write_walking_table(batch_dir: Path, settings: Mapping[str, Any], configs: Mapping[str, ExperimentConfig],
                        rows: list[dict[str, Any]]) -> None:
    name = settings["table"]
    artifacts.write_metrics_csv(batch_dir / f"{name}.csv",
                                [{k: r.get(k, "") for k in walking_table.FIELDS} for r in rows])
    notes = [
        f"Scale {settings['scale']}: " + "; ".join(
            f"{c}: {', '.join(cfg.targets)}, {cfg.target.ppo.num_iterations} it x "
            f"{cfg.target.ppo.env_steps_per_iteration} steps, {cfg.seeds} seed(s)" for c, cfg in configs.items()),
        "Checks: deterministic 20 s MJX rollouts (mean action, no initial noise, no randomization); quadrupeds "
        "walk at vx 0.5, bipeds stand at vx 0 and walk at vx 0.3; a rollout passes with no fall and a mean "
        "forward speed within 0.15 m/s of the command (`python -m ptrl_jax.evaluate ckpt=... check=true`)",
        "Final reward: mean episode reward over the last iterations (report.final_window); compile and "
        "training times are each experiment's own (one robot per program)",
        "Experiments: " + ", ".join(f"[{c}]({c}/report.md)" for c in configs),
    ]
    artifacts.atomic_write_text(batch_dir / f"{name}.md", walking_table.format_markdown(rows, notes))


def write_table(batch_dir: Path, settings: Mapping[str, Any], configs: Mapping[str, ExperimentConfig],
                rows: list[dict[str, Any]]) -> None:
    name = settings["table"]
    csv_rows = [{k: r.get(k, "") for k in transfer_table.FIELDS} for r in rows]
    csv_rows.append(transfer_table.average_row(rows))
    artifacts.write_metrics_csv(batch_dir / f"{name}.csv", csv_rows)
    any_cfg = next(iter(configs.values()))
    notes = [
        f"Scale {settings['scale']}: " + "; ".join(
            f"{c}: source {cfg.source.robot} "
            + ("from " + cfg.source_checkpoint if cfg.source_checkpoint else
               f"{cfg.source.ppo.num_iterations} it x {cfg.source.ppo.env_steps_per_iteration} steps")
            + f", targets {cfg.target.ppo.num_iterations} it x {cfg.target.ppo.env_steps_per_iteration} steps"
            f", {cfg.seeds} seed(s)" for c, cfg in configs.items()),
        f"Threshold: {any_cfg.report.threshold_fraction:g} x the scratch run's final {any_cfg.report.threshold_metric} (mean of the "
        f"last {any_cfg.report.final_window} iterations, over seeds); time to threshold = env steps and "
        f"target-stage wall time at the first iteration reaching it",
        "Saved = 1 - transfer / scratch per seed (paired seeds), mean ± std over seeds where both reached it",
        "Variants of one program run in lockstep under vmap and share a clock, so wall time saved equals "
        "steps saved up to the spread of iteration times; freezing masks gradients, it does not skip them",
        "Experiments: " + ", ".join(f"[{c}]({c}/report.md)" for c in configs),
    ]
    artifacts.atomic_write_text(batch_dir / f"{name}.md", transfer_table.format_markdown(rows, notes))
