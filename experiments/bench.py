"""Throughput benchmark (not a test): ``python experiments/bench.py [envs=1024] [iterations=3] [robot=go2|all]``.

``robot=all`` prints, per registered robot, compile time and raw env steps/s only.

Prints, for Go2 at ``envs`` parallel environments, measured side by side in one process:
  - raw vmapped env steps/s (zero actions, no learning; a scan of the env step), and the same
    with random actions,
  - the rollout (env + actor + sampling) and the actor's share of it,
  - training-loop env steps/s with rsl_rl's PPO schedule (24 steps/env, 5 epochs, 4 minibatches),
  - their ratio,
  - the same training loop with the progress callback, and its cost,
  - compile time of the whole go2_to_xbot program (scale=cpu shapes),
  - peak resident memory of the process.
"""

from __future__ import annotations

import platform
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import envs  # noqa: E402
from ptrl_jax.config import NetworkConfig, PPOConfig  # noqa: E402
from ptrl_jax.freeze import empty_mask  # noqa: E402
from ptrl_jax.overrides import load_experiment, parse_cli  # noqa: E402
from ptrl_jax.program import make_program  # noqa: E402
from ptrl_jax.train import make_train  # noqa: E402


def timed(fn, *args, repeats=1):
    out = jax.block_until_ready(fn(*args))  # compile + warm
    t = time.perf_counter()
    for _ in range(repeats):
        out = jax.block_until_ready(fn(*args))
    return out, (time.perf_counter() - t) / repeats


def raw_env_table(n: int, steps: int) -> None:
    """``robot=all``: per registered robot, compile time and raw vmapped env steps/s (random
    actions, N(0, 0.5)) of a scan of ``steps`` env steps at ``n`` envs."""
    print(f"{'robot':10} {'physics':>12} {'compile s':>10} {'env steps/s':>12} {'physics steps/s':>16}")
    for robot in envs.robot_names():
        env = envs.make(robot)
        t = time.perf_counter()
        states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), n))

        def scan(s, key):
            def f(c, k):
                return jax.vmap(env.step)(c, 0.5 * jax.random.normal(k, (n, env.action_size))), None
            return jax.lax.scan(f, s, jax.random.split(key, steps))[0]

        compiled = jax.jit(scan).lower(states, jax.random.PRNGKey(1)).compile()
        compile_s = time.perf_counter() - t
        _, secs = timed(compiled, states, jax.random.PRNGKey(1))
        sps = n * steps / secs
        c = env.config
        print(f"{robot:10} {f'{c.sim_dt * 1e3:g} ms x {c.decimation}':>12} {compile_s:10.1f} {sps:12,.0f} "
              f"{sps * c.decimation:16,.0f}", flush=True)


