"""Configuration: frozen dataclasses with a docstring per field.

Static fields (sizes, counts) are closed over by ``jit``. The dynamic PPO hyperparameters are
gathered into ``PPOHparams``, a pytree of arrays that can be vmapped, like the freeze mask.
Validation happens in ``__post_init__``, so an impossible config fails before anything compiles.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import jax.numpy as jnp

from envs.semantics import KNEE_CONVENTIONS
from ptrl_jax.core.freeze import (FREEZE_PRESETS, MODE_SEPARATOR, RATIO_PREFIX, TRANSFER_MODES, is_semantic, ratio_name,
                                  variant, with_mode)


class ConfigError(ValueError):
    """A bad key, value or preset. The message names what is wrong."""


THRESHOLD_CURVES = ("episode_reward", "step_reward")
"""The logged curves ``report.threshold_metric`` may name, whole or one reward term of them."""


@dataclass(frozen=True)
class NetworkConfig:
    """Actor and critic MLPs (paper Fig. 3: 512-256-128, ELU)."""

    actor_hidden: tuple[int, ...] = (512, 256, 128)
    """Actor hidden sizes; the paper's L1 is hidden[0] x hidden[1], L2 hidden[1] x hidden[2]."""
    critic_hidden: tuple[int, ...] = (512, 256, 128)
    """Critic hidden sizes."""
    activation: str = "elu"
    """Hidden activation: elu, tanh or relu."""
    init_noise_std: float = 1.0
    """Initial policy standard deviation (rsl_rl: 1.0)."""
    source_init_noise_std: float = 0.0
    """The source stage's initial policy std; 0: ``init_noise_std``. Lets a target robot explore
    with its own recipe's std (A1: 1.0) while the source trains with its own (Go2: 0.5)."""

    def __post_init__(self):
        if len(self.actor_hidden) != 3:
            raise ValueError(
                f"network.actor_hidden must have 3 layers (L1 and L2 are its hidden-to-hidden "
                f"weights), got {self.actor_hidden}"
            )
        if any(h <= 0 for h in (*self.actor_hidden, *self.critic_hidden)):
            raise ValueError("network hidden sizes must be positive")
        if self.activation not in ("elu", "tanh", "relu"):
            raise ValueError(f"network.activation must be elu, tanh or relu, got {self.activation!r}")
        if self.init_noise_std <= 0:
            raise ValueError(f"network.init_noise_std must be > 0, got {self.init_noise_std}")
        if self.source_init_noise_std < 0:
            raise ValueError(f"network.source_init_noise_std must be >= 0 (0: init_noise_std), got {self.source_init_noise_std}")

    @property
    def source(self) -> "NetworkConfig":
        """The network of the source stage (its own initial std)."""
        if not self.source_init_noise_std:
            return self
        return dataclasses.replace(self, init_noise_std=self.source_init_noise_std, source_init_noise_std=0.0)


class PPOHparams(NamedTuple):
    """The dynamic PPO hyperparameters: arrays, so they can be vmapped across variants."""

    learning_rate: Any
    clip_epsilon: Any
    value_coef: Any
    entropy_coef: Any
    gamma: Any
    gae_lambda: Any
    max_grad_norm: Any
    desired_kl: Any
    min_learning_rate: Any
    max_learning_rate: Any
    final_noise_std: Any
    critic_warmup: Any = 0.0
    """Iterations at the stage's start in which only the critic learns: the actor and its log-std
    are left out of the update (masked like a frozen layer) and the adaptive learning rate is held.
    Not a ``PPOConfig`` field: the program sets it per target variant from
    ``transfer.critic_warmup`` (transferring variants only; 0 elsewhere)."""


