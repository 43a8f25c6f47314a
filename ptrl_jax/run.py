"""The command line: ``python -m ptrl_jax.run exp=go2_to_xbot [scale=smoke] [key=value ...]``.

Input and output live here, at the edge: the config is resolved and validated (a refused run
writes nothing), the PTRL program is compiled once and run, and the run folder
``runs/<exp>/<timestamp>/`` receives config.yaml, metrics.csv, checkpoints, curves.png and
report.md. ``resume=runs/<exp>/<timestamp>`` continues a stopped or killed run from its
last saved state (``resume_state.npz``) to the same result an uninterrupted run gives.
"""

from __future__ import annotations

import dataclasses
import difflib
import os
import signal
import sys

if __name__ == "__main__":
    # Before jax's backend exists (the imports below create it): compile-bound smoke runs
    # compile about 2.5x faster with the fast-compile XLA settings, and a resumed run compiles
    # with the flags it was saved with (ptrl_jax/xla_flags.py).
    from ptrl_jax.xla_flags import configure_from_argv

    configure_from_argv(sys.argv[1:])

import threading
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np
import yaml

from envs.mujoco_engine import resolve_engine
from ptrl_jax import artifacts, normalization, sharding, summary
from ptrl_jax.config import ExperimentConfig
from ptrl_jax.freeze import TRANSFER_MODES, variant
from ptrl_jax.artifacts import CheckpointError
from ptrl_jax.overrides import ConfigError, build_config, flatten, load_experiment, parse_cli, to_dict
from ptrl_jax.program import Program, ProgramOutput, make_program, target_run_id

USAGE = """usage: python -m ptrl_jax.run exp=NAME [scale=smoke|cpu|paper] [key=value ...]
       python -m ptrl_jax.run resume=runs/NAME/STAMP

  exp        preset name in experiments/ (e.g. go2_to_xbot) or a path to a .yaml file
  scale      smoke (tests, < 2 min), cpu (default, <= 30 min on 2 cores), paper (GPU)
  key=value  any config key, dotted: seeds=3 target.ppo.learning_rate=3e-4
             source.env.commands.lin_vel_x=[0,1] freeze_presets=[L2,scratch]
"""


class Progress:
    """Wall-clock stamps per iteration, and with ``show`` a tqdm bar per stage.

    With ``show``, a ``jax.debug.callback`` stamps every iteration of every vmapped run as it
    ends. Without it the program holds no host callback at all (so XLA's persistent cache can
    keep it) and the stamps come from the slice boundaries of ``run`` instead, spread evenly over
    the iterations of each slice (exact when ``checkpoint_every`` is 1)."""

    def __init__(self, cfg: ExperimentConfig, show: bool):
        n_targets = len(cfg.variants) * cfg.seeds * len(cfg.targets)
        self.n_targets = n_targets
        self.totals = {
            "source": cfg.source_iterations,
            "target": cfg.target.ppo.num_iterations * n_targets,
        }
        self.steps_per_call = {
            "source": cfg.source.ppo.env_steps_per_iteration,
            "target": cfg.target.ppo.env_steps_per_iteration,
        }
        self.show = show
        self.lock = threading.Lock()
        self.times: dict[tuple[str, int, int], float] = {}
        self.stage_start: dict[str, float] = {}
        self.counts = {"source": 0, "target": 0}
        self.spread_over = 0
        """Most iterations one call ran whose stamps ``record_slice`` had to spread (0: every
        stamp was measured by the callback or covers one iteration)."""
        self.bars: dict[str, Any] = {}
        self.t0 = time.monotonic()

    def start(self) -> None:
        # On resume, wall times continue from the last saved stamp (the downtime is not counted).
        last = max(self.times.values(), default=0.0)
        self.t0 = time.monotonic() - last

    def restore(self, meta: dict) -> None:
        """Wall-clock stamps and progress counts saved with a resume state."""
        self.times = {(s, int(r), int(i)): float(t) for s, r, i, t in meta.get("times", [])}
        self.stage_start = {k: float(v) for k, v in meta.get("stage_start", {}).items()}
        for (stage, _, _) in self.times:
            self.counts[stage] += 1

    def record_slice(self, before: tuple[int, int], after: tuple[int, int], t_start: float) -> None:
        """Stamp the (source, target) iterations a slice ran, where no callback did."""
        t_end = time.monotonic() - self.t0
        done = [("source", i) for i in range(before[0] + 1, after[0] + 1)]
        done += [("target", i) for i in range(before[1] + 1, after[1] + 1)]
        if any((stage, 0, it) not in self.times for stage, it in done):
            self.spread_over = max(self.spread_over, len(done))
        for k, (stage, it) in enumerate(done):
            t = t_start + (t_end - t_start) * (k + 1) / len(done)
            runs = range(self.n_targets) if stage == "target" else (0,)
            if stage == "target" and "target" not in self.stage_start:
                self.stage_start["target"] = self.last_time_before("target")
            self.stage_start.setdefault("source", 0.0)
            for r in runs:
                self.times.setdefault((stage, r, it), t)

    def hook(self, stage: str):
        if not self.show:
            return None

        def callback(d: dict) -> None:
            now = time.monotonic() - self.t0
            with self.lock:
                self.times[(stage, int(d["run_id"]), int(d["iteration"]))] = now
                if stage not in self.stage_start:
                    self.stage_start[stage] = self.last_time_before(stage)
                self.counts[stage] += 1
                if self.show:
                    self._update_bar(stage, now, float(d["episode_reward"]))

        return callback

    def last_time_before(self, stage: str) -> float:
        # The target stage starts when the source's last iteration ends (at 0 when the source
        # comes from a checkpoint and has no iterations).
        if stage == "target":
            return max((t for (s, _, _), t in self.times.items() if s == "source"), default=0.0)
        return 0.0

    def _update_bar(self, stage: str, now: float, reward: float) -> None:
        from tqdm import tqdm

        if stage not in self.bars:
            for bar in self.bars.values():
                bar.close()
            self.bars[stage] = tqdm(total=self.totals[stage], initial=self.counts[stage] - 1, desc=f"{stage:>6}",
                                    unit="it", dynamic_ncols=True)
        bar = self.bars[stage]
        bar.update(1)
        elapsed = max(now - self.stage_start[stage], 1e-9)
        sps = self.counts[stage] * self.steps_per_call[stage] / elapsed
        bar.set_postfix_str(f"{sps:,.0f} env steps/s, reward {reward:.3f}")
        if self.counts[stage] >= self.totals[stage]:
            bar.close()

    def close(self) -> None:
        for bar in self.bars.values():
            bar.close()


