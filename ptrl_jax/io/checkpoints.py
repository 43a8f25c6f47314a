"""A run's policy checkpoints, checked at the edge: ``save_checkpoints`` writes ``source.npz`` and
one ``target_*.npz`` per target run; ``load_policy`` reads one back against the network and
observation sizes a program expects, and refuses a mismatch naming the file and the leaf
(``source_checkpoint=`` and ``init_checkpoint=``). The file format is ``artifacts``'."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any, Mapping

import jax
import numpy as np

import envs
from ptrl_jax.config import ExperimentConfig
from ptrl_jax.core import normalization
from ptrl_jax.core.program import Program, ProgramOutput
from ptrl_jax.io import artifacts
from ptrl_jax.io.artifacts import CheckpointError
from ptrl_jax.io.overrides import to_dict


def stage_meta(cfg: ExperimentConfig, stage: str, preset: str, seed: int, robot: str | None = None) -> dict[str, Any]:
    sc = cfg.source if stage == "source" else cfg.targets[robot or cfg.target.robot]
    return {
        "robot": sc.robot, "stage": stage, "preset": preset, "seed": seed, "experiment": cfg.name,
        "network": to_dict(cfg.network), "env": to_dict(sc.env),
        "normalize_observations": sc.ppo.normalize_observations,
        "asset_sha256": envs.asset_sha256(sc.env.asset),
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


def warn_if_model_changed(path: str | Path, meta: Mapping[str, Any], asset: str) -> None:
    """Warn when a checkpoint was trained on another version of its robot's MJCF than ``asset``
    as installed (``asset_sha256`` in its metadata; checkpoints written before stop 57 carry
    none). The policy is still used, on the installed model, as its config and shapes are
    unchanged; what it measured when it was trained may not hold there."""
    saved, now = meta.get("asset_sha256"), envs.asset_sha256(asset)
    if saved is not None and saved != now:
        warnings.warn(f"checkpoint {path} was trained on another version of {asset} (sha256 {saved}, "
                      f"installed {now}); it is used on the installed model, so it may behave "
                      f"otherwise than when it was trained", UserWarning, stacklevel=3)


def load_policy(path: Path, robot: str, trainer, what: str, asset: str | None = None) -> dict[str, Any]:
    """``{"params", "normalizer"}`` of a checkpoint, checked against ``robot`` and the network and
    observation sizes of ``trainer``; each refusal names the file and the leaf. ``what`` names
    the config key in messages. With ``asset`` (the MJCF the experiment trains ``robot`` on) it
    warns when the checkpoint was trained on another version of it."""
    path = Path(path)
    ckpt = artifacts.load_checkpoint(path)
    found = ckpt["meta"].get("robot")
    if found != robot:
        raise CheckpointError(f"{what} {path} is a {found!r} policy; this experiment needs a {robot!r} one")
    if asset is not None:
        warn_if_model_changed(path, ckpt["meta"], asset)
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
    return load_policy(Path(cfg.source_checkpoint), cfg.source.robot, program.source_trainer, "source_checkpoint",
                       cfg.source.env.asset)


def load_init_target(cfg: ExperimentConfig, program: Program) -> Any:
    """``{"params", "normalizer"}`` of ``cfg.init_checkpoint`` (a target checkpoint), or None."""
    if not cfg.init_checkpoint:
        return None
    return load_policy(Path(cfg.init_checkpoint), cfg.target.robot, program.target_trainers[cfg.target.robot],
                       "init_checkpoint", cfg.targets[cfg.target.robot].env.asset)