@dataclass(frozen=True)
class PPOConfig:
    """PPO, paper Table III plus rsl_rl's defaults for what the table leaves out."""

    num_envs: int = 1024
    """Parallel environments (static)."""
    unroll_length: int = 24
    """Steps per environment per iteration (rsl_rl: 24)."""
    num_epochs: int = 5
    """Passes over each batch (rsl_rl: 5)."""
    num_minibatches: int = 4
    """Minibatches per epoch (rsl_rl: 4)."""
    num_iterations: int = 100
    """PPO iterations (rollout + update) for this stage."""
    normalize_observations: bool = True
    """Running mean/std normalisation of actor and critic inputs."""
    clip_value_loss: bool = True
    """Clipped value loss, as rsl_rl."""
    adaptive_lr: bool = True
    """Adaptive-KL learning rate (paper: 'lr 1e-3 adaptive'); False keeps it fixed."""
    learning_rate: float = 1e-3
    """Initial learning rate (Table III)."""
    clip_epsilon: float = 0.2
    """PPO ratio clip (Table III); also the value clip."""
    value_coef: float = 1.0
    """Value-loss coefficient (Table III)."""
    entropy_coef: float = 0.01
    """Entropy bonus (rsl_rl: 0.01)."""
    gamma: float = 0.998
    """Discount (Table III)."""
    gae_lambda: float = 0.95
    """GAE lambda (Table III)."""
    max_grad_norm: float = 1.0
    """Global-norm gradient clip (rsl_rl: 1.0)."""
    desired_kl: float = 0.01
    """Adaptive-KL target (rsl_rl: 0.01)."""
    min_learning_rate: float = 1e-5
    """Lower bound of the adaptive learning rate."""
    max_learning_rate: float = 1e-2
    """Upper bound of the adaptive learning rate."""
    final_noise_iterations: int = 0
    """Closing iterations of the stage run with the policy std held at ``final_noise_std`` (the
    log-std is set and not learned); 0 keeps the std learned throughout, as rsl_rl does. Why:
    at CPU budgets PPO can learn a gait that only the exploration noise drives, so the mean
    action stands (README, Go2); training on with less noise makes the mean action walk."""
    final_noise_std: float = 0.2
    """The policy std of the closing ``final_noise_iterations`` (per action, before action_scale)."""

    def __post_init__(self):
        for name in ("num_envs", "unroll_length", "num_epochs", "num_minibatches", "num_iterations"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"ppo.{name} must be >= 1, got {getattr(self, name)}")
        batch = self.num_envs * self.unroll_length
        if batch % self.num_minibatches:
            raise ValueError(
                f"ppo.num_envs * ppo.unroll_length = {batch} is not divisible by "
                f"ppo.num_minibatches = {self.num_minibatches}"
            )
        if not 0.0 < self.gamma <= 1.0:
            raise ValueError(f"ppo.gamma must be in (0, 1], got {self.gamma}")
        if not 0.0 <= self.gae_lambda <= 1.0:
            raise ValueError(f"ppo.gae_lambda must be in [0, 1], got {self.gae_lambda}")
        for name in ("learning_rate", "clip_epsilon", "max_grad_norm", "desired_kl", "min_learning_rate"):
            if getattr(self, name) <= 0:
                raise ValueError(f"ppo.{name} must be > 0, got {getattr(self, name)}")
        if not 0 <= int(self.final_noise_iterations) <= int(self.num_iterations):
            raise ValueError(
                f"ppo.final_noise_iterations must lie in [0, ppo.num_iterations={self.num_iterations}], "
                f"got {self.final_noise_iterations}"
            )
        if self.final_noise_std <= 0:
            raise ValueError(f"ppo.final_noise_std must be > 0, got {self.final_noise_std}")
        if self.value_coef < 0 or self.entropy_coef < 0:
            raise ValueError("ppo.value_coef and ppo.entropy_coef must be >= 0")
        if not self.min_learning_rate <= self.learning_rate <= self.max_learning_rate:
            raise ValueError(
                f"ppo.learning_rate={self.learning_rate} must lie in [ppo.min_learning_rate="
                f"{self.min_learning_rate}, ppo.max_learning_rate={self.max_learning_rate}]"
            )

    @property
    def batch_size(self) -> int:
        return self.num_envs * self.unroll_length

    @property
    def minibatch_size(self) -> int:
        return self.batch_size // self.num_minibatches

    @property
    def env_steps_per_iteration(self) -> int:
        return self.batch_size

    def hparams(self) -> PPOHparams:
        """This stage's dynamic hyperparameters; fields that are not PPO settings
        (``critic_warmup``) take their defaults."""
        defaults = PPOHparams._field_defaults
        return PPOHparams(
            *(jnp.asarray(getattr(self, f, defaults.get(f)), jnp.float32) for f in PPOHparams._fields)
        )


