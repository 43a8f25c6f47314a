"""PPO as one jitted program: ``make_train(env, ppo, network) -> Trainer``.

``trainer.train(key, hparams, frozen, params) -> (TrainState, metrics)`` runs
``ppo.num_iterations`` iterations as a ``lax.scan``; each iteration is a rollout scan
(``unroll_length`` vmapped env steps) followed by an SGD scan over epochs x minibatches.
Everything is a pure function of named pytrees, so ``vmap`` batches seeds, hyperparameters and
freeze masks, and the PTRL program (``program.py``) chains source and target training inside a
single ``jit``. No I/O happens here; the optional ``progress`` hook is a ``jax.debug.callback``
that the caller supplies.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from envs.base import StepInfo
from ptrl_jax.core import distributions, normalization
from ptrl_jax.config import NetworkConfig, PPOConfig, PPOHparams
from ptrl_jax.core.freeze import masked
from ptrl_jax.core.losses import LossInputs, compute_gae, ppo_loss
from ptrl_jax.core.networks import init_actor_critic, policy_apply, value_apply
from ptrl_jax.core.optim import (
    adaptive_kl_learning_rate,
    apply_updates,
    chain,
    clip_by_global_norm,
    scale_by_adam,
)
from ptrl_jax.core.types import Mask, Observation, Params, PRNGKey, Transition

ProgressFn = Callable[[dict], None]


class EpisodeStats(NamedTuple):
    """Per-env episode accumulators. ``last_*`` hold each env's most recent finished episode,
    the rolling window rsl_rl reports (its mean over envs is the logged episode reward)."""

    running_return: jax.Array
    running_length: jax.Array
    running_terms: dict
    last_return: jax.Array
    last_length: jax.Array
    last_terms: dict
    finished: jax.Array
    """Episodes finished per env since the start of training."""


class RolloutCarry(NamedTuple):
    """What the rollout's scan carries from one env step to the next."""

    env_state: Any
    episodes: EpisodeStats
    stats: dict
    """Observation statistics gathered this rollout (the normaliser in use stays fixed)."""
    key: PRNGKey


class TrainState(NamedTuple):
    params: Params
    opt_state: Any
    learning_rate: jax.Array
    """Current (adaptive) learning rate."""
    normalizer: dict
    """RunningStats per observation key."""
    env_state: Any
    episodes: EpisodeStats
    key: PRNGKey
    iteration: jax.Array
    env_steps: jax.Array
    hparams: PPOHparams
    frozen: Mask
    """Freeze mask (True = frozen), shaped like params."""
    run_id: jax.Array
    """Which vmapped run this is (variant * seeds + seed); tags progress callbacks."""


class Trainer(NamedTuple):
    init_params: Callable[[PRNGKey], Params]
    init: Callable[..., TrainState]
    iteration: Callable[[TrainState], tuple[TrainState, dict]]
    train: Callable[..., tuple[TrainState, dict]]
    update: Callable[..., tuple[tuple, dict]]
    """One iteration's SGD on a given batch (the update half of ``iteration``; benchmarks time it)."""
    observation_sizes: dict


def make_optimizer(frozen: Mask, max_grad_norm) -> Any:
    return masked(chain(clip_by_global_norm(max_grad_norm), scale_by_adam()), frozen)


def normalize_obs(normalizer: dict, obs: Observation, enabled: bool) -> Observation:
    if not enabled:
        return obs
    return {k: normalization.normalize(normalizer[k], v) for k, v in obs.items()}


def _tree_where(cond, a, b):
    return jax.tree.map(lambda x, y: jnp.where(cond, x, y), a, b)