def interpolated_times_note(slice_iterations: int) -> str:
    """Report note for runs without the progress callback: ``Progress.record_slice`` then stamps
    each iteration of a call at an even share of the call's time, source and target alike, so
    the per-stage wall times (and wall time to threshold) are estimates, not measurements."""
    return (f"Progress was off: wall times are spread evenly over the iterations of each call (up to "
            f"{slice_iterations} iterations, source and target alike), so stage wall times and wall "
            f"time to threshold are estimates within a call; env steps are exact")


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


def stage_meta(cfg: ExperimentConfig, stage: str, preset: str, seed: int, robot: str | None = None) -> dict[str, Any]:
    sc = cfg.source if stage == "source" else cfg.targets[robot or cfg.target.robot]
    return {
        "robot": sc.robot, "stage": stage, "preset": preset, "seed": seed, "experiment": cfg.name,
        "network": to_dict(cfg.network), "env": to_dict(sc.env),
        "normalize_observations": sc.ppo.normalize_observations,
    }


def save_checkpoints(cfg: ExperimentConfig, run_dir: Path, out: ProgramOutput) -> None:
    """``source.npz`` (the source this run transferred from; none when it trained no source) and
    one ``target_[<robot>_]<variant>_seed<k>.npz`` per target run."""
    if cfg.source_checkpoint:
        # The source as it was trained (its own normaliser statistics; the program's source state
        # holds only its parameters).
        artifacts.atomic_write_bytes(run_dir / "source.npz", Path(cfg.source_checkpoint).read_bytes())
    elif cfg.trains_source:
        src = jax.device_get(out.source)
        artifacts.save_checkpoint(
            run_dir / "source.npz", src.params, src.normalizer, src.frozen, stage_meta(cfg, "source", "source", 0)
        )
    multi = len(cfg.targets) > 1  # several target robots: file names carry the robot
    for robot in cfg.targets:
        tgt = jax.device_get(out.target[robot])
        for p, preset in enumerate(cfg.variants):
            for s in range(cfg.seeds):
                pick = lambda x: x[p, s]  # noqa: E731
                name = f"target_{robot}_{preset}_seed{s}.npz" if multi else f"target_{preset}_seed{s}.npz"
                artifacts.save_checkpoint(
                    run_dir / name,
                    jax.tree.map(pick, tgt.params), jax.tree.map(pick, tgt.normalizer),
                    jax.tree.map(pick, tgt.frozen), stage_meta(cfg, "target", preset, s, robot),
                )


