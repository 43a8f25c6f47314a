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
import sys

if __name__ == "__main__":
    # Before jax's backend exists (the imports below create it): compile-bound smoke runs
    # compile about 2.5x faster with the fast-compile XLA settings, and a resumed run compiles
    # with the flags it was saved with (ptrl_jax/io/xla_flags.py).
    # Several hosts join through jax.distributed, also before the backend exists (ptrl_jax/io/hosts.py).
    from ptrl_jax.io.hosts import HostsError, start_from_argv
    from ptrl_jax.io.xla_flags import configure_from_argv

    configure_from_argv(sys.argv[1:])
    try:
        sys.argv[1:] = start_from_argv(sys.argv[1:])
    except HostsError as e:
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(2)

import time
from pathlib import Path

import jax
import numpy as np
import yaml

from ptrl_jax.config import ConfigError, ExperimentConfig
from ptrl_jax.core import sharding
from ptrl_jax.core.program import make_program
from ptrl_jax.io import artifacts, hosts
from ptrl_jax.io.artifacts import CheckpointError
from ptrl_jax.io.checkpoints import load_init_target, load_source_params
from ptrl_jax.io.outputs import save_outputs
from ptrl_jax.io.overrides import build_config, flatten, load_experiment, parse_cli, to_dict
from ptrl_jax.io.progress import Progress, interpolated_times_note
from ptrl_jax.io.resume import RESUME_STATE, StopRequest, check_runtime, host_cpu, save_resume_state

USAGE = """usage: python -m ptrl_jax.run exp=NAME [scale=smoke|cpu|paper] [key=value ...]
       python -m ptrl_jax.run resume=runs/NAME/STAMP

  exp        preset name in experiments/ (e.g. go2_to_xbot) or a path to a .yaml file
  scale      smoke (tests, < 2 min), cpu (default, <= 30 min on 2 cores), paper (GPU)
  key=value  any config key, dotted: seeds=3 target.ppo.learning_rate=3e-4
             source.env.commands.lin_vel_x=[0,1] freeze_presets=[L2,scratch]
  several hosts (docs/scaling.md): coordinator=HOST:PORT num_processes=N process_id=K
             [host_timeout=300] devices=all engine=mjx, or distributed=auto under a cluster scheduler
"""


def new_run_dir(cfg: ExperimentConfig) -> Path:
    return artifacts.new_run_dir(cfg.runs_dir, cfg.name)


def walking_checker(cfg: ExperimentConfig):
    """The zero-shot section's check of an initial policy: the family's walking check of its
    mean action in MuJoCo C, ``report.zero_shot_seconds`` per command."""
    from ptrl_jax import evaluate

    return lambda policy: evaluate.run_walking_check(policy, sim="mujoco", seconds=cfg.report.zero_shot_seconds)


def source_checker(cfg: ExperimentConfig):
    """The report's check of the source: ``walking_checker`` on the written ``source.npz``."""
    from ptrl_jax import evaluate

    check = walking_checker(cfg)
    return lambda path: check(evaluate.policy_from_checkpoint(str(path)))


# Compiled programs of this process, by what shapes them, for runs without a progress hook (a
# hook binds its own Progress). A notebook sweep, or a resume in the same process, then skips the
# trace and compile: tracing the two MJX pipelines alone takes most of a minute on 2 cores.
_PROGRAMS: dict[tuple, tuple] = {}


def check_threshold_metric(metric: str, reward_terms: dict[str, tuple[str, ...]]) -> None:
    """Refuse a ``report.threshold_metric`` reward term that a target robot does not log
    (``reward_terms``: robot -> its reward terms), naming the nearest one."""
    curve, _, term = metric.partition("/")
    if not term:
        return
    for robot, terms in reward_terms.items():
        if term not in terms:
            near = difflib.get_close_matches(term, list(terms), n=1, cutoff=0.4)
            hint = f"; did you mean '{curve}/{near[0]}'?" if near else ""
            raise ConfigError(f"report.threshold_metric={metric!r}: {robot} has no reward term {term!r} "
                              f"(its terms: {', '.join(terms)}){hint}")


def env_counts(cfg: ExperimentConfig) -> dict[str, int]:
    """The env batch of every stage the program steps: the source (when it trains) and each target."""
    counts = {"source": cfg.source.ppo.num_envs} if cfg.trains_source else {}
    counts.update({robot: stage.ppo.num_envs for robot, stage in cfg.targets.items()})
    return counts


def _compiled_program(cfg: ExperimentConfig, progress: Progress, key: jax.Array, budget: np.int32, devices: int = 1):
    """(program, jitted init, compiled advance, state shardings or None) for ``cfg`` on
    ``devices`` local devices (``ptrl_jax/core/sharding.py``)."""
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


def check_engine_for_hosts(cfg: ExperimentConfig) -> None:
    """Refuse MuJoCo C's engine over several processes: its host callback steps the whole env
    batch in this process's thread pool, which cannot reach another host's envs."""
    from envs.mujoco_engine import resolve_engine

    if hosts.process_count() > 1 and resolve_engine(cfg.engine) != "mjx":
        raise ConfigError(f"engine={cfg.engine} runs the physics in one process's MuJoCo C thread pool; over "
                          f"{hosts.process_count()} processes use engine=mjx")


