"""The PTRL chain as one jitted function (paper Algorithm 1).

    source params --PPO (SLRT)--> trained source --transfer L1, L2--> target params
                                                  --PPO with freeze mask (TLRT)--> per variant

Every target variant (freeze preset) and every seed runs under ``vmap``: the presets differ
only in two arrays, a transfer flag and a freeze mask, so one compiled program trains them all.
Seed k uses the same target initialisation and env stream under every preset, so presets are
compared on paired runs. Several target robots (``extra_targets``, exp=xbot_to_all) start from
the same trained source and advance together, one iteration each per step of the target loop;
their states live in dicts keyed by robot.

The program is a function of a ``ProgramState`` (``init(key)`` builds the first one):
``advance(state, budget)`` runs up to ``budget`` more iterations, each stage a ``while_loop``
that starts from the state's own counters and the transfer happening when the source stage
completes. One compiled ``advance`` runs a whole experiment in one call, or in slices with a
checkpoint between them (``run.py``), or resumes an interrupted run from a saved state; every
way gives bitwise the same result. It holds no host callbacks (except the optional progress
hook), so XLA's persistent compilation cache can keep it between processes.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import envs
from envs.mujoco_engine import resolve_engine
from ptrl_jax.core import normalization, semantic
from ptrl_jax.config import ExperimentConfig, PPOHparams
from ptrl_jax.core.freeze import TRANSFER_MODES, empty_mask, preset_mask, transfer, variant
from ptrl_jax.core.train import ProgressFn, Trainer, TrainState, make_train


class ProgramState(NamedTuple):
    """Everything the PTRL program carries: enough to resume it exactly."""

    source: TrainState
    source_metrics: dict
    """Per-iteration metrics of the source stage, leaves shaped [iterations] (filled as it runs)."""
    targets: dict[str, TrainState]
    """Per target robot: states with leaves shaped [presets, seeds, ...]; placeholders until the
    source is done."""
    target_metrics: dict[str, dict]
    """Per target robot: leaves shaped [iterations, presets, seeds]."""
    targets_started: jax.Array
    """Whether the targets have been initialised from the trained source (transfer done)."""
    target_key: jax.Array
    """PRNG key of the target stage (initialisation and env streams)."""
    init_target: Any = None
    """``{"params", "normalizer"}`` of ``init_checkpoint`` (the start of every transferring
    variant), or None."""


class ProgramOutput(NamedTuple):
    source: TrainState
    source_metrics: dict
    """Per-iteration metrics of the source stage, leaves shaped [iterations]."""
    target: dict[str, TrainState]
    """Per target robot: states with leaves shaped [presets, seeds, ...]."""
    target_metrics: dict[str, dict]
    """Per target robot: leaves shaped [presets, seeds, iterations]."""


class TargetStart(NamedTuple):
    """What the transfer gives one target robot's runs before any fine-tuning: leaves shaped
    [presets, seeds, ...]. The weights of ``ProgramState.targets`` when the target stage starts,
    without the env states (for zero-shot evaluations, which need only the policies)."""

    params: Any
    normalizer: Any


class Program(NamedTuple):
    init: Callable[..., ProgramState]
    """``init(key, source=None, init_target=None)``: the initial state (jit it). ``source``,
    ``{"params", "normalizer"}`` of a trained source, when the config starts from
    ``source_checkpoint``; ``init_target``, the same of the target, with ``init_checkpoint``."""
    advance: Callable[[ProgramState, jax.Array], ProgramState]
    """``advance(state, budget)``: run up to ``budget`` more iterations, source stage first,
    then (after the transfer) the target stage (jit it; ``budget`` is a traced int)."""
    run: Callable[[jax.Array], ProgramOutput]
    """``run(key)``: ``output(advance(init(key), all))``, the whole chain in one function."""
    source_trainer: Trainer
    target_trainers: dict[str, Trainer]
    source_env: Any
    target_envs: dict[str, Any]
    initial_weights: Callable[[ProgramState], dict[str, TargetStart]]
    """``initial_weights(state)``: per target robot, the weights as the transfer left them, before
    any fine-tuning (recomputed from the state's source, key and init checkpoint; bitwise the
    weights the target stage started from). It resets no env, so it compiles in seconds."""
    start_weights: Callable[..., dict[str, TargetStart]]
    """``start_weights(key, source=None, init_target=None)``: ``initial_weights`` of the state
    ``init`` would build, for a config that trains no source (tests and tools)."""
    transfer_maps: dict[str, Any]
    """Per target robot: its ``semantic.TransferMap`` from the source (only when a variant
    transfers semantically)."""

    @staticmethod
    def output(state: ProgramState) -> ProgramOutput:
        metrics = jax.tree.map(lambda x: jnp.moveaxis(x, 0, -1), state.target_metrics)
        return ProgramOutput(state.source, state.source_metrics, state.targets, metrics)

    @staticmethod
    def iterations(state: ProgramState) -> tuple[int, int]:
        """(source iterations done, target iterations done)."""
        if not bool(state.targets_started):
            return int(state.source.iteration), 0
        tgt = min(int(jax.device_get(t.iteration).min()) for t in state.targets.values())
        return int(state.source.iteration), tgt

    @staticmethod
    def finished(state: ProgramState, cfg: ExperimentConfig) -> bool:
        return Program.iterations(state)[1] >= cfg.target.ppo.num_iterations


def target_run_id(cfg: ExperimentConfig, robot_index, preset_index, seed):
    """The id of one vmapped target run (it tags progress stamps): robots, then presets, then
    seeds, counting from 0. Works on ints and on broadcasting arrays alike."""
    return (robot_index * len(cfg.variants) + preset_index) * cfg.seeds + seed


def target_hparams(cfg: ExperimentConfig) -> PPOHparams:
    """The target stage's hyperparameters per variant (leaves shaped [variants]): ``target.ppo``'s
    for all, and ``transfer.critic_warmup`` for the variants that transfer (0 for scratch)."""
    base = cfg.target.ppo.hparams()
    transfers = jnp.array([variant(v).transfer for v in cfg.variants])
    stacked = jax.tree.map(lambda x: jnp.broadcast_to(x, transfers.shape), base)
    warmup = jnp.where(transfers, jnp.float32(cfg.transfer.critic_warmup), jnp.float32(0.0))
    return stacked._replace(critic_warmup=warmup)


def make_program(
    cfg: ExperimentConfig,
    progress: Callable[[str], ProgressFn | None] | None = None,
) -> Program:
    """``progress(stage_name)`` returns that stage's progress hook (or None)."""
    hook = progress or (lambda stage: None)
    physics = resolve_engine(cfg.engine)
    engine = lambda env_cfg: dataclasses.replace(env_cfg, engine=physics)  # noqa: E731
    source_env = envs.make(cfg.source.robot, engine(cfg.source.env))
    source = make_train(source_env, cfg.source.ppo, cfg.network.source, hook("source"))
    stages = cfg.targets
    target_envs = {r: envs.make(r, engine(st.env)) for r, st in stages.items()}
    targets = {r: make_train(target_envs[r], st.ppo, cfg.network, hook("target")) for r, st in stages.items()}
    presets = cfg.variants
    n_seeds = cfg.seeds
    n_source, n_target = cfg.source_iterations, cfg.target.ppo.num_iterations
    # Built before anything compiles: a joint map naming a joint that does not exist fails here.
    transfer_maps = ({r: semantic.build_map(source_env, e, cfg.transfer.joint_map, cfg.transfer.unmapped_blocks,
                                            cfg.transfer.knee)
                      for r, e in target_envs.items()} if cfg.semantic else {})
    modes = [variant(p).mode_index for p in presets]  # 0 scratch, 1 + TRANSFER_MODES.index(mode)
    # Per mode index, which parts (critic, output, input) a semantic variant keeps fresh.
    fresh_parts = np.array([[part in semantic.FRESH_PARTS.get(m, ()) for part in ("critic", "output", "input")]
                            for m in ("scratch", *TRANSFER_MODES)])

    def init_robot_targets(target: Trainer, robot: str, robot_index: int, source, target_key,
                           init_target=None) -> TrainState:
        template = jax.eval_shape(target.init_params, target_key)
        zeros = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), template)
        masks = jax.tree.map(lambda *m: jnp.stack(m), *[preset_mask(zeros, p) for p in presets])
        mode_ids = jnp.array(modes, jnp.int32)
        run_ids = target_run_id(cfg, robot_index, jnp.arange(len(presets))[:, None], jnp.arange(n_seeds)[None, :])
        seed_keys = jax.random.split(target_key, n_seeds)
        hparams = target_hparams(cfg)

        def one_target(seed_key, mode, mask, run_id, hp):
            train_k, params, norm = target_weights(target, robot, source, seed_key, mode, init_target)
            return target.init(train_k, hp, mask, params, run_id, norm)

        over_seeds = jax.vmap(one_target, in_axes=(0, None, None, 0, None))
        return jax.vmap(over_seeds, in_axes=(None, 0, 0, 0, 0))(seed_keys, mode_ids, masks, run_ids, hparams)

    def target_weights(target: Trainer, robot: str, source, seed_key, mode, init_target=None):
        """One run's start: (its training key, params, normaliser) for variant ``mode``."""
        init_k, train_k = jax.random.split(seed_key)
        fresh = target.init_params(init_k)
        fresh_norm = {k: normalization.init(n) for k, n in target.observation_sizes.items()}
        if init_target is not None:  # init_checkpoint: every transferring variant starts from it
            pick = lambda a, b: jax.tree.map(lambda x, y: jnp.where(mode > 0, x, y), a, b)  # noqa: E731
            return train_k, pick(init_target["params"], fresh), pick(init_target["normalizer"], fresh_norm)
        params = transfer(source["params"], fresh, mode == 1)
        if not cfg.semantic:  # static: programs without a semantic variant are unchanged
            return train_k, params, fresh_norm
        sem_params, sem_norm = semantic.apply(transfer_maps[robot], source["params"], source["normalizer"],
                                              fresh, fresh_norm, cfg.transfer.noise_std)
        if any(fresh_parts[m].any() for m in modes):  # static: a variant keeps some part fresh
            fc, fo, fi = jnp.asarray(fresh_parts)[mode]
            sem_params = semantic.keep_fresh(sem_params, fresh, fresh_critic=fc, fresh_output=fo,
                                             noise_std=cfg.transfer.noise_std, fresh_input=fi)
        else:
            fi = False
        is_sem = mode >= 2
        params = jax.tree.map(lambda a, b: jnp.where(is_sem, a, b), sem_params, params)
        mapped_norm = is_sem & ~jnp.asarray(fi)  # a fresh input layer reads a fresh normaliser
        norm = jax.tree.map(lambda a, b: jnp.where(mapped_norm, a, b), sem_norm, fresh_norm)
        return train_k, params, norm

    def robot_keys(target_key) -> list:
        # The first target robot uses target_key itself (a single-target program is unchanged by
        # the multi-target generalisation); further robots fold in their index.
        return [target_key] + [jax.random.fold_in(target_key, i) for i in range(1, len(targets))]

    @jax.jit  # traced once: init's eval_shape and advance's transfer share the trace
    def init_targets(source, target_key, init_target=None) -> dict[str, TrainState]:
        keys = robot_keys(target_key)
        return {r: init_robot_targets(t, r, i, source, keys[i], init_target)
                for i, (r, t) in enumerate(targets.items())}

    # Wrapped in jit so that tracing happens once: ``init`` asks for the metric shapes with
    # eval_shape, and ``advance`` then reuses the same traced jaxprs (jit's trace cache) instead
    # of tracing both MJX pipelines a second time (about half of a warm start's 70 s).
    source_iteration = jax.jit(source.iteration)
    batched_target_iterations = {r: jax.jit(jax.vmap(jax.vmap(t.iteration))) for r, t in targets.items()}
    first_target = next(iter(targets))

    def zeros_like_shapes(tree):
        return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), tree)

    def init(key: jax.Array, source_ckpt=None, init_target=None) -> ProgramState:
        source_key, target_key = jax.random.split(key)
        init_key, train_key = jax.random.split(source_key)
        if (source_ckpt is None) != (not cfg.source_checkpoint):
            raise ValueError("init: pass source_ckpt exactly when the config has a source_checkpoint")
        if (init_target is None) != (not cfg.init_checkpoint):
            raise ValueError("init: pass init_target exactly when the config has an init_checkpoint")
        params = source.init_params(init_key) if source_ckpt is None else source_ckpt["params"]
        src = source.init(train_key, cfg.source.ppo.hparams(), empty_mask(params), params,
                          normalizer=None if source_ckpt is None else source_ckpt["normalizer"])
        src_metrics = jax.eval_shape(source_iteration, src)[1]
        tgts = jax.eval_shape(init_targets, {"params": src.params, "normalizer": src.normalizer}, target_key,
                              init_target)
        tgt_metrics = {r: jax.eval_shape(batched_target_iterations[r], tgts[r])[1] for r in targets}
        return ProgramState(
            source=src,
            source_metrics=jax.tree.map(lambda s: jnp.zeros((n_source, *s.shape), s.dtype), src_metrics),
            targets=zeros_like_shapes(tgts),
            target_metrics=jax.tree.map(lambda s: jnp.zeros((n_target, *s.shape), s.dtype), tgt_metrics),
            targets_started=jnp.array(False),
            target_key=target_key,
            init_target=init_target,
        )

    def source_body(carry):
        state, done = carry
        i = state.source.iteration
        src, metrics = source_iteration(state.source)
        buffers = jax.tree.map(lambda b, v: b.at[i].set(v), state.source_metrics, metrics)
        return state._replace(source=src, source_metrics=buffers), done + 1

    def target_body(carry):
        state, done = carry
        i = state.targets[first_target].iteration[0, 0]
        stepped = {r: batched_target_iterations[r](state.targets[r]) for r in targets}
        tgts = {r: stepped[r][0] for r in targets}
        metrics = {r: stepped[r][1] for r in targets}
        buffers = jax.tree.map(lambda b, v: b.at[i].set(v), state.target_metrics, metrics)
        return state._replace(targets=tgts, target_metrics=buffers), done + 1

    def start_targets(state: ProgramState) -> ProgramState:
        source_now = {"params": state.source.params, "normalizer": state.source.normalizer}
        return state._replace(targets=init_targets(source_now, state.target_key, state.init_target),
                              targets_started=jnp.array(True))

    def advance(state: ProgramState, budget: jax.Array) -> ProgramState:
        done = jnp.zeros((), jnp.int32)
        if n_source:  # no source to train (from a checkpoint, or scratch only): no source stage compiled
            state, done = jax.lax.while_loop(
                lambda c: (c[0].source.iteration < n_source) & (c[1] < budget), source_body, (state, done)
            )
        begin = (state.source.iteration >= n_source) & ~state.targets_started
        state = jax.lax.cond(begin, start_targets, lambda s: s, state)
        state, _ = jax.lax.while_loop(
            lambda c: c[0].targets_started & (c[0].targets[first_target].iteration[0, 0] < n_target)
            & (c[1] < budget),
            target_body, (state, done),
        )
        return state

    def run(key: jax.Array) -> ProgramOutput:
        return Program.output(advance(init(key), jnp.int32(n_source + n_target)))

    @jax.jit
    def weights_from(source_now, target_key, init_target=None) -> dict[str, TargetStart]:
        mode_ids = jnp.array(modes, jnp.int32)
        out = {}
        for (robot, target), key in zip(targets.items(), robot_keys(target_key)):
            def weights(seed_key, mode, target=target, robot=robot):
                return target_weights(target, robot, source_now, seed_key, mode, init_target)[1:]
            over_seeds = jax.vmap(weights, in_axes=(0, None))
            out[robot] = TargetStart(*jax.vmap(over_seeds, in_axes=(None, 0))(jax.random.split(key, n_seeds), mode_ids))
        return out

    def initial_weights(state: ProgramState) -> dict[str, TargetStart]:
        source_now = {"params": state.source.params, "normalizer": state.source.normalizer}
        return weights_from(source_now, state.target_key, state.init_target)

    def start_weights(key: jax.Array, source_ckpt=None, init_target=None) -> dict[str, TargetStart]:
        """What ``initial_weights(init(key, source_ckpt, init_target))`` gives when no source is
        trained (the source from its checkpoint, or none), without building env states."""
        if n_source:
            raise ValueError("start_weights: the config trains its source; the targets start from the trained one")
        source_key, target_key = jax.random.split(key)
        init_key, _ = jax.random.split(source_key)
        if source_ckpt is None:
            source_ckpt = {"params": source.init_params(init_key),
                           "normalizer": {k: normalization.init(n) for k, n in source.observation_sizes.items()}}
        return weights_from(source_ckpt, target_key, init_target)

    return Program(init, advance, run, source, targets, source_env, target_envs, initial_weights, start_weights,
                   transfer_maps)