@dataclass(frozen=True)
class StageConfig:
    """One training stage on one robot (the source SLRT or the target TLRT)."""

    robot: str = "go2"
    """Robot name from the env registry."""
    ppo: PPOConfig = field(default_factory=PPOConfig)
    """PPO settings of this stage."""
    env: Any = None
    """The robot's environment config (its family's dataclass); filled from the registry."""


@dataclass(frozen=True)
class ReportConfig:
    """How report.md summarises the curves."""

    threshold_fraction: float = 0.9
    """Time-to-threshold uses this fraction of the scratch baseline's final value of
    ``threshold_metric``."""
    threshold_metric: str = "episode_reward"
    """The logged curve that time-to-threshold reads: ``episode_reward`` (the paper's measure), or
    one reward term, ``episode_reward/<term>``. ``episode_reward/tracking_lin_vel`` is earned
    only by following the velocity command, so a policy that stands cannot reach its threshold
    (docs/table4.md: on A1, standing earns 90 % of a walking policy's episode reward). The
    episode curves move only as episodes end, which once envs survive whole episodes is every
    ``episode_length / unroll_length`` iterations; ``step_reward`` and ``step_reward/<term>``
    (the reward, or one term, per env step of each rollout) move every iteration."""
    final_window: int = 10
    """'Final reward' is the mean over this many last iterations."""
    zero_shot_check: bool = True
    """Run the robot family's walking check on each transferred initialisation (and scratch's)
    before any fine-tuning, seed 0, in MuJoCo C (a few seconds per check), for report.md's
    zero-shot table, and on the source policy (its written ``source.npz``; none with
    ``checkpoint=false``), for the report's source line: a source that fails its own check
    carries no gait. The first rollout's reward is reported either way."""
    zero_shot_seconds: float = 20.0
    """Length of each zero-shot check rollout, s (the walking check's own 20 s by default)."""
    semantic_preset: str = ""
    """The semantic variant that Table IV reports in its semantic column, named before the runs
    (``L2@semantic_output``): the preset rule of docs/transfer.md, which the source presets set
    per source family. Empty: the semantic variant that reached the threshold soonest, chosen
    after the fact on the seeds it is reported on (the row says which)."""

    def __post_init__(self):
        base, _, term = self.threshold_metric.partition("/")
        if base not in THRESHOLD_CURVES or (not term and "/" in self.threshold_metric):
            raise ValueError(f"report.threshold_metric must be one of {list(THRESHOLD_CURVES)}, optionally "
                             f"with /<reward term> (episode_reward/tracking_lin_vel), got {self.threshold_metric!r}")
        if not 0.0 < self.threshold_fraction <= 1.5:
            raise ValueError(f"report.threshold_fraction must be in (0, 1.5], got {self.threshold_fraction}")
        if self.final_window < 1:
            raise ValueError("report.final_window must be >= 1")
        if self.zero_shot_seconds <= 0:
            raise ValueError(f"report.zero_shot_seconds must be > 0, got {self.zero_shot_seconds}")
        if self.semantic_preset:
            try:
                variant(self.semantic_preset)
            except ValueError as e:
                raise ValueError(f"report.semantic_preset: {e}") from None
            if not is_semantic(self.semantic_preset):
                raise ValueError(f"report.semantic_preset must name a semantic variant (<preset>@semantic_actor, "
                                 f"...), got {self.semantic_preset!r}")


