"""Throughput benchmark (not a test): ``python experiments/bench.py [envs=1024] [iterations=3] [robot=go2|all]
[engines=mjx,mujoco|none] [brax=true] [program_compile=false]``.

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

import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import envs  # noqa: E402
from ptrl_jax.config import NetworkConfig, PPOConfig  # noqa: E402
from ptrl_jax.core.freeze import empty_mask  # noqa: E402
from ptrl_jax.io.overrides import load_experiment, parse_cli  # noqa: E402
from ptrl_jax.core.program import make_program  # noqa: E402
from ptrl_jax.core.train import make_train  # noqa: E402
from ptrl_jax.io.resume import host_cpu  # noqa: E402


def machine() -> str:
    """The CPU as the OS names it (``/proc/cpuinfo``, with family and model), its core count and
    its vector extensions, with jax's devices: what a figure needs to be compared."""
    import os

    name, isa = host_cpu()
    return (f"{name}, {os.cpu_count()} cores ({isa or 'no vector ISA listed'}), {jax.device_count()} "
            f"{jax.devices()[0].platform} device(s), jax {jax.__version__}")


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


UPDATE_PRODUCTS = ("fwd", "dx", "dw")


def update_products(layers: list[tuple[int, int]], first: set[int]) -> list[tuple[int, int, str]]:
    """The matrix products of one SGD step through MLP layers ``(in, out)``: each layer's forward
    product and weight gradient, and its input gradient except for the networks' first layers
    (indices in ``first``), whose input is data."""
    return [(i, o, form) for n, (i, o) in enumerate(layers) for form in UPDATE_PRODUCTS
            if not (form == "dx" and n in first)]


def matmul_peak(batch: int, products: list[tuple[int, int, str]], repeats: int = 20) -> dict[tuple, float]:
    """fp32 GFLOP/s of each product ``(in, out, form)`` at ``batch`` rows: x[batch, in] @ w[in, out]
    (fwd), dy @ w.T (dx) or x.T @ dy (dw). Each is timed alone, ``repeats`` times inside one
    jitted loop (no dispatch cost), behind optimization barriers so that XLA neither hoists it
    out of the loop nor computes only the element the loop keeps."""
    out = {}
    key = jax.random.PRNGKey(0)
    ops = {"fwd": lambda a, b: a @ b, "dx": lambda a, b: a @ b.T, "dw": lambda a, b: a.T @ b}
    for i, o, form in products:
        x, w, dy = (jax.random.normal(key, shape) for shape in ((batch, i), (i, o), (batch, o)))
        a, b = {"fwd": (x, w), "dx": (dy, w), "dw": (x, dy)}[form]

        @jax.jit
        def loop(a, b, op=ops[form]):
            def body(_, carry):
                a, acc = carry
                a = jax.lax.optimization_barrier(a)
                return a, acc + jax.lax.optimization_barrier(op(a, b))[0, 0]
            return jax.lax.fori_loop(0, repeats, body, (a, jnp.float32(0.0)))[1]

        _, secs = timed(loop, a, b, repeats=3)
        out[(i, o, form)] = 2 * batch * i * o * repeats / secs / 1e9
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
    engines = [e for e in str(args.get("engines", "mjx,mujoco")).strip("[]").split(",") if e and e != "none"]
    program_compile = str(args.get("program_compile", "true")).lower() in ("1", "true", "yes")
    if robot == "all":
        print(f"machine: {machine()}; {n} envs, {24 * iters} steps")
        raw_env_table(n, 24 * iters)
        return
    ppo = PPOConfig(num_envs=n, num_iterations=iters)  # rsl_rl schedule: 24 x 5 epochs x 4 minibatches
    net = NetworkConfig()
    print(f"machine: {machine()}; robot {robot}, {n} envs, {iters} iterations of {ppo.unroll_length} "
          f"steps/env, {ppo.num_epochs} epochs x {ppo.num_minibatches} minibatches")
    env = envs.make(robot)
    obs = jax.eval_shape(env.reset, jax.random.PRNGKey(0)).obs
    obs_sizes = {k: int(v.shape[-1]) for k, v in obs.items()}
    actor = list(zip([obs_sizes["state"], *net.actor_hidden], [*net.actor_hidden, env.action_size]))
    critic = list(zip([obs_sizes["privileged_state"], *net.critic_hidden], [*net.critic_hidden, 1]))
    products = update_products(actor + critic, first={0, len(actor)})
    rates = matmul_peak(ppo.minibatch_size, sorted(set(products)))
    flops = lambda p: 2 * ppo.minibatch_size * p[0] * p[1]  # noqa: E731
    # The update's mix of products (with repeats: actor and critic share shapes), each at its own
    # rate: total FLOPs / total time.
    step_flops = sum(flops(p) for p in products)
    step_seconds = sum(flops(p) / (rates[p] * 1e9) for p in products)
    peak = step_flops / step_seconds / 1e9
    physics = mujoco_c_physics_rate(env, n)
    print("limits, measured now:")
    print(f"  fp32 matmul at the update's shapes (minibatch {ppo.minibatch_size}): {peak:,.0f} GFLOP/s for the mix of "
          f"one SGD step's {len(products)} products, each timed alone:")
    for p in sorted(set(products), key=flops, reverse=True):
        share = products.count(p) * flops(p) / (rates[p] * 1e9) / step_seconds
        print(f"    {p[0]:>4} x {p[1]:<4} {p[2]:3s} {rates[p]:8,.0f} GFLOP/s  ({100 * share:4.1f} % of the step's matmul time)")
    print(f"  MuJoCo C batched physics ({n} sims, PD hold, all threads): {physics:,.0f} physics steps/s = "
          f"{physics / env.config.decimation:,.0f} env steps/s")
    sgd_flops_per_iteration = step_flops * ppo.num_minibatches * ppo.num_epochs
    roofline_s = sgd_flops_per_iteration / (peak * 1e9) + ppo.batch_size / (physics / env.config.decimation)
    roofline = ppo.batch_size / roofline_s
    print(f"  roofline: {roofline:,.0f} env steps/s (update {sgd_flops_per_iteration / 1e9:.0f} GFLOP per iteration "
          f"at the matmul rate + the env steps at MuJoCo C's physics rate)")
    results = {}
    for engine in engines:
        results[engine] = bench_engine(robot, engine, n, iters, ppo, net, sgd_flops_per_iteration, roofline, peak)
    if str(args.get("brax", "false")).lower() in ("1", "true", "yes"):
        brax_sps = bench_brax_ppo(robot, n, iters)
        best = max((r["train"] for r in results.values()), default=float("nan"))
        print(f"brax.training PPO, same networks and schedule: {brax_sps:,.0f} env steps/s; ours / Brax: "
              f"{best / brax_sps:.2f}")

    if not program_compile:
        return
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
    from ptrl_jax.core import distributions  # noqa: E402
    from ptrl_jax.core.networks import policy_apply  # noqa: E402

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
    update_s = time_update(trainer, state, ppo, iters)
    train = steps / train_s
    sgd_rate = sgd_flops_per_iteration * iters / update_s / 1e9
    print(f"engine {engine}:")
    print(f"  raw env (random actions):   {steps / raw_s:10,.0f} env steps/s")
    print(f"  rollout (env + policy):     {steps / rollout_s:10,.0f} env steps/s")
    print(f"  training:                   {train:10,.0f} env steps/s = {train / roofline:.2f} of the roofline "
          f"(trainer compile {compile_s:.1f} s)")
    print(f"  update, timed alone:        {update_s / iters:10.2f} s per iteration = {100 * update_s / train_s:.0f} % of "
          f"training (SGD {sgd_rate:.0f} GFLOP/s = {sgd_rate / peak:.2f} of the matmul rate)")
    print(f"  rollout + update / training: {(rollout_s + update_s) / train_s:9.2f}  (the rest: GAE, bookkeeping)")
    return {"raw": steps / raw_s, "rollout": steps / rollout_s, "train": train, "sgd": sgd_rate}