def make_train(
    env: Any,
    ppo: PPOConfig,
    network: NetworkConfig,
    progress: ProgressFn | None = None,
) -> Trainer:
    """Build the PPO trainer for one (unbatched) env. ``progress`` receives a dict of scalars
    each iteration through ``jax.debug.callback`` (the program stays one compiled graph)."""
    obs_shapes = jax.eval_shape(env.reset, jax.random.PRNGKey(0)).obs
    obs_sizes = {k: int(v.shape[-1]) for k, v in obs_shapes.items()}
    action_size = env.action_size
    reward_names = [f"reward/{k}" for k in env.reward_names]
    reset_fn = jax.vmap(env.reset)
    step_fn = jax.vmap(env.step)

    def init_params(key: PRNGKey) -> Params:
        return init_actor_critic(key, network, obs_sizes["state"], obs_sizes["privileged_state"], action_size)

    def init(key: PRNGKey, hparams: PPOHparams, frozen: Mask, params: Params, run_id=0,
             normalizer: dict | None = None) -> TrainState:
        """``normalizer``: starting statistics (a transfer's); fresh when None."""
        key, env_key = jax.random.split(key)
        env_state = reset_fn(jax.random.split(env_key, ppo.num_envs))
        n = ppo.num_envs
        zeros = jnp.zeros(n)
        terms = {k: zeros for k in reward_names}
        return TrainState(
            params=params,
            opt_state=make_optimizer(frozen, hparams.max_grad_norm).init(params),
            learning_rate=jnp.asarray(hparams.learning_rate, jnp.float32),
            normalizer=normalizer if normalizer is not None else {k: normalization.init(s) for k, s in obs_sizes.items()},
            env_state=env_state,
            episodes=EpisodeStats(zeros, zeros, terms, zeros, zeros, terms, zeros),
            key=key,
            iteration=jnp.zeros((), jnp.int32),
            env_steps=jnp.zeros((), jnp.int32),
            hparams=hparams,
            frozen=frozen,
            run_id=jnp.asarray(run_id, jnp.int32),
        )

    # ----- rollout ---------------------------------------------------------------------------------
    def rollout(state: TrainState):
        def env_step(carry: RolloutCarry, _):
            key, action_key = jax.random.split(carry.key)
            obs = carry.env_state.obs
            obs_n = normalize_obs(state.normalizer, obs, ppo.normalize_observations)
            out = policy_apply(state.params, obs_n, network)
            action = distributions.sample(action_key, out.mean, out.std)
            next_state = step_fn(carry.env_state, action)
            info = StepInfo.of(next_state)
            final_n = normalize_obs(state.normalizer, info.final_obs, ppo.normalize_observations)
            transition = Transition(
                observation=obs_n,
                action=action,
                log_prob=distributions.log_prob(action, out.mean, out.std),
                action_mean=out.mean,
                action_std=out.std,
                reward=next_state.reward,
                termination=info.termination,
                truncation=info.truncation,
                final_observation=final_n,
            )
            stats = {k: normalization.update(carry.stats[k], obs[k]) for k in carry.stats}
            extras = {
                "nonfinite": jnp.sum(info.nonfinite),
                "terms": {k: jnp.mean(v) for k, v in next_state.metrics.items()},
            }
            return RolloutCarry(next_state, _track_episodes(carry.episodes, next_state), stats, key), (transition, extras)

        key, rollout_key = jax.random.split(state.key)
        end, (transitions, extras) = jax.lax.scan(
            env_step,
            RolloutCarry(state.env_state, state.episodes, state.normalizer, rollout_key),
            None,
            length=ppo.unroll_length,
        )
        env_state, episodes, new_stats = end.env_state, end.episodes, end.stats
        return env_state, episodes, new_stats, key, transitions, extras

    # ----- update ------------------------------------------------------------------------------------
    def loss_fn(params, batch: Transition, inputs: LossInputs, hparams: PPOHparams, clip_value):
        out = policy_apply(params, batch.observation, network)
        value = value_apply(params, batch.observation, network)
        terms = ppo_loss(
            out.mean, out.std, value, inputs,
            hparams.clip_epsilon, hparams.value_coef, hparams.entropy_coef, clip_value,
        )
        kl = jnp.mean(distributions.kl_divergence(batch.action_mean, batch.action_std, out.mean, out.std))
        return terms.total, (terms, kl)

    grad_fn = jax.value_and_grad(loss_fn, has_aux=True)

    def make_sgd_step(hp: PPOHparams, frozen: Mask, warming: jax.Array | bool = False):
        """One minibatch's Adam step. ``warming`` (the critic warm-up): the adaptive learning rate
        is held, and the value loss is not clipped (the clip is a trust region for a critic
        whose policy moves; here the policy is held, and the clip would only slow the fit)."""
        optimizer = make_optimizer(frozen, hp.max_grad_norm)
        clip_value = (~jnp.asarray(warming)) if ppo.clip_value_loss else False

        def sgd_step(carry, minibatch):
            params, opt_state, lr = carry
            batch, inputs = minibatch
            (_, (terms, kl)), grads = grad_fn(params, batch, inputs, hp, clip_value)
            if ppo.adaptive_lr:
                # rsl_rl adapts the rate from this minibatch's KL before taking the step.
                # Held while the actor is out of the update (critic warm-up): its KL is then 0, which
                # would otherwise raise the rate step after step to its maximum.
                adapted = adaptive_kl_learning_rate(lr, kl, hp.desired_kl, hp.min_learning_rate, hp.max_learning_rate)
                lr = jnp.where(warming, lr, adapted)
            direction, new_opt_state = optimizer.update(grads, opt_state, params)
            new_params = apply_updates(params, direction, lr)
            # A non-finite gradient skips the update (and is counted) instead of poisoning params.
            finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(g)) for g in jax.tree.leaves(grads)]))
            params = _tree_where(finite, new_params, params)
            opt_state = _tree_where(finite, new_opt_state, opt_state)
            metrics = {
                "loss/total": terms.total, "loss/policy": terms.policy, "loss/value": terms.value,
                "loss/entropy": terms.entropy, "loss/clip_fraction": terms.clip_fraction,
                "kl": kl, "skipped_updates": 1.0 - finite.astype(jnp.float32),
            }
            return (params, opt_state, lr), metrics

        return sgd_step

    def hold_closing_noise(state: TrainState) -> tuple[TrainState, Mask]:
        """In the stage's last ``final_noise_iterations``, set the policy std to
        ``final_noise_std`` and leave it out of the update (the mask freezes it, like a frozen
        layer; ``state.frozen``, the run's PTRL mask, is not changed). The checkpoint's log-std
        is then the std the policy last acted with."""
        if not ppo.final_noise_iterations:  # static: programs without the phase are unchanged
            return state, state.frozen
        closing = state.iteration >= ppo.num_iterations - ppo.final_noise_iterations
        log_std = state.params["log_std"]
        log_std = jnp.where(closing, jnp.log(state.hparams.final_noise_std).astype(log_std.dtype), log_std)
        frozen = {**state.frozen, "log_std": state.frozen["log_std"] | closing}
        return state._replace(params={**state.params, "log_std": log_std}), frozen

    def update(params: Params, opt_state: Any, learning_rate: jax.Array, hp: PPOHparams, frozen: Mask,
               batch: Transition, inputs: LossInputs, key: PRNGKey, warming: jax.Array | bool = False):
        """The SGD of one iteration: ``ppo.num_epochs`` passes over ``batch`` (flattened to
        ``[batch_size, ...]``), each shuffled into ``ppo.num_minibatches`` minibatches, one Adam
        step per minibatch (frozen leaves masked). ``warming``: a critic warm-up iteration
        (``make_sgd_step``). Returns ``((params, opt_state, lr), metrics)`` with metrics per epoch
        and minibatch."""
        sgd_step = make_sgd_step(hp, frozen, warming)

        def epoch(carry, epoch_key):
            perm = jax.random.permutation(epoch_key, ppo.batch_size)
            shuffle = lambda x: x[perm].reshape((ppo.num_minibatches, ppo.minibatch_size) + x.shape[1:])  # noqa: E731
            minibatches = jax.tree.map(shuffle, (batch, inputs))
            return jax.lax.scan(sgd_step, carry, minibatches)

        return jax.lax.scan(epoch, (params, opt_state, learning_rate), jax.random.split(key, ppo.num_epochs))

    def hold_actor_for_critic_warmup(state: TrainState, frozen: Mask) -> tuple[Mask, jax.Array]:
        """In the stage's first ``hparams.critic_warmup`` iterations, leave the actor and its
        log-std out of the update (``frozen`` is the update's mask; the run's own is not changed).
        Returns the mask and whether this iteration warms up (``make_sgd_step`` then holds the
        learning rate and fits the value unclipped)."""
        warming = state.iteration < state.hparams.critic_warmup
        policy = lambda tree: jax.tree.map(lambda m: m | warming, tree)  # noqa: E731
        return {**frozen, "actor": policy(frozen["actor"]), "log_std": policy(frozen["log_std"])}, warming

    def iteration(state: TrainState) -> tuple[TrainState, dict]:
        hp = state.hparams
        state, update_frozen = hold_closing_noise(state)
        update_frozen, warming = hold_actor_for_critic_warmup(state, update_frozen)
        env_state, episodes, new_stats, key, tr, extras = rollout(state)

        values = value_apply(state.params, tr.observation, network)
        next_values = value_apply(state.params, tr.final_observation, network)
        next_values = jnp.where(tr.termination > 0, 0.0, next_values)
        advantages, returns = compute_gae(
            tr.reward, values, next_values, tr.termination, tr.truncation, hp.gamma, hp.gae_lambda
        )
        advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)

        flat = lambda x: x.reshape((-1,) + x.shape[2:])  # noqa: E731
        batch = jax.tree.map(flat, tr)
        inputs = LossInputs(
            action=batch.action, old_log_prob=batch.log_prob, old_value=flat(values),
            advantage=flat(advantages), target_return=flat(returns),
        )
        key, sgd_key = jax.random.split(key)
        (params, opt_state, lr), sgd_metrics = update(
            state.params, state.opt_state, state.learning_rate, hp, update_frozen, batch, inputs, sgd_key, warming
        )

        env_steps = state.env_steps + ppo.batch_size
        has_finished = episodes.finished > 0
        denom = jnp.maximum(jnp.sum(has_finished), 1.0)
        ep_mean = lambda x: jnp.sum(jnp.where(has_finished, x, 0.0)) / denom  # noqa: E731
        metrics = {
            "iteration": state.iteration + 1,
            "env_steps": env_steps,
            "episode_reward": ep_mean(episodes.last_return),
            "episode_length": ep_mean(episodes.last_length),
            "episodes_finished": jnp.sum(episodes.finished),
            "step_reward": jnp.mean(tr.reward),
            "learning_rate": lr,
            "noise_std": jnp.mean(jnp.exp(state.params["log_std"])),  # the std this iteration acted with
            # How well the critic (before this update) predicted the rollout's GAE returns.
            "value_explained_variance": explained_variance(values, returns),
            "critic_warmup": warming.astype(jnp.float32),
            "nonfinite_states": jnp.sum(extras["nonfinite"]),
            **{f"episode_{k}": ep_mean(v) for k, v in episodes.last_terms.items()},
            # Each term per env step over this rollout: unlike the episode terms, which change only
            # as episodes end (every 1,000 steps once envs survive), it moves every iteration.
            **{f"step_{k}": jnp.mean(v) for k, v in extras["terms"].items()},
            **{k: jnp.mean(v) for k, v in sgd_metrics.items()},
        }
        metrics["skipped_updates"] = jnp.sum(sgd_metrics["skipped_updates"])
        if progress is not None:
            jax.debug.callback(
                progress,
                {"run_id": state.run_id, **{k: metrics[k] for k in ("iteration", "env_steps", "episode_reward")}},
            )
        new_state = TrainState(
            params=params, opt_state=opt_state, learning_rate=lr,
            normalizer=new_stats if ppo.normalize_observations else state.normalizer,
            env_state=env_state, episodes=episodes, key=key, iteration=state.iteration + 1,
            env_steps=env_steps, hparams=hp, frozen=state.frozen, run_id=state.run_id,
        )
        return new_state, metrics

    def train(key: PRNGKey, hparams: PPOHparams, frozen: Mask, params: Params, run_id=0):
        state = init(key, hparams, frozen, params, run_id)
        return jax.lax.scan(lambda s, _: iteration(s), state, None, length=ppo.num_iterations)

    return Trainer(init_params, init, iteration, train, update, obs_sizes)


def explained_variance(values: jax.Array, returns: jax.Array) -> jax.Array:
    """1 - Var[returns - values] / Var[returns] over every entry: 1 for a critic that predicts
    the returns exactly, 0 for one no better than their mean, negative for worse; 0 when the
    returns do not vary."""
    var = jnp.var(returns)
    return jnp.where(var > 0, 1.0 - jnp.var(returns - values) / jnp.where(var > 0, var, 1.0), 0.0)


def _track_episodes(ep: EpisodeStats, state) -> EpisodeStats:
    done = state.done > 0
    running_return = ep.running_return + state.reward
    running_length = ep.running_length + 1.0
    running_terms = {k: ep.running_terms[k] + state.metrics[k] for k in ep.running_terms}
    return EpisodeStats(
        running_return=jnp.where(done, 0.0, running_return),
        running_length=jnp.where(done, 0.0, running_length),
        running_terms={k: jnp.where(done, 0.0, v) for k, v in running_terms.items()},
        last_return=jnp.where(done, running_return, ep.last_return),
        last_length=jnp.where(done, running_length, ep.last_length),
        last_terms={k: jnp.where(done, running_terms[k], ep.last_terms[k]) for k in running_terms},
        finished=ep.finished + done,
    )