def save_outputs(
    cfg: ExperimentConfig, run_dir: Path, out: ProgramOutput, times: dict, extra_notes=(), stage_start=None,
    initial: dict | None = None,
) -> dict:
    """Every file of the run folder. ``initial``: ``Program.initial_targets`` of the final state,
    for the zero-shot walking checks (none without it)."""
    rows = metric_rows(cfg, out, times, stage_start)
    multi = len(cfg.targets) > 1  # several target robots: file names carry the robot
    artifacts.write_metrics_csv(run_dir / "metrics.csv", rows)
    if cfg.tensorboard:
        from ptrl_jax.tensorboard import write_events

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
            zero = zero_shot_rows(cfg, robot, rows, None if initial is None else initial[robot])
            text += "\n" + format_zero_shot(zero, cfg.report.zero_shot_seconds)
        sections.append(text)
        tables[robot] = (table, threshold)
    artifacts.atomic_write_text(run_dir / "report.md", "\n".join(sections))
    table, threshold = tables[cfg.target.robot]
    return {"rows": rows, "summary": table, "threshold": threshold,
            "summaries": {robot: t for robot, (t, _) in tables.items()}}


def zero_shot_rows(cfg: ExperimentConfig, robot: str, rows, initial: Any, checker=None) -> list[dict[str, Any]]:
    """Per distinct initialisation of ``robot``'s targets (scratch, paper, semantic, init
    checkpoint: the first variant of each): the first rollout's mean reward per env step over
    seeds (the policy before any update acted in it, with its exploration noise), and with
    ``initial`` (``Program.initial_targets``' states of the robot) the family's walking check
    of seed 0's deterministic policy. ``checker(policy) -> verdicts`` replaces the MuJoCo C
    check (tests)."""
    from ptrl_jax import evaluate

    checker = checker or (lambda policy: evaluate.run_walking_check(
        policy, sim="mujoco", seconds=cfg.report.zero_shot_seconds))
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


def format_zero_shot(rows: list[dict[str, Any]], seconds: float = 20.0) -> str:
    lines = ["## Zero-shot: the initialisations before any fine-tuning", "",
             "First rollout: mean reward per env step over seeds, sampled actions (the first iteration's "
             "rollout, before its update). Check: the family's walking check of seed 0's mean action "
             f"(MuJoCo C, {seconds:g} s per command; `python -m ptrl_jax.evaluate ckpt=... check=true`).", "",
             "| initialisation (variant) | first rollout, reward per step | walking check (survived, forward speed) |",
             "|---|---|---|"]
    for r in rows:
        checks = "not run (report.zero_shot_check=false)" if r["checks"] is None else "; ".join(
            f"{v['check']} vx {v['command'][0]:g}: {v['time_survived_s']:.1f} s, {v['mean_velocity'][0]:.2f} m/s, "
            f"{'pass' if v['passed'] else 'fail'}" for v in r["checks"])
        lines.append(f"| {r['initialisation']} ({r['variant']}) | {r['first_reward_mean']:.4f} ± "
                     f"{r['first_reward_std']:.4f} | {checks} |")
    return "\n".join(lines) + "\n"


def new_run_dir(cfg: ExperimentConfig) -> Path:
    return artifacts.new_run_dir(cfg.runs_dir, cfg.name)


RESUME_STATE = "resume_state.npz"
"""The whole program state, written every ``checkpoint_every`` iterations and on Ctrl-C/SIGTERM."""


class StopRequest:
    """Ctrl-C / SIGTERM set a flag instead of killing the process: the run saves its state at
    the end of the current slice and exits cleanly. A second Ctrl-C aborts at once (the last
    saved state is still there)."""

    def __init__(self):
        self.requested = False
        self._previous: dict[int, Any] = {}

    def _handler(self, signum, frame) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        print(f"\n{signal.Signals(signum).name}: saving the run state at the next checkpoint "
              f"(Ctrl-C again to abort now)", file=sys.stderr)

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc):
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        return False


def runtime_fingerprint(cfg: ExperimentConfig) -> dict[str, str]:
    """What a run's float results depend on besides its config and state: library versions,
    XLA flags, the device and the physics engine. A resume must match it bitwise."""
    import jaxlib
    import mujoco

    return {"jax": jax.__version__, "jaxlib": jaxlib.__version__, "mujoco": mujoco.__version__,
            "xla_flags": os.environ.get("XLA_FLAGS", ""), "device": jax.devices()[0].device_kind,
            "engine": resolve_engine(cfg.engine), "devices": str(sharding.resolve_devices(cfg.devices))}