def time_update(trainer, state, ppo, iters) -> float:
    """Seconds for ``iters`` calls of the trainer's SGD alone (``trainer.update``: epochs x
    minibatches of Adam steps) on a batch of ``ppo.batch_size`` random transitions of the env's
    shapes; the cost of the update does not depend on the values."""
    from ptrl_jax.core.losses import LossInputs
    from ptrl_jax.core.types import Transition

    b, a = ppo.batch_size, state.params["log_std"].shape[0]
    keys = iter(jax.random.split(jax.random.PRNGKey(5), 8))
    normal = lambda *shape: jax.random.normal(next(keys), shape)  # noqa: E731
    obs = {k: normal(b, size) for k, size in trainer.observation_sizes.items()}
    action = normal(b, a)
    zeros = jnp.zeros(b)
    batch = Transition(observation=obs, action=action, log_prob=zeros - 10.0, action_mean=action, action_std=jnp.ones((b, a)),
                       reward=zeros, termination=zeros, truncation=zeros, final_observation=obs)
    inputs = LossInputs(action=action, old_log_prob=zeros - 10.0, old_value=zeros, advantage=normal(b), target_return=normal(b))

    @jax.jit
    def updates(state, key):
        def f(carry, k):
            params, opt_state, lr = carry
            return trainer.update(params, opt_state, lr, state.hparams, state.frozen, batch, inputs, k)[0], None
        return jax.lax.scan(f, (state.params, state.opt_state, state.learning_rate), jax.random.split(key, iters))[0]

    _, seconds = timed(updates, state, jax.random.PRNGKey(6))
    return seconds


def bench_brax_ppo(robot, n, iters) -> float:
    """Brax's own PPO (``brax.training.agents.ppo``) on our env, with our networks' sizes and
    rsl_rl's schedule: the env steps/s that Brax itself reports (``training/sps``) for its second
    training epoch of ``iters`` iterations, compiled by the first; no evaluation rollouts. A peer
    measured here only: the trainer never imports it."""
    import functools

    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.ppo import train as ppo

    env = envs.make(robot)
    make_networks = functools.partial(ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=(512, 256, 128),
                                      value_hidden_layer_sizes=(512, 256, 128),
                                      activation=jax.nn.elu, policy_obs_key="state", value_obs_key="privileged_state")
    reports = []
    ppo.train(environment=env, num_timesteps=2 * n * 24 * iters, episode_length=env.config.episode_steps, num_envs=n,
              unroll_length=24, batch_size=n // 4, num_minibatches=4, num_updates_per_batch=5,
              learning_rate=1e-3, entropy_cost=0.01, discounting=0.99, gae_lambda=0.95, normalize_observations=True,
              num_evals=3, run_evals=False, network_factory=make_networks,
              progress_fn=lambda step, metrics: reports.append(metrics), seed=0)
    sps = [float(m["training/sps"]) for m in reports if "training/sps" in m]
    if len(sps) < 2:
        raise RuntimeError(f"Brax's PPO reported {len(sps)} training epochs; expected 2")
    return sps[-1]


if __name__ == "__main__":
    main(sys.argv[1:])