@dataclass(frozen=True)
class TransferConfig:
    """How transferring variants initialise the target from the source (``transfer=semantic``
    on the command line is short for ``transfer.mode=semantic``)."""

    mode: str = "paper"
    """``paper``: copy the actor's L1 and L2, everything else fresh (the paper's transfer).
    ``semantic``: map the whole agent (input and output layers, log-std, normaliser, critic)
    through the robots' declared observations and joint roles (``ptrl_jax.core.semantic``).
    ``semantic_actor``: the same, but the critic starts fresh. ``semantic_input``: only the
    actor's input layer and the normaliser mapped, its hidden layers copied, output layer, log-std
    and critic fresh (the paper's transfer with a mapped input layer). ``semantic_output``: its
    complement, only the output layer and log-std mapped, the input layer, normaliser and critic
    fresh, the hidden layers copied (the paper's transfer with a mapped output layer). A variant named
    ``<preset>@<mode>`` picks its own mode."""
    joint_map: tuple[str, ...] = ()
    """Overrides of the role-based joint pairs for semantic transfers, ``"<target joint>:<source
    joint>"`` (``-<source joint>`` flips the sign, ``none`` leaves the joint unmapped)."""
    unmapped_blocks: tuple[str, ...] = ()
    """Target observation blocks (``foot_contact``, ``base_height``, ...) left unmapped by semantic
    transfers: their input weights start at zero."""
    knee: str = "axis"
    """How semantic transfers sign knees. ``axis``: by their axes, so a mapped knee turns the
    same way (Go2's knee flexion arrives as extension on a knee that points the other way, as on
    ANYmal's hind legs, XBot-L and TRON1... see docs/transfer.md). ``flexion``: by their flexion
    directions, so a knee flexes where its source's flexes (``envs.semantics.knee_flexion_signs``).
    Where two knees point the same way the two agree."""
    noise_std: float = 0.0
    """The policy std semantic transfers start from: 0 carries the source's (per joint, scaled
    like its action); a positive value starts every joint's std there instead. A source trained
    with a closing phase ends at its ``final_noise_std`` (0.2), which may leave the target too
    little exploration (docs/table4.md)."""
    critic_warmup: int = 0
    """Target iterations at the start of every transferring variant in which only the critic
    learns: the transferred actor and its log-std act unchanged (the adaptive learning rate is held
    too) while the critic fits the target's returns. A fresh critic's values are far from them at
    first, and PPO's first actor updates then follow noisy advantages; 0 (the default, the paper's
    schedule) updates the actor from the first iteration. Scratch variants never warm up. The
    warm-up's env steps count against the variant like any others (docs/transfer.md)."""

    def __post_init__(self):
        if self.mode not in TRANSFER_MODES:
            raise ValueError(f"transfer.mode must be one of {list(TRANSFER_MODES)}, got {self.mode!r}")
        if self.knee not in KNEE_CONVENTIONS:
            raise ValueError(f"transfer.knee must be one of {list(KNEE_CONVENTIONS)}, got {self.knee!r}")
        if self.noise_std < 0:
            raise ValueError(f"transfer.noise_std must be >= 0 (0 carries the source's std), got {self.noise_std}")
        if int(self.critic_warmup) != self.critic_warmup or self.critic_warmup < 0:
            raise ValueError(f"transfer.critic_warmup must be a whole number of iterations >= 0, got {self.critic_warmup}")


