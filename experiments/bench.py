"""Throughput benchmark (not a test): ``python experiments/bench.py [envs=1024] [iterations=3] [robot=go2|all]
[engines=mjx,mujoco] [brax=true]``.

``robot=all`` prints, per registered robot, compile time and raw env steps/s only.

First the machine's limits, measured in the same run: the fp32 matmul rate at the PPO update's
shapes (one minibatch through each layer, forward and the two backward products), and MuJoCo C's
batched physics steps/s on the robot's model (``mujoco.batch.Batch``, every env under a PD hold
of its home pose, all threads). Each engine's training rate is then printed against its
roofline: the update's FLOPs at the matmul rate plus the env steps at MuJoCo C's physics rate.

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


def matmul_peak(batch: int, sizes: list[tuple[int, int]]) -> dict[str, float]:
    """fp32 GFLOP/s of the update's products: for each layer (i -> o), x[batch, i] @ w[i, o]
    (forward), dy @ w.T (input gradient) and x.T @ dy (weight gradient), each timed alone."""
    out = {}
    key = jax.random.PRNGKey(0)
    for i, o in sizes:
        x = jax.random.normal(key, (batch, i))
        w = jax.random.normal(key, (i, o))
        dy = jax.random.normal(key, (batch, o))
        for name, fn, args in (("fwd", lambda a, b: a @ b, (x, w)), ("dx", lambda a, b: a @ b.T, (dy, w)),
                               ("dw", lambda a, b: a.T @ b, (x, dy))):
            f = jax.jit(fn)
            _, secs = timed(f, *args, repeats=20)
            out[f"{batch}x{i}x{o} {name}"] = 2 * batch * i * o / secs / 1e9
    return out


def mujoco_c_physics_rate(env, n: int, substeps: int = 200) -> float:
    """MuJoCo C's batched physics steps/s on the env's model: n copies on the home keyframe,
    each substep under the PD law holding it (with 5 % joint noise), on all threads."""
    import mujoco
    import numpy as np
    from mujoco import batch as mj_batch

    m = env.mj_model
    b = mj_batch.Batch(m, n, 0)
    key = m.key("home")
    rng = np.random.default_rng(0)
    b.bind("qpos")[:] = key.qpos
    b.bind("qpos")[:, 7:] += 0.05 * rng.standard_normal((n, m.nu))
    b.bind("qvel")[:] = 0.0
    kp = np.asarray(env._kp, np.float64)  # noqa: SLF001 (the env's own gains)
    limit = np.asarray(env._torque_limit, np.float64)  # noqa: SLF001
    default = key.qpos[7:]
    qpos, ctrl = b.bind("qpos"), b.bind("ctrl")
    t = time.perf_counter()
    for _ in range(substeps):
        ctrl[:] = np.clip(kp * (default - qpos[:, 7:]), -limit, limit)
        b.step()
    return n * substeps / (time.perf_counter() - t)


def main(argv):
    args = parse_cli(argv)
    n = int(args.get("envs", 1024))
    iters = int(args.get("iterations", 3))
    robot = args.get("robot", "go2")
    engines = [e for e in str(args.get("engines", "mjx,mujoco")).strip("[]").split(",") if e]
    if robot == "all":
        print(f"machine: {platform.processor() or platform.machine()}, {jax.device_count()} "
              f"{jax.devices()[0].platform} device(s), jax {jax.__version__}; {n} envs, {24 * iters} steps")
        raw_env_table(n, 24 * iters)
        return
    ppo = PPOConfig(num_envs=n, num_iterations=iters)  # rsl_rl schedule: 24 x 5 epochs x 4 minibatches
    net = NetworkConfig()
    print(f"machine: {platform.processor() or platform.machine()}, {jax.device_count()} {jax.devices()[0].platform} "
          f"device(s), jax {jax.__version__}; robot {robot}, {n} envs, {iters} iterations of {ppo.unroll_length} "
          f"steps/env, {ppo.num_epochs} epochs x {ppo.num_minibatches} minibatches")
    env = envs.make(robot)
    obs = jax.eval_shape(env.reset, jax.random.PRNGKey(0)).obs
    obs_sizes = {k: int(v.shape[-1]) for k, v in obs.items()}
    layers = lambda i, o: list(zip([i, *net.actor_hidden], [*net.actor_hidden, o]))  # noqa: E731
    shapes = layers(obs_sizes["state"], env.action_size) + list(zip([obs_sizes["privileged_state"], *net.critic_hidden],
                                                                     [*net.critic_hidden, 1]))
    rates = matmul_peak(ppo.minibatch_size, shapes)
    flops = {k: 2 * ppo.minibatch_size * int(k.split("x")[1]) * int(k.split("x")[2].split()[0]) for k in rates}
    # The update's mix of products at their own rates: total FLOPs / total time.
    peak = sum(flops.values()) / sum(flops[k] / (rates[k] * 1e9) for k in rates) / 1e9
    physics = mujoco_c_physics_rate(env, n)
    print("limits, measured now:")
    print(f"  fp32 matmul at the update's shapes (minibatch {ppo.minibatch_size}): {peak:,.0f} GFLOP/s "
          f"(largest product alone {max(rates.values()):,.0f}, smallest {min(rates.values()):,.0f})")
    print(f"  MuJoCo C batched physics ({n} sims, PD hold, all threads): {physics:,.0f} physics steps/s = "
          f"{physics / env.config.decimation:,.0f} env steps/s")
    macs = lambda s: sum(a * b for a, b in s)  # noqa: E731
    per_sample = 6 * macs(shapes)
    sgd_flops_per_iteration = per_sample * ppo.batch_size * ppo.num_epochs
    roofline_s = sgd_flops_per_iteration / (peak * 1e9) + ppo.batch_size / (physics / env.config.decimation)
    roofline = ppo.batch_size / roofline_s
    print(f"  roofline: {roofline:,.0f} env steps/s (update {sgd_flops_per_iteration / 1e9:.0f} GFLOP per iteration "
          f"at the matmul rate + the env steps at MuJoCo C's physics rate)")
    results = {}
    for engine in engines:
        results[engine] = bench_engine(robot, engine, n, iters, ppo, net, sgd_flops_per_iteration, roofline, peak)
    if str(args.get("brax", "false")).lower() in ("1", "true", "yes"):
        brax_sps = bench_brax_ppo(robot, n, iters)
        best = max(r["train"] for r in results.values())
        print(f"brax.training PPO, same networks and schedule: {brax_sps:,.0f} env steps/s; ours / Brax: "
              f"{best / brax_sps:.2f}")

    cfg = load_experiment("go2_to_xbot", ["scale=cpu"])
    program = make_program(cfg)
    t = time.perf_counter()
    jax.jit(program.run).lower(jax.random.PRNGKey(0)).compile()
    compile_s = time.perf_counter() - t
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"go2_to_xbot program compile (engine mjx, scale=cpu shapes): {compile_s:.1f} s")
    print(f"peak resident memory: {peak_mib:,.0f} MiB")


def bench_engine(robot, engine, n, iters, ppo, net, sgd_flops_per_iteration, roofline, peak):
    import dataclasses

    env = envs.make(robot, dataclasses.replace(envs.default_config(robot), engine=engine))
    steps = n * ppo.unroll_length * iters
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), n))

    @jax.jit
    def raw_random(s, key):
        def f(c, k):
            return jax.vmap(env.step)(c, 0.5 * jax.random.normal(k, (n, env.action_size))), None
        return jax.lax.scan(f, s, jax.random.split(key, ppo.unroll_length * iters))[0]

    _, raw_s = timed(raw_random, states, jax.random.PRNGKey(4))
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
    state = jax.jit(trainer.init)(jax.random.PRNGKey(2), ppo.hparams(), empty_mask(params), params)
    run = jax.jit(lambda s: jax.lax.scan(lambda c, _: trainer.iteration(c), s, None, length=iters))
    t = time.perf_counter()
    compiled = run.lower(state).compile()
    compile_s = time.perf_counter() - t
    _, train_s = timed(compiled, state)
    train = steps / train_s
    update_s = train_s - rollout_s
    sgd_rate = sgd_flops_per_iteration * iters / max(update_s, 1e-9) / 1e9
    print(f"engine {engine}:")
    print(f"  raw env (random actions):   {steps / raw_s:10,.0f} env steps/s")
    print(f"  rollout (env + policy):     {steps / rollout_s:10,.0f} env steps/s")
    print(f"  training:                   {train:10,.0f} env steps/s = {train / roofline:.2f} of the roofline "
          f"(trainer compile {compile_s:.1f} s)")
    print(f"  update share of training:   {100 * update_s / train_s:10.0f} %  (SGD ~{sgd_rate:.0f} GFLOP/s = "
          f"{sgd_rate / peak:.2f} of the matmul rate)")
    return {"raw": steps / raw_s, "rollout": steps / rollout_s, "train": train, "sgd": sgd_rate}


def bench_brax_ppo(robot, n, iters) -> float:
    """Brax's own PPO (``brax.training.agents.ppo``) on our env, with our networks' sizes and
    rsl_rl's schedule; env steps/s of its training after its first (compiling) call. A peer
    measured here only: the trainer never imports it."""
    import functools

    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.ppo import train as ppo

    env = envs.make(robot)
    num_steps = n * 24 * iters
    make_networks = functools.partial(ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=(512, 256, 128),
                                      value_hidden_layer_sizes=(512, 256, 128),
                                      activation=jax.nn.elu, policy_obs_key="state", value_obs_key="privileged_state")
    times = []
    kwargs = dict(environment=env, num_timesteps=num_steps, episode_length=env.config.episode_steps, num_envs=n,
                  unroll_length=24, batch_size=n * 24 // 4 // 24, num_minibatches=4, num_updates_per_batch=5,
                  learning_rate=1e-3, entropy_cost=0.01, discounting=0.998, gae_lambda=0.95, normalize_observations=True,
                  num_evals=2, network_factory=make_networks, progress_fn=lambda *a: times.append(time.perf_counter()),
                  seed=0)
    ppo.train(**kwargs)  # compile + first run
    t = time.perf_counter()
    times.clear()
    ppo.train(**kwargs)
    return num_steps / (time.perf_counter() - t)


if __name__ == "__main__":
    main(sys.argv[1:])