def run(cfg: ExperimentConfig, run_dir: Path | None = None, show_progress: bool | None = None,
        resume_from: Path | None = None) -> dict:
    """Compile and run the PTRL program for ``cfg``; write the run folder. Returns paths and
    timings (``interrupted=True`` if it stopped early, with the state saved for ``resume``).
    Usable from notebooks as well as the CLI.

    The one compiled program is called in slices of ``cfg.checkpoint_every`` iterations (one
    call when it is 0), and the whole state is saved between slices."""
    show = (cfg.progress if show_progress is None else show_progress) and hosts.is_main()
    progress = Progress(cfg, show)
    key = jax.random.PRNGKey(cfg.seed)
    total = cfg.source_iterations + cfg.target.ppo.num_iterations
    budget = np.int32(cfg.checkpoint_every or total)
    # Before compiling: the reward terms are the fields of each target's reward config.
    check_threshold_metric(cfg.report.threshold_metric, {
        robot: tuple(f.name for f in dataclasses.fields(stage.env.rewards)) for robot, stage in cfg.targets.items()})
    devices = sharding.resolve_devices(cfg.devices)
    sharding.check_divisible(env_counts(cfg), devices)
    check_engine_for_hosts(cfg)
    t = time.monotonic()
    program, init, advance, shardings = _compiled_program(cfg, progress, key, budget, devices)
    # Everything the report needs is imported now, not after training: a source file edited while
    # the run trains cannot then break its report (it did once, 40 minutes in; the state was
    # saved, and `resume=` wrote the report).
    checker = walking_checker(cfg)
    check_source = source_checker(cfg) if cfg.report.zero_shot_check else None
    main = hosts.is_main()  # with several processes only process 0 writes the run folder
    # after compiling: a refused run writes nothing
    run_dir = resume_from or run_dir or (new_run_dir(cfg) if main else None)
    inputs = load_source_params(cfg, program), load_init_target(cfg, program)
    if resume_from is not None:
        state, meta = artifacts.load_state(run_dir / RESUME_STATE, jax.eval_shape(init, key, *inputs))
        if shardings is not None:
            # device_put checks that every process holds the same state, a collective: meet first
            # (a loaded CI machine once had process 1 more than Gloo's 30 s behind here)
            hosts.barrier("loaded")
            state = jax.device_put(state, shardings)
        progress.restore(meta)
    else:
        state = init(key, *inputs)
    compile_s = time.monotonic() - t
    if resume_from is None and main:
        artifacts.write_config(run_dir / "config.yaml", to_dict(cfg))
    hosts.barrier("compiled")  # a process's compile can lag another's longer than a collective waits
    interrupted = False
    with StopRequest() as stop:
        progress.start()
        while not program.finished(state, cfg):
            before, t_start = program.iterations(state), time.monotonic() - progress.t0
            state = jax.block_until_ready(advance(state, budget))
            progress.record_slice(before, program.iterations(state), t_start)
            stop_now = hosts.any_process(stop.requested)  # a signal on any host stops all at this slice
            if cfg.checkpoint_every or stop_now:
                saved = hosts.fetch(state)
                if main:
                    save_resume_state(cfg, run_dir, saved, progress)
                hosts.barrier("saved")
            if stop_now and not program.finished(state, cfg):
                interrupted = True
                break
    run_s = time.monotonic() - progress.t0
    progress.close()
    if interrupted:
        return {"run_dir": run_dir, "interrupted": True, "compile_s": compile_s, "run_s": run_s,
                "state": state}
    state = hosts.fetch(state)
    out = program.output(state)
    notes = [f"Compile {compile_s:.1f} s, run {run_s:.1f} s on {jax.devices()[0].platform.upper()} "
             f"({devices} of {jax.device_count()} device(s))" + (" (resumed)" if resume_from else "")]
    if progress.spread_over > 1:
        notes.append(interpolated_times_note(progress.spread_over))
    if hosts.process_count() > 1:
        notes[0] += f" over {hosts.process_count()} processes"
    if jax.devices()[0].platform == "cpu":  # the float results follow the host's instruction set
        model, isa = host_cpu()
        notes.append(f"Host CPU: {model or 'unknown'}; vector ISA: {isa or 'none listed'} (the same seed "
                     f"gives other floats on a CPU with another ISA: docs/design.md, 'What a seed fixes')")
    initial = None
    result: dict = {}
    if main:
        if cfg.report.zero_shot_check and (cfg.trains_source or cfg.source_checkpoint or cfg.init_checkpoint):
            initial = jax.device_get(program.initial_weights(state))
        result = save_outputs(cfg, run_dir, out, progress.times, notes, progress.stage_start, initial,
                              checker=checker, source_checker=check_source)
        (run_dir / RESUME_STATE).unlink(missing_ok=True)  # finished: the final checkpoints replace it
    hosts.barrier("written", timeout_s=3600.0)  # the others wait for process 0's report and checks
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
    if run_dir is None:  # a process other than 0 of several: process 0 writes and reports
        print(f"process {jax.process_index()} of {jax.process_count()}: "
              + ("stopped with the others" if result["interrupted"] else "done") + "; process 0 writes the run folder")
        return 130 if result["interrupted"] else 0
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
        from ptrl_jax.io.overrides import format_keys

        print(f"{USAGE}\nkeys, with their defaults (a preset overrides them; source.env / target.env take the\n"
              f"robot's env config keys, envs/quadruped.py and envs/biped.py):\n{format_keys()}")
        return 0
    try:
        # Host keys (ptrl_jax/io/hosts.py) when main() is called without `python -m`: they work
        # only if nothing has run jax yet, and the error says so otherwise.
        argv = hosts.start_from_argv(argv)
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
            if not hosts.is_main():
                print(f"process {jax.process_index()} of {jax.process_count()}: "
                      + ("stopped with the others" if result["interrupted"] else "done")
                      + "; process 0 writes the batch folder")
                return 130 if result["interrupted"] else 0
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