def main(argv):
    args = parse_cli(argv)
    n = int(args.get("envs", 1024))
    iters = int(args.get("iterations", 3))
    robot = args.get("robot", "go2")
    if robot == "all":
        print(f"machine: {platform.processor() or platform.machine()}, {jax.device_count()} "
              f"{jax.devices()[0].platform} device(s), jax {jax.__version__}; {n} envs, {24 * iters} steps")
        raw_env_table(n, 24 * iters)
        return
    env = envs.make(robot)
    ppo = PPOConfig(num_envs=n, num_iterations=iters)  # rsl_rl schedule: 24 x 5 epochs x 4 minibatches
    net = NetworkConfig()
    print(f"machine: {platform.processor() or platform.machine()}, {jax.device_count()} {jax.devices()[0].platform} device(s), jax {jax.__version__}")

    # Raw env throughput: the same number of env steps as one training iteration.
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), n))
    zeros = jnp.zeros((n, env.action_size))

    @jax.jit
    def raw(s):
        return jax.lax.scan(lambda c, _: (jax.vmap(env.step)(c, zeros), None), s, None, length=ppo.unroll_length * iters)[0]

    _, raw_s = timed(raw, states)
    raw_sps = n * ppo.unroll_length * iters / raw_s

    # Zero actions flatter "raw": XLA folds the constant into the PD law and the legs barely move.
    @jax.jit
    def raw_random(s, key):
        def f(c, k):
            return jax.vmap(env.step)(c, 0.5 * jax.random.normal(k, (n, env.action_size))), None
        return jax.lax.scan(f, s, jax.random.split(key, ppo.unroll_length * iters))[0]

    _, raw_random_s = timed(raw_random, states, jax.random.PRNGKey(4))
    raw_random_sps = n * ppo.unroll_length * iters / raw_random_s

    def train_sps(progress):
        trainer = make_train(env, ppo, net, progress)
        params = trainer.init_params(jax.random.PRNGKey(1))
        state = jax.jit(trainer.init)(jax.random.PRNGKey(2), ppo.hparams(), empty_mask(params), params)
        run = jax.jit(lambda s: jax.lax.scan(lambda c, _: trainer.iteration(c), s, None, length=iters))
        _, secs = timed(run, state)
        return n * ppo.unroll_length * iters / secs

    # Rollout alone (env step + policy forward + sampling, as in training, no update).
    trainer = make_train(env, ppo, net)
    params = trainer.init_params(jax.random.PRNGKey(1))
    from ptrl_jax import distributions  # noqa: E402
    from ptrl_jax.networks import policy_apply  # noqa: E402

    @jax.jit
    def rollout(s, key):
        def f(c, k):
            out = policy_apply(params, c.obs, net)
            return jax.vmap(env.step)(c, distributions.sample(k, out.mean, out.std)), None
        return jax.lax.scan(f, s, jax.random.split(key, ppo.unroll_length * iters))[0]

    _, rollout_s = timed(rollout, states, jax.random.PRNGKey(3))
    rollout_sps = n * ppo.unroll_length * iters / rollout_s

    @jax.jit
    def actor_only(obs, key):  # the rollout's policy work without the env
        def f(c, k):
            out = policy_apply(params, {"state": c}, net)
            return c + 1e-3 * jnp.tanh(distributions.sample(k, out.mean, out.std)).sum(-1, keepdims=True), None
        return jax.lax.scan(f, obs, jax.random.split(key, ppo.unroll_length * iters))[0]

    _, actor_s = timed(actor_only, states.obs["state"], jax.random.PRNGKey(5))

    train = train_sps(None)
    calls = []
    with_progress = train_sps(lambda d: calls.append(time.monotonic()))

    cfg = load_experiment("go2_to_xbot", ["scale=cpu"])
    program = make_program(cfg)
    t = time.perf_counter()
    jax.jit(program.run).lower(jax.random.PRNGKey(0)).compile()
    compile_s = time.perf_counter() - t
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    print(f"robot {robot}, {n} envs, {iters} iterations of {ppo.unroll_length} steps/env, "
          f"{ppo.num_epochs} epochs x {ppo.num_minibatches} minibatches")
    print(f"raw env steps/s:              {raw_sps:10,.0f}")
    print(f"raw env steps/s, random actions:{raw_random_sps:8,.0f}")
    print(f"rollout (env + policy) steps/s:{rollout_sps:9,.0f}")
    print(f"actor forward + sampling alone: {100 * actor_s / rollout_s:7.0f} % of the rollout time")
    print(f"training env steps/s:         {train:10,.0f}")
    # What the PPO update costs: per sample and epoch, forward + backward of both MLPs is about
    # 3 x 2 x (multiply-adds of one forward pass) FLOPs.
    sizes = lambda i, h, o: [i, *h, o]  # noqa: E731
    macs = lambda s: sum(a * b for a, b in zip(s[:-1], s[1:]))  # noqa: E731
    obs = trainer.observation_sizes
    per_sample = 6 * (macs(sizes(obs["state"], net.actor_hidden, env.action_size))
                      + macs(sizes(obs["privileged_state"], net.critic_hidden, 1)))
    update_s = n * ppo.unroll_length * iters / train - rollout_s
    sgd_flops = per_sample * ppo.batch_size * ppo.num_epochs * iters
    print(f"update share of training:     {100 * update_s / (update_s + rollout_s):10.0f} %  "
          f"(~{sgd_flops / max(update_s, 1e-9) / 1e9:.0f} GFLOP/s in the SGD)")
    print(f"training / raw:               {train / raw_sps:10.2f}")
    print(f"training with progress hook:  {with_progress:10,.0f}  (cost {100 * (1 - with_progress / train):.1f} %)")
    print(f"go2_to_xbot program compile:  {compile_s:10.1f} s (scale=cpu shapes)")
    print(f"peak resident memory:         {peak_mib:10,.0f} MiB")


if __name__ == "__main__":
    main(sys.argv[1:])
