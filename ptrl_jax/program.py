"""The PTRL chain as one jitted function (paper Algorithm 1).

    source params --PPO (SLRT)--> trained source --transfer L1, L2--> target params
                                                  --PPO with freeze mask (TLRT)--> per variant

Every target variant (freeze preset) and every seed runs under ``vmap``: the presets differ
only in two arrays, a transfer flag and a freeze mask, so one compiled program trains them all.
Seed k uses the same target initialisation and env stream under every preset, so presets are
compared on paired runs.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

import envs
from ptrl_jax.config import ExperimentConfig
from ptrl_jax.freeze import FREEZE_PRESETS, empty_mask, preset_mask, transfer
from ptrl_jax.train import ProgressFn, Trainer, TrainState, make_train


class ProgramOutput(NamedTuple):
    source: TrainState
    source_metrics: dict
    """Per-iteration metrics of the source stage, leaves shaped [iterations]."""
    target: TrainState
    """Target states, leaves shaped [presets, seeds, ...]."""
    target_metrics: dict
    """Leaves shaped [presets, seeds, iterations]."""


class Program(NamedTuple):
    run: Callable[[jax.Array], ProgramOutput]
    """``run(key)``: the whole chain; jit it (``jax.jit(program.run)``)."""
    source_trainer: Trainer
    target_trainer: Trainer
    source_env: Any
    target_env: Any


def make_program(
    cfg: ExperimentConfig,
    progress: Callable[[str], ProgressFn | None] | None = None,
) -> Program:
    """``progress(stage_name)`` returns that stage's progress hook (or None)."""
    hook = progress or (lambda stage: None)
    source_env = envs.make(cfg.source.robot, cfg.source.env)
    target_env = envs.make(cfg.target.robot, cfg.target.env)
    source = make_train(source_env, cfg.source.ppo, cfg.network, hook("source"))
    target = make_train(target_env, cfg.target.ppo, cfg.network, hook("target"))
    presets = cfg.freeze_presets
    n_seeds = cfg.seeds

    def run(key: jax.Array) -> ProgramOutput:
        source_key, target_key = jax.random.split(key)
        init_key, train_key = jax.random.split(source_key)
        source_params = source.init_params(init_key)
        source_state, source_metrics = source.train(
            train_key, cfg.source.ppo.hparams(), empty_mask(source_params), source_params
        )

        template = jax.eval_shape(target.init_params, target_key)
        masks = jax.tree.map(
            lambda *m: jnp.stack(m),
            *[preset_mask(jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), template), p) for p in presets],
        )
        transfer_flags = jnp.array([FREEZE_PRESETS[p].transfer for p in presets])
        run_ids = jnp.arange(len(presets))[:, None] * n_seeds + jnp.arange(n_seeds)[None, :]
        seed_keys = jax.random.split(target_key, n_seeds)
        hparams = cfg.target.ppo.hparams()

        def one_target(seed_key, transfer_flag, mask, run_id):
            init_k, train_k = jax.random.split(seed_key)
            fresh = target.init_params(init_k)
            params = transfer(source_state.params, fresh, transfer_flag)
            return target.train(train_k, hparams, mask, params, run_id)

        over_seeds = jax.vmap(one_target, in_axes=(0, None, None, 0))
        over_presets = jax.vmap(over_seeds, in_axes=(None, 0, 0, 0))
        target_state, target_metrics = over_presets(seed_keys, transfer_flags, masks, run_ids)
        return ProgramOutput(source_state, source_metrics, target_state, target_metrics)

    return Program(run, source, target, source_env, target_env)
