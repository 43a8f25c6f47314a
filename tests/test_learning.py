"""PPO learns: on a cheap task its return clearly rises, and training never recompiles."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import State

from ptrl_jax.config import NetworkConfig, PPOConfig
from ptrl_jax.core.freeze import empty_mask
from ptrl_jax.core.train import make_train


@dataclasses.dataclass(frozen=True)
class _Weights:
    distance: float = 1.0


class PointMass:
    """2-D point mass pushed toward the origin; reward exp(-|x|^2) - 0.01 |a|^2 per step.
    Episodes last 20 steps (truncation); leaving |x| > 3 terminates. Pure JAX, no MJX."""

    action_size = 2
    reward_names = ("distance",)  # the env contract: metrics hold reward/<name>
    horizon = 20

    def _obs(self, pos, vel):
        o = jnp.concatenate([pos, vel])
        return {"state": o, "privileged_state": o}

    def reset(self, key):
        k1, k2 = jax.random.split(key)
        pos = jax.random.uniform(k1, (2,), minval=-2.0, maxval=2.0)
        vel = jnp.zeros(2)
        obs = self._obs(pos, vel)
        info = {"rng": k2, "pos": pos, "vel": vel, "t": jnp.zeros((), jnp.int32), "final_obs": obs,
                "truncation": jnp.zeros(()), "termination": jnp.zeros(()), "nonfinite": jnp.zeros(())}
        return State(None, obs, jnp.zeros(()), jnp.zeros(()), {"reward/distance": jnp.zeros(())}, info)

    def step(self, state, action):
        info = state.info
        a = jnp.clip(action, -1.0, 1.0)
        vel = 0.8 * info["vel"] + 0.2 * a
        pos = info["pos"] + vel
        reward = jnp.exp(-jnp.sum(pos**2)) - 0.01 * jnp.sum(a**2)
        t = info["t"] + 1
        term = jnp.any(jnp.abs(pos) > 3.0)
        trunc = (t >= self.horizon) & ~term
        done = term | trunc
        obs = self._obs(pos, vel)
        fresh = self.reset(info["rng"])
        rng = jax.random.split(info["rng"])[0]
        new_info = {
            "rng": rng,
            "pos": jnp.where(done, fresh.info["pos"], pos),
            "vel": jnp.where(done, fresh.info["vel"], vel),
            "t": jnp.where(done, 0, t),
            "final_obs": obs,
            "truncation": trunc.astype(jnp.float32),
            "termination": term.astype(jnp.float32),
            "nonfinite": jnp.zeros(()),
        }
        next_obs = jax.tree.map(lambda f, o: jnp.where(done, f, o), fresh.obs, obs)
        return State(None, next_obs, reward.astype(jnp.float32), done.astype(jnp.float32),
                     {"reward/distance": reward.astype(jnp.float32)}, new_info)


PPO = PPOConfig(num_envs=64, unroll_length=20, num_epochs=4, num_minibatches=4, num_iterations=40,
                learning_rate=3e-4, gamma=0.95, entropy_coef=0.0)
NET = NetworkConfig(actor_hidden=(32, 32, 32), critic_hidden=(32, 32), init_noise_std=0.5)


class TestPPOLearns:
    def test_return_rises_on_point_mass(self):
        trainer = make_train(PointMass(), PPO, NET)
        params = trainer.init_params(jax.random.PRNGKey(0))
        train = jax.jit(trainer.train)
        _, metrics = train(jax.random.PRNGKey(1), PPO.hparams(), empty_mask(params), params)
        reward = np.asarray(metrics["episode_reward"])
        first, last = reward[2:6].mean(), reward[-5:].mean()
        # Staying at the origin for 20 steps is worth ~20; a random policy gets a few.
        assert last > first + 3.0, (first, last)
        assert last > 8.0, last
        assert np.all(np.asarray(metrics["skipped_updates"]) == 0)


class PointMassWithAliveTerm(PointMass):
    """PointMass with a second reward term, a constant 0.25 per step."""

    reward_names = ("distance", "alive")

    def reset(self, key):
        state = super().reset(key)
        return state.replace(metrics={**state.metrics, "reward/alive": jnp.zeros(())})

    def step(self, state, action):
        nxt = super().step(state, action)
        alive = jnp.float32(0.25)
        return nxt.replace(reward=nxt.reward + alive, metrics={**nxt.metrics, "reward/alive": alive})


class TestPerStepTermMetrics:
    def test_each_term_per_env_step_of_the_rollout(self):
        """``step_reward/<term>``: the term's mean over every env and step of the iteration's
        rollout, so the constant term reads its constant and the terms add up to ``step_reward``."""
        ppo = dataclasses.replace(PPO, num_iterations=3)
        trainer = make_train(PointMassWithAliveTerm(), ppo, NET)
        params = trainer.init_params(jax.random.PRNGKey(0))
        _, metrics = jax.jit(trainer.train)(jax.random.PRNGKey(1), ppo.hparams(), empty_mask(params), params)
        np.testing.assert_array_equal(np.asarray(metrics["step_reward/alive"]), np.float32(0.25))
        total = np.asarray(metrics["step_reward/distance"]) + np.asarray(metrics["step_reward/alive"])
        np.testing.assert_allclose(total, np.asarray(metrics["step_reward"]), rtol=1e-5)
        assert np.all(np.asarray(metrics["step_reward/distance"]) > 0)  # exp(-|x|^2): positive


class TestNoRecompilation:
    def test_iterations_reuse_one_compiled_program(self):
        trainer = make_train(PointMass(), dataclasses.replace(PPO, num_iterations=1), NET)
        params = trainer.init_params(jax.random.PRNGKey(0))
        state = jax.jit(trainer.init)(jax.random.PRNGKey(1), PPO.hparams(), empty_mask(params), params)
        iteration = jax.jit(trainer.iteration)
        for _ in range(4):
            state, _ = iteration(state)
        assert iteration._cache_size() == 1


class TestDeterminism:
    def test_same_seed_same_metrics(self):
        ppo = dataclasses.replace(PPO, num_iterations=3)
        trainer = make_train(PointMass(), ppo, NET)
        params = trainer.init_params(jax.random.PRNGKey(0))
        train = jax.jit(trainer.train)
        _, m1 = train(jax.random.PRNGKey(5), ppo.hparams(), empty_mask(params), params)
        _, m2 = train(jax.random.PRNGKey(5), ppo.hparams(), empty_mask(params), params)
        for k in m1:
            assert np.array_equal(np.asarray(m1[k]), np.asarray(m2[k])), k


@pytest.mark.xdist_group("closing_noise")  # one worker, so the class fixture compiles once
class TestClosingNoise:
    """``ppo.final_noise_iterations``: the last iterations act with the std held at
    ``final_noise_std`` while the rest of the network keeps learning. One compiled iteration
    serves all three tests (six iterations: four learned, two held)."""

    PPO = dataclasses.replace(PPO, num_iterations=6, final_noise_iterations=2, final_noise_std=0.1,
                              entropy_coef=0.01)

    @pytest.fixture(scope="class")
    def history(self):
        ppo = self.PPO
        trainer = make_train(PointMass(), ppo, NET)
        params = trainer.init_params(jax.random.PRNGKey(0))
        state = trainer.init(jax.random.PRNGKey(1), ppo.hparams(), empty_mask(params), params)
        iteration = jax.jit(trainer.iteration)
        states, stds = [state], []
        for _ in range(ppo.num_iterations):
            state, metrics = iteration(state)
            states.append(state)
            stds.append(float(metrics["noise_std"]))
        return states, np.asarray(stds)

    def test_std_is_learned_then_held(self, history):
        states, stds = history
        assert np.all(np.abs(stds[:4] - 0.1) > 0.05), stds  # learned from 0.5 first
        assert not np.allclose(stds[1:4], stds[0]), stds  # and it did move
        np.testing.assert_allclose(stds[4:], 0.1, rtol=1e-6)
        held = np.log(np.float32(0.1)).astype(np.float32)
        assert np.all(np.asarray(states[-1].params["log_std"]) == held)
        assert np.all(np.asarray(states[-2].params["log_std"]) == held)

    def test_the_rest_of_the_network_keeps_learning(self, history):
        states, _ = history
        w = lambda s: np.asarray(s.params["actor"]["layer_3"]["w"])  # noqa: E731
        assert not np.array_equal(w(states[-1]), w(states[-2]))

    def test_the_run_mask_is_not_changed(self, history):
        states, _ = history
        assert not any(np.any(np.asarray(m)) for m in jax.tree.leaves(states[-1].frozen))


# MuJoCo C's engine inside the trainer (MJX's is the go2_to_xbot smoke program's, whose kill -9
# and resume tests/test_resume.py checks).
@pytest.mark.parametrize("engine", [pytest.param("mujoco", marks=pytest.mark.xdist_group("engine_mujoco_learning")),
                                    pytest.param("mjx", marks=pytest.mark.slow)])
class TestEngineInsideTheTrainer:
    """Each physics engine inside the trainer (MuJoCo C: the host callback is part of the one
    compiled iteration): no recompiles, same seed same metrics, and a state written to a resume
    file and read back continues bitwise, the physics state (warm start included) with it."""

    def test_no_recompiles_same_seed_and_a_saved_state_continues_bitwise(self, engine, tmp_path):
        import envs
        from ptrl_jax.io import artifacts

        env = envs.make("go2", dataclasses.replace(envs.default_config("go2"), engine=engine))
        ppo = dataclasses.replace(PPO, num_envs=8, unroll_length=4, num_minibatches=2, num_iterations=1)
        trainer = make_train(env, ppo, NET)
        params = trainer.init_params(jax.random.PRNGKey(0))
        init = jax.jit(trainer.init)
        iteration = jax.jit(trainer.iteration)
        runs, states = [], []
        for _ in range(2):
            state = init(jax.random.PRNGKey(1), ppo.hparams(), empty_mask(params), params)
            metrics = []
            for _ in range(3):
                state, m = iteration(state)
                metrics.append(jax.device_get(m))
            runs.append(metrics)
            states.append(state)
        assert iteration._cache_size() == 1
        for a, b in zip(*runs):
            for k in a:
                assert np.array_equal(a[k], b[k]), k
        assert runs[0][-1]["env_steps"] == 3 * 8 * 4 and np.isfinite(runs[0][-1]["loss/total"])

        # Through the resume file: save after 3 iterations, load into the state's structure, run a
        # 4th; it equals a 4th run on the state kept in memory.
        artifacts.save_state(tmp_path / "state.npz", states[0], {"test": engine})
        loaded, meta = artifacts.load_state(tmp_path / "state.npz", jax.eval_shape(lambda: states[0]))
        assert meta["test"] == engine
        (a, ma), (b, mb) = iteration(states[1]), iteration(loaded)
        for k in ma:
            assert np.array_equal(np.asarray(ma[k]), np.asarray(mb[k])), k
        same = jax.tree.map(lambda x, y: np.array_equal(np.asarray(x), np.asarray(y)), a, b)
        assert all(jax.tree.leaves(same))


class TestExplainedVariance:
    def test_hand_computed_values(self):
        from ptrl_jax.core.train import explained_variance

        returns = jnp.array([1.0, 2.0, 3.0, 4.0])  # variance 1.25
        assert float(explained_variance(returns, returns)) == 1.0
        assert float(explained_variance(jnp.full(4, 2.5), returns)) == 0.0  # the mean: no better
        # residuals [0.5, -0.5, 0.5, -0.5]: variance 0.25, so 1 - 0.25 / 1.25 = 0.8
        np.testing.assert_allclose(float(explained_variance(returns - jnp.array([0.5, -0.5, 0.5, -0.5]), returns)), 0.8)
        assert float(explained_variance(-returns, returns)) < 0.0  # worse than the mean
        assert float(explained_variance(jnp.arange(4.0), jnp.ones(4))) == 0.0  # returns that do not vary


@pytest.mark.xdist_group("critic_warmup")  # one worker, so the class fixture compiles once
class TestCriticWarmup:
    """``hparams.critic_warmup``: the first iterations update the critic alone; the actor, its
    log-std and their Adam moments stay bitwise as they were, the adaptive learning rate is held,
    and afterwards the whole network learns. Five iterations, two of them warming up."""

    PPO = dataclasses.replace(PPO, num_iterations=5, entropy_coef=0.01)

    @pytest.fixture(scope="class")
    def history(self):
        ppo = self.PPO
        trainer = make_train(PointMass(), ppo, NET)
        params = trainer.init_params(jax.random.PRNGKey(0))
        hparams = ppo.hparams()._replace(critic_warmup=jnp.float32(2))
        state = trainer.init(jax.random.PRNGKey(1), hparams, empty_mask(params), params)
        iteration = jax.jit(trainer.iteration)
        states, metrics = [state], []
        for _ in range(ppo.num_iterations):
            state, m = iteration(state)
            states.append(state)
            metrics.append(jax.device_get(m))
        return states, metrics

    @staticmethod
    def _policy_of(tree):
        return {"actor": tree["actor"], "log_std": tree["log_std"]}

    @classmethod
    def _policy(cls, state):
        return cls._policy_of(state.params)

    def test_the_actor_is_bitwise_unchanged_while_warming_up(self, history):
        states, metrics = history
        for s in states[1:3]:
            same = jax.tree.map(np.array_equal, self._policy(s), self._policy(states[0]))
            assert all(jax.tree.leaves(same))
        assert [m["critic_warmup"] for m in metrics] == [1.0, 1.0, 0.0, 0.0, 0.0]

    def test_the_critic_learns_while_warming_up(self, history):
        states, _ = history
        w = lambda s: np.asarray(s.params["critic"]["layer_0"]["w"])  # noqa: E731
        assert not np.array_equal(w(states[1]), w(states[0]))
        assert not np.array_equal(w(states[2]), w(states[1]))

    def test_the_actor_keeps_no_moving_state_and_the_rate_is_held(self, history):
        states, metrics = history
        params_def = jax.tree.structure(states[0].params)
        is_moment = lambda x: isinstance(x, dict) and jax.tree.structure(x) == params_def  # noqa: E731
        moments = [m for m in jax.tree.leaves(states[2].opt_state, is_leaf=is_moment) if is_moment(m)]
        assert len(moments) == 3  # Adam's count, mu and nu, each per entry
        for m in moments:  # the actor's are still zero, the critic's are not
            assert not any(np.any(np.asarray(x)) for x in jax.tree.leaves(self._policy_of(m)))
            assert any(np.any(np.asarray(x)) for x in jax.tree.leaves(m["critic"]))
        assert float(states[2].learning_rate) == np.float32(self.PPO.learning_rate)
        np.testing.assert_allclose([m["kl"] for m in metrics[:2]], 0.0, atol=1e-9)

    def test_the_critic_fits_unclipped_while_warming_up(self):
        """The clipped value loss keeps each value within clip_epsilon of its last one per
        iteration (up to the network's generalisation); the warm-up fits the returns unclipped,
        so a fresh critic moves far further in its first iteration."""
        from ptrl_jax.core.networks import value_apply
        from ptrl_jax.core.train import normalize_obs

        ppo = dataclasses.replace(self.PPO, num_iterations=1, clip_epsilon=0.01, learning_rate=3e-3, adaptive_lr=False)
        trainer = make_train(PointMass(), ppo, NET)
        params = trainer.init_params(jax.random.PRNGKey(0))
        iteration = jax.jit(trainer.iteration)
        moved = []
        for warmup in (0.0, 1.0):
            hparams = ppo.hparams()._replace(critic_warmup=jnp.float32(warmup))
            state = trainer.init(jax.random.PRNGKey(1), hparams, empty_mask(params), params)
            after, _ = iteration(state)
            obs = normalize_obs(after.normalizer, after.env_state.obs, True)
            moved.append(float(jnp.mean(jnp.abs(value_apply(after.params, obs, NET) - value_apply(params, obs, NET)))))
        assert moved[0] < 0.1, moved  # clipped: a few clip_epsilon (measured 0.07)
        assert moved[1] > 5 * moved[0], moved

    def test_the_whole_network_learns_afterwards(self, history):
        states, _ = history
        for name in ("actor", "log_std"):
            a, b = self._policy(states[2])[name], self._policy(states[5])[name]
            assert not all(jax.tree.leaves(jax.tree.map(np.array_equal, a, b))), name
        assert not all(jax.tree.leaves(jax.tree.map(lambda m: bool(np.any(m)), states[5].frozen)))  # run mask untouched