def check_runtime(saved: dict[str, str], cfg: ExperimentConfig, run_dir: Path) -> None:
    """Refuse to resume under another runtime, naming each difference."""
    now = runtime_fingerprint(cfg)
    diff = [f"{k}: saved {saved[k]!r}, now {now[k]!r}" for k in now if k in saved and saved[k] != now[k]]
    if diff:
        raise ConfigError(f"resume={run_dir}: the run was saved under another runtime, so it would not "
                          f"continue bitwise ({'; '.join(diff)}); resume it where it ran, or start it anew")


def save_resume_state(cfg: ExperimentConfig, run_dir: Path, state: Any, progress: "Progress") -> None:
    times = [[s, r, i, t] for (s, r, i), t in progress.times.items()]
    meta = {"experiment": cfg.name, "jax": jax.__version__, "runtime": runtime_fingerprint(cfg), "times": times,
            "stage_start": progress.stage_start,
            "source_iteration": Program.iterations(state)[0],
            "target_iteration": Program.iterations(state)[1]}
    artifacts.save_state(run_dir / RESUME_STATE, state, meta)


# Compiled programs of this process, by what shapes them, for runs without a progress hook (a
# hook binds its own Progress). A notebook sweep, or a resume in the same process, then skips the
# trace and compile: tracing the two MJX pipelines alone takes most of a minute on 2 cores.
_PROGRAMS: dict[tuple, tuple] = {}


def load_policy(path: Path, robot: str, trainer, what: str) -> dict[str, Any]:
    """``{"params", "normalizer"}`` of a checkpoint, checked against ``robot`` and the network and
    observation sizes of ``trainer``; each refusal names the file and the leaf. ``what`` names
    the config key in messages."""
    path = Path(path)
    ckpt = artifacts.load_checkpoint(path)
    found = ckpt["meta"].get("robot")
    if found != robot:
        raise CheckpointError(f"{what} {path} is a {found!r} policy; this experiment needs a {robot!r} one")
    template = jax.eval_shape(trainer.init_params, jax.random.PRNGKey(0))
    flat = dict(jax.tree_util.tree_leaves_with_path(ckpt["params"]))
    want = dict(jax.tree_util.tree_leaves_with_path(template))
    for name in sorted(set(map(jax.tree_util.keystr, want)) ^ set(map(jax.tree_util.keystr, flat))):
        raise CheckpointError(f"{what} {path}: parameter {name} is in only one of the "
                              f"checkpoint and this experiment's network")
    for k, like in want.items():
        if flat[k].shape != like.shape:
            raise CheckpointError(f"{what} {path}: {jax.tree_util.keystr(k)} is "
                                  f"{list(flat[k].shape)}, this network needs {list(like.shape)}")
    params = jax.tree.map(lambda x, like: np.asarray(x, like.dtype), ckpt["params"], template)
    normalizer = {}
    for key, size in trainer.observation_sizes.items():
        stats = ckpt["normalizer"].get(key)
        if not isinstance(stats, dict) or set(stats) != {"mean", "m2", "count"}:
            raise CheckpointError(f"{what} {path}: no normaliser statistics for {key!r} "
                                  f"(normalizer/{key}/mean, m2, count)")
        if stats["mean"].shape != (size,):
            raise CheckpointError(f"{what} {path}: normalizer/{key} has {stats['mean'].shape[0]} entries, "
                                  f"this robot's {key} has {size}")
        normalizer[key] = normalization.RunningStats(
            np.asarray(stats["mean"], np.float32), np.asarray(stats["m2"], np.float32),
            np.asarray(stats["count"], np.float32))
    return {"params": params, "normalizer": normalizer}


def load_source_params(cfg: ExperimentConfig, program: Program) -> Any:
    """``{"params", "normalizer"}`` of ``cfg.source_checkpoint``, checked against this
    experiment's source robot and network; None when the config trains its own source."""
    if not cfg.source_checkpoint:
        return None
    return load_policy(Path(cfg.source_checkpoint), cfg.source.robot, program.source_trainer, "source_checkpoint")


def load_init_target(cfg: ExperimentConfig, program: Program) -> Any:
    """``{"params", "normalizer"}`` of ``cfg.init_checkpoint`` (a target checkpoint), or None."""
    if not cfg.init_checkpoint:
        return None
    return load_policy(Path(cfg.init_checkpoint), cfg.target.robot, program.target_trainers[cfg.target.robot],
                       "init_checkpoint")