@dataclass(frozen=True)
class ExperimentConfig:
    """A PTRL experiment: train the source, transfer, fine-tune every target variant."""

    name: str = "go2_to_xbot"
    """Experiment name; outputs go to runs/<name>/<timestamp>/."""
    scale: str = "cpu"
    """Preset scale: smoke (tests, < 2 min), cpu (<= 30 min on 2 cores), paper (GPU)."""
    seed: int = 0
    """Root PRNG seed of the whole program."""
    seeds: int = 1
    """Target seeds per freeze preset, batched with vmap."""
    source: StageConfig = field(default_factory=StageConfig)
    """Source robot training (SLRT)."""
    target: StageConfig = field(default_factory=lambda: StageConfig(robot="xbot_l"))
    """Target robot fine-tuning (TLRT)."""
    extra_targets: tuple[str, ...] = ()
    """More target robots, fine-tuned from the same trained source in the same program
    (exp=xbot_to_all). Each runs every freeze preset and seed with ``target.ppo`` and its
    robot's registry env config."""
    freeze_presets: tuple[str, ...] = ("none", "L1", "L2", "L1+L2", "scratch")
    """Target variants: what is transferred and frozen (scratch = no transfer, the baseline)."""
    freeze_ratio: tuple[float, ...] = ()
    """Continuous freeze ratios rho in [0, 1], run as more target variants beside
    ``freeze_presets`` (named ``rho<r>``): L1 and L2 transferred and the first ceil(rho n) output
    units of each frozen (``freeze.ratio_preset``)."""
    transfer: TransferConfig = field(default_factory=TransferConfig)
    """How transferring variants initialise the target (paper or semantic)."""
    engine: str = "auto"
    """Physics engine of every stage: ``mjx`` (in JAX; GPU or CPU), ``mujoco`` (MuJoCo C's
    batched stepper on the CPU threads, through a host callback; ``envs.mujoco_engine``), or
    ``auto``: ``mujoco`` where jax runs on the CPU, ``mjx`` on a GPU (docs/engines.md)."""
    devices: str = "1"
    """Local devices the program runs on: a count, or ``all``. With more than one, every stage's
    env batch is split across them and XLA partitions the one program (``ptrl_jax/core/sharding.py``);
    each stage's ``num_envs`` must divide by the count."""
    init_checkpoint: str = ""
    """A target checkpoint to start every transferring variant from (``python -m
    ptrl_jax.transfer`` writes one; any checkpoint of the target robot serves): no source is
    trained or mapped, and ``scratch`` still starts fresh. One target robot only."""
    source_checkpoint: str = ""
    """A trained source (``source.npz`` of an earlier run) to transfer from instead of training
    one: the source stage is skipped, so ablations over target variants reuse one source."""
    network: NetworkConfig = field(default_factory=NetworkConfig)
    """Actor-critic sizes, shared by source and target so the hidden layers transfer."""
    report: ReportConfig = field(default_factory=ReportConfig)
    """Report settings."""
    runs_dir: str = "runs"
    """Where run folders are created."""
    tensorboard: bool = False
    """Also write the metrics as TensorBoard event files, one folder per run under
    ``tensorboard/`` of the run folder (``ptrl_jax/io/tensorboard.py``), when metrics.csv is written."""
    progress: bool = True
    """Show a progress bar per stage (host callback; no recompilation)."""
    checkpoint: bool = True
    """Write source.npz and target_<preset>_seed<k>.npz."""
    checkpoint_every: int = 10
    """Save the whole program state (resume_state.npz) every this many iterations; the program
    runs in slices this long, so it is also how soon Ctrl-C takes effect. 0: one slice, no
    periodic saves."""

    def __post_init__(self):
        if self.scale not in SCALES:
            raise ValueError(f"scale must be one of {SCALES}, got {self.scale!r}")
        if self.checkpoint_every < 0:
            raise ValueError(f"checkpoint_every must be >= 0, got {self.checkpoint_every}")
        if self.seeds < 1:
            raise ValueError(f"seeds must be >= 1, got {self.seeds}")
        if not self.freeze_presets and not self.freeze_ratio:
            raise ValueError("freeze_presets and freeze_ratio are both empty: name at least one variant")
        bad = []
        for p in self.freeze_presets:
            try:
                variant(p)
            except ValueError:
                if p.partition(MODE_SEPARATOR)[1]:
                    raise  # a known base with a bad mode suffix: its message names the mode
                bad.append(p)
        if bad:
            raise ValueError(f"freeze_presets: unknown {bad}; choose from {list(FREEZE_PRESETS)} or "
                             f"{RATIO_PREFIX}<r> with r in [0, 1], optionally with {MODE_SEPARATOR}<mode>, "
                             f"a mode of {list(TRANSFER_MODES)}")
        from envs.mujoco_engine import ENGINE_CHOICES

        if self.engine not in ENGINE_CHOICES:
            raise ValueError(f"engine must be one of {list(ENGINE_CHOICES)}, got {self.engine!r}")
        if self.devices != "all" and not (str(self.devices).isdigit() and int(self.devices) >= 1):
            raise ValueError(f"devices must be all or a positive number of devices, got {self.devices!r}")
        if self.init_checkpoint and self.source_checkpoint:
            raise ValueError("init_checkpoint and source_checkpoint exclude each other: the first starts "
                             "the target from a transferred checkpoint, the second transfers from a source")
        if self.init_checkpoint and self.extra_targets:
            raise ValueError(f"init_checkpoint initialises one target robot; extra_targets={list(self.extra_targets)} "
                             f"would need one each")
        out_of_range = [r for r in self.freeze_ratio if not 0.0 <= float(r) <= 1.0]
        if out_of_range:
            raise ValueError(f"freeze_ratio: {out_of_range} outside [0, 1] (the frozen fraction of L1 and L2)")
        if len(set(self.variants)) != len(self.variants):
            raise ValueError(f"freeze_presets / freeze_ratio repeat a variant: {list(self.variants)}")
        import envs

        unknown = [r for r in self.extra_targets if r not in envs.robot_names()]
        if unknown:
            raise ValueError(f"extra_targets: unknown robots {unknown}; known: {envs.robot_names()}")
        robots = (self.target.robot, *self.extra_targets)
        if len(set(robots)) != len(robots):
            raise ValueError(f"target.robot and extra_targets repeat a robot: {list(robots)}")
        if self.transfer.critic_warmup >= self.target.ppo.num_iterations:
            raise ValueError(f"transfer.critic_warmup={self.transfer.critic_warmup} must be below "
                             f"target.ppo.num_iterations={self.target.ppo.num_iterations}: the transferred "
                             f"actor would never be fine-tuned")

    @property
    def variants(self) -> tuple[str, ...]:
        """Every target variant, in program order: the presets, then the freeze ratios."""
        mode = self.transfer.mode
        named = [variant(p).name if MODE_SEPARATOR in p else with_mode(p, mode) for p in self.freeze_presets]
        return (*named, *(with_mode(ratio_name(r), mode) for r in self.freeze_ratio))

    @property
    def trains_source(self) -> bool:
        """Whether the program trains a source: not when it starts from ``source_checkpoint``, and
        not when no variant transfers (``freeze_presets=[scratch]``: each target robot trained
        from scratch alone, the per-robot runs of the README)."""
        return (not self.source_checkpoint and not self.init_checkpoint
                and any(variant(v).transfer for v in self.variants))

    @property
    def semantic(self) -> bool:
        """Whether any variant transfers semantically (the program then builds the map)."""
        return any(variant(v).mode_index >= 2 for v in self.variants)

    @property
    def source_iterations(self) -> int:
        """Source iterations the program runs: 0 when it trains no source (``trains_source``)."""
        return self.source.ppo.num_iterations if self.trains_source else 0

    @property
    def targets(self) -> dict[str, StageConfig]:
        """Every target stage by robot: ``target`` first, then ``extra_targets`` (each with
        ``target.ppo`` and its registry env config)."""
        import envs  # the trainer may import envs (never the reverse)

        extra = {r: StageConfig(robot=r, ppo=self.target.ppo, env=envs.default_config(r))
                 for r in self.extra_targets}
        return {self.target.robot: self.target, **extra}


SCALES = ("smoke", "cpu", "paper")
