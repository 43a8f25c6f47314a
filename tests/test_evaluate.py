"""Evaluation actors: the mean action, or actions sampled as in training (``stochastic=true``)."""

import jax
import jax.numpy as jnp
import numpy as np

import envs
from ptrl_jax import evaluate, normalization
from ptrl_jax.config import NetworkConfig
from ptrl_jax.networks import init_actor_critic, policy_apply

OBS, PRIV, ACT = 45, 53, 12
NET = NetworkConfig(actor_hidden=(32, 16, 8), critic_hidden=(8,), init_noise_std=0.3)


def policy_parts():
    params = init_actor_critic(jax.random.PRNGKey(0), NET, OBS, PRIV, ACT)
    stats = {"state": normalization.init(OBS), "privileged_state": normalization.init(PRIV)}
    return params, stats


def one_obs():
    return {"state": jax.random.normal(jax.random.PRNGKey(1), (OBS,)), "privileged_state": jnp.zeros(PRIV)}


class TestActor:
    def test_the_mean_actor_ignores_the_key(self):
        params, stats = policy_parts()
        act = evaluate.make_actor(params, stats, NET)
        obs = one_obs()
        a, b = act(obs, jax.random.PRNGKey(0)), act(obs, jax.random.PRNGKey(1))
        np.testing.assert_array_equal(a, b)
        np.testing.assert_allclose(a, policy_apply(params, obs, NET).mean, rtol=1e-6)

    def test_the_stochastic_actor_samples_the_policy_gaussian(self):
        params, stats = policy_parts()
        act = evaluate.make_actor(params, stats, NET, stochastic=True)
        obs = one_obs()
        n = 20_000
        samples = np.asarray(jax.vmap(lambda k: act(obs, k))(jax.random.split(jax.random.PRNGKey(2), n)))
        mean = np.asarray(policy_apply(params, obs, NET).mean)
        # std 0.3 per action: the sample mean lies within 5 standard errors (0.3 / sqrt(n) each),
        # and the sample std within 3 % of 0.3.
        np.testing.assert_allclose(samples.mean(axis=0), mean, atol=5 * 0.3 / np.sqrt(n))
        np.testing.assert_allclose(samples.std(axis=0), 0.3, rtol=0.03)


class TestStochasticRollout:
    """Five control steps of Go2 in the MuJoCo C env (no MJX compile)."""

    def rollout(self, stochastic, seed):
        params, stats = policy_parts()
        actor = evaluate.make_actor(params, stats, NET, stochastic=stochastic)
        rec = evaluate.rollout_mujoco("go2", envs.default_config("go2"), actor, (0.5, 0.0, 0.0), 0.1, seed)
        return rec["qpos"]

    def test_the_seed_picks_the_samples(self):
        a, b, c = self.rollout(True, 0), self.rollout(True, 0), self.rollout(True, 1)
        np.testing.assert_array_equal(a, b)
        assert np.abs(a - c).max() > 1e-4

    def test_mean_actions_do_not_depend_on_the_seed(self):
        np.testing.assert_array_equal(self.rollout(False, 0), self.rollout(False, 1))

    def test_sampled_actions_move_the_robot_differently_from_the_mean(self):
        assert np.abs(self.rollout(True, 0) - self.rollout(False, 0)).max() > 1e-4


class TestCli:
    def test_a_bad_stochastic_value_is_refused_naming_the_key(self, capsys):
        assert evaluate.main(["ckpt=missing.npz", "stochastic=maybe"]) == 2
        assert "stochastic" in capsys.readouterr().err
