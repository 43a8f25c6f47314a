"""GAE against a plain Python loop, with truncation kept apart from termination."""

import jax.numpy as jnp
import numpy as np

from ptrl_jax.core.losses import compute_gae


def gae_loop(rewards, values, next_values, term, trunc, gamma, lam):
    T, N = rewards.shape
    adv = np.zeros((T, N))
    for n in range(N):
        running = 0.0
        for t in reversed(range(T)):
            bootstrap = 0.0 if term[t, n] else next_values[t, n]
            delta = rewards[t, n] + gamma * bootstrap - values[t, n]
            if term[t, n] or trunc[t, n]:
                running = delta
            else:
                running = delta + gamma * lam * running
            adv[t, n] = running
    return adv, adv + values


class TestGAE:
    def test_matches_python_loop_with_terminations_and_truncations(self):
        rng = np.random.default_rng(0)
        T, N = 9, 5
        rewards = rng.normal(size=(T, N))
        values = rng.normal(size=(T, N))
        next_values = rng.normal(size=(T, N))
        term = np.zeros((T, N))
        trunc = np.zeros((T, N))
        term[3, 0] = term[7, 2] = 1
        trunc[5, 1] = trunc[2, 2] = trunc[8, 4] = 1
        adv, ret = compute_gae(*map(jnp.asarray, (rewards, values, next_values, term, trunc)), 0.99, 0.9)
        ref_adv, ref_ret = gae_loop(rewards, values, next_values, term, trunc, 0.99, 0.9)
        np.testing.assert_allclose(adv, ref_adv, rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(ret, ref_ret, rtol=1e-5, atol=1e-5)

    def test_hand_computed_single_step(self):
        # One step, reward 1, V(s)=0.5, V(s')=2, gamma 0.5:
        # truncation bootstraps: A = 1 + 0.5*2 - 0.5 = 1.5; termination does not: A = 1 - 0.5 = 0.5.
        args = lambda term, trunc: (jnp.array([[1.0]]), jnp.array([[0.5]]), jnp.array([[2.0]]),  # noqa: E731
                                    jnp.array([[term]]), jnp.array([[trunc]]))
        adv_trunc, _ = compute_gae(*args(0.0, 1.0), 0.5, 0.95)
        adv_term, _ = compute_gae(*args(1.0, 0.0), 0.5, 0.95)
        assert float(adv_trunc[0, 0]) == 1.5
        assert float(adv_term[0, 0]) == 0.5

    def test_episode_boundary_stops_the_recursion(self):
        # Two steps; step 0 truncated: A_0 must not include anything from step 1.
        r = jnp.array([[1.0], [10.0]])
        v = jnp.zeros((2, 1))
        nv = jnp.zeros((2, 1))
        adv, _ = compute_gae(r, v, nv, jnp.zeros((2, 1)), jnp.array([[1.0], [0.0]]), 0.9, 0.9)
        assert float(adv[0, 0]) == 1.0