def check_threshold_metric(metric: str, reward_terms: dict[str, tuple[str, ...]]) -> None:
    """Refuse a ``report.threshold_metric`` reward term that a target robot does not log
    (``reward_terms``: robot -> its reward terms), naming the nearest one."""
    if metric == "episode_reward":
        return
    term = metric.split("/", 1)[1]
    for robot, terms in reward_terms.items():
        if term not in terms:
            near = difflib.get_close_matches(term, list(terms), n=1, cutoff=0.4)
            hint = f"; did you mean 'episode_reward/{near[0]}'?" if near else ""
            raise ConfigError(f"report.threshold_metric={metric!r}: {robot} has no reward term {term!r} "
                              f"(its terms: {', '.join(terms)}){hint}")


def env_counts(cfg: ExperimentConfig) -> dict[str, int]:
    """The env batch of every stage the program steps: the source (when it trains) and each target."""
    counts = {"source": cfg.source.ppo.num_envs} if cfg.trains_source else {}
    counts.update({robot: stage.ppo.num_envs for robot, stage in cfg.targets.items()})
    return counts


def _compiled_program(cfg: ExperimentConfig, progress: Progress, key: jax.Array, budget: np.int32, devices: int = 1):
    """(program, jitted init, compiled advance, state shardings or None) for ``cfg`` on
    ``devices`` local devices (``ptrl_jax/sharding.py``)."""
    cache_key = (cfg.source, cfg.target, cfg.extra_targets, cfg.network, cfg.variants, cfg.seeds,
                 bool(cfg.source_checkpoint), bool(cfg.init_checkpoint), cfg.trains_source, cfg.transfer, cfg.engine,
                 devices)
    if not progress.show and cache_key in _PROGRAMS:
        return _PROGRAMS[cache_key]
    program = make_program(cfg, progress.hook)
    inputs = load_source_params(cfg, program), load_init_target(cfg, program)
    shapes = jax.eval_shape(program.init, key, *inputs)
    shardings = None
    if devices > 1:
        mesh = sharding.make_mesh(devices)
        shardings = sharding.state_shardings(mesh, shapes, cfg.source.ppo.num_envs,
                                             {robot: stage.ppo.num_envs for robot, stage in cfg.targets.items()})
        init = jax.jit(program.init, out_shardings=shardings)
        replicated = sharding.NamedSharding(mesh, sharding.PartitionSpec())
        advance = jax.jit(program.advance, in_shardings=(shardings, replicated), out_shardings=shardings)
    else:
        init, advance = jax.jit(program.init), jax.jit(program.advance)
    advance = advance.lower(shapes, budget).compile()
    if not progress.show:
        _PROGRAMS[cache_key] = (program, init, advance, shardings)
    return program, init, advance, shardings


def run(cfg: ExperimentConfig, run_dir: Path | None = None, show_progress: bool | None = None,
        resume_from: Path | None = None) -> dict:
    """Compile and run the PTRL program for ``cfg``; write the run folder. Returns paths and
    timings (``interrupted=True`` if it stopped early, with the state saved for ``resume``).
    Usable from notebooks as well as the CLI.

    The one compiled program is called in slices of ``cfg.checkpoint_every`` iterations (one
    call when it is 0), and the whole state is saved between slices."""
    show = cfg.progress if show_progress is None else show_progress
    progress = Progress(cfg, show)
    key = jax.random.PRNGKey(cfg.seed)
    total = cfg.source_iterations + cfg.target.ppo.num_iterations
    budget = np.int32(cfg.checkpoint_every or total)
    # Before compiling: the reward terms are the fields of each target's reward config.
    check_threshold_metric(cfg.report.threshold_metric, {
        robot: tuple(f.name for f in dataclasses.fields(stage.env.rewards)) for robot, stage in cfg.targets.items()})
    devices = sharding.resolve_devices(cfg.devices)
    sharding.check_divisible(env_counts(cfg), devices)
    t = time.monotonic()
    program, init, advance, shardings = _compiled_program(cfg, progress, key, budget, devices)
    run_dir = resume_from or run_dir or new_run_dir(cfg)  # after compiling: a refused run writes nothing
    inputs = load_source_params(cfg, program), load_init_target(cfg, program)
    if resume_from is not None:
        state, meta = artifacts.load_state(run_dir / RESUME_STATE, jax.eval_shape(init, key, *inputs))
        if shardings is not None:
            state = jax.device_put(state, shardings)
        progress.restore(meta)
    else:
        state = init(key, *inputs)
    compile_s = time.monotonic() - t
    if resume_from is None:
        artifacts.write_config(run_dir / "config.yaml", to_dict(cfg))
    interrupted = False
    with StopRequest() as stop:
        progress.start()
        while not program.finished(state, cfg):
            before, t_start = program.iterations(state), time.monotonic() - progress.t0
            state = jax.block_until_ready(advance(state, budget))
            progress.record_slice(before, program.iterations(state), t_start)
            if cfg.checkpoint_every or stop.requested:
                save_resume_state(cfg, run_dir, state, progress)
            if stop.requested and not program.finished(state, cfg):
                interrupted = True
                break
    run_s = time.monotonic() - progress.t0
    progress.close()
    if interrupted:
        return {"run_dir": run_dir, "interrupted": True, "compile_s": compile_s, "run_s": run_s,
                "state": state}
    out = program.output(state)
    notes = [f"Compile {compile_s:.1f} s, run {run_s:.1f} s on {jax.devices()[0].platform.upper()} "
             f"({devices} of {jax.device_count()} device(s))" + (" (resumed)" if resume_from else "")]
    if progress.spread_over > 1:
        notes.append(interpolated_times_note(progress.spread_over))
    initial = None
    if cfg.report.zero_shot_check and (cfg.trains_source or cfg.source_checkpoint or cfg.init_checkpoint):
        initial = jax.device_get(program.initial_targets(state))
    result = save_outputs(cfg, run_dir, out, progress.times, notes, progress.stage_start, initial)
    (run_dir / RESUME_STATE).unlink(missing_ok=True)  # finished: the final checkpoints replace it
    result.update({"run_dir": run_dir, "compile_s": compile_s, "run_s": run_s, "output": out,
                   "interrupted": False, "state": state})
    return result


def resume(run_dir: Path, show_progress: bool | None = None) -> dict:
    """Continue an interrupted run in its own folder from its last saved state."""
    run_dir = Path(run_dir)
    config_path = run_dir / "config.yaml"
    if not config_path.is_file():
        raise ConfigError(f"resume={run_dir}: no config.yaml there (is it a run folder?)")
    if not (run_dir / RESUME_STATE).is_file():
        done = (run_dir / "report.md").is_file()
        raise ConfigError(f"resume={run_dir}: no {RESUME_STATE} there"
                          + (" (the run finished; nothing to resume)" if done else ""))
    with open(config_path) as f:
        cfg = build_config(flatten(yaml.safe_load(f)))
    check_runtime(artifacts.read_state_meta(run_dir / RESUME_STATE).get("runtime", {}), cfg, run_dir)
    return run(cfg, show_progress=show_progress, resume_from=run_dir)


def _report_result(result: dict) -> int:
    run_dir = result["run_dir"]
    if result["interrupted"]:
        print(f"stopped; state saved in {run_dir / RESUME_STATE}\n"
              f"resume with: python -m ptrl_jax.run resume={run_dir}", file=sys.stderr)
        return 130
    print(f"run folder: {run_dir}")
    print((run_dir / "report.md").read_text())
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help", "help"):
        from ptrl_jax.overrides import format_keys

        print(f"{USAGE}\nkeys, with their defaults (a preset overrides them; source.env / target.env take the\n"
              f"robot's env config keys, envs/quadruped.py and envs/biped.py):\n{format_keys()}")
        return 0
    try:
        args = parse_cli(argv)
        if "resume" in args:
            if len(args) > 1:
                raise ConfigError(f"resume=DIR takes no other arguments (got {sorted(set(args) - {'resume'})}); "
                                  "the run continues with its own config.yaml")
            return _report_result(resume(Path(args["resume"])))
        exp = args.pop("exp", None)
        if exp is None:
            raise ConfigError("exp=NAME is required (e.g. exp=go2_to_xbot)")
        from ptrl_jax import batch

        if batch.is_batch(exp):  # several experiments and one table (exp=table4)
            result = batch.run_batch(exp, args, run)
            print(f"batch folder: {result['run_dir']}")
            table = result["table_path"]
            if table.is_file():
                print(table.read_text())
            return 130 if result["interrupted"] else 0
        cfg = load_experiment(exp, args)
        return _report_result(run(cfg))  # run() refuses what needs the robots (reward terms, checkpoints)
    except (ConfigError, CheckpointError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
