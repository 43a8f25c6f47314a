"""Hand-written Adam, clipping and the adaptive-KL rule against hand-computed steps."""

import math

import jax.numpy as jnp
import numpy as np

from ptrl_jax.core.optim import (
    adaptive_kl_learning_rate, apply_updates, chain, clip_by_global_norm, global_norm, scale_by_adam,
)


class TestAdam:
    def test_first_two_steps_by_hand(self):
        opt = scale_by_adam(b1=0.9, b2=0.999, eps=1e-8)
        params = {"w": jnp.array([1.0, -2.0])}
        state = opt.init(params)
        g1 = {"w": jnp.array([0.5, -1.0])}
        d1, state = opt.update(g1, state, params)
        # Step 1: m = 0.1 g, v = 0.001 g^2, m^ = g, v^ = g^2 -> direction = g/|g| = sign(g).
        # rtol 1e-5: 1 - 0.999 has a ~1e-5 relative rounding error in float32.
        np.testing.assert_allclose(d1["w"], [1.0, -1.0], rtol=1e-5)
        g2 = {"w": jnp.array([-0.5, 2.0])}
        d2, state = opt.update(g2, state, params)
        m = 0.9 * 0.1 * np.array([0.5, -1.0]) + 0.1 * np.array([-0.5, 2.0])
        v = 0.999 * 0.001 * np.array([0.25, 1.0]) + 0.001 * np.array([0.25, 4.0])
        expected = (m / (1 - 0.9**2)) / (np.sqrt(v / (1 - 0.999**2)) + 1e-8)
        np.testing.assert_allclose(d2["w"], expected, rtol=1e-5)
        assert np.all(np.asarray(state.count["w"]) == 2)
        new = apply_updates(params, d2, 0.1)
        np.testing.assert_allclose(new["w"], params["w"] - 0.1 * expected, rtol=1e-6)


    def test_an_entry_held_out_starts_its_bias_correction_when_it_starts(self):
        """Under ``freeze.masked``, an entry frozen for 100 steps and then released takes the
        first step of a fresh Adam (sign of g), not one corrected for 100 steps of zero moments."""
        from ptrl_jax.core.freeze import masked

        params = {"w": jnp.array([1.0, -2.0])}
        g = {"w": jnp.array([0.5, -1.0])}
        held = masked(scale_by_adam(), {"w": jnp.array([False, True])})
        state = held.init(params)
        for _ in range(100):
            _, state = held.update(g, state, params)
        np.testing.assert_array_equal(np.asarray(state.count["w"]), [100, 0])
        released = masked(scale_by_adam(), {"w": jnp.array([False, False])})
        d, state = released.update(g, state, params)
        np.testing.assert_allclose(d["w"][1], -1.0, rtol=1e-5)  # a first step: the sign of g
        np.testing.assert_array_equal(np.asarray(state.count["w"]), [101, 1])


class TestClipByGlobalNorm:
    def test_rescales_to_max_norm(self):
        g = {"a": jnp.array([3.0]), "b": jnp.array([4.0])}  # norm 5
        clipped, _ = clip_by_global_norm(1.0).update(g, (), None)
        np.testing.assert_allclose(global_norm(clipped), 1.0, rtol=1e-6)
        np.testing.assert_allclose(clipped["a"], [0.6], rtol=1e-6)

    def test_leaves_small_gradients_alone(self):
        g = {"a": jnp.array([0.3])}
        clipped, _ = clip_by_global_norm(1.0).update(g, (), None)
        np.testing.assert_allclose(clipped["a"], [0.3])

    def test_chain_applies_in_order(self):
        opt = chain(clip_by_global_norm(1.0), scale_by_adam())
        params = {"a": jnp.array([0.0, 0.0])}
        d, _ = opt.update({"a": jnp.array([30.0, 40.0])}, opt.init(params), params)
        np.testing.assert_allclose(d["a"], [1.0, 1.0], rtol=1e-5)  # first Adam step = sign


class TestAdaptiveKL:
    def test_rsl_rl_rule(self):
        f = lambda lr, kl: float(adaptive_kl_learning_rate(jnp.float32(lr), jnp.float32(kl), 0.01, 1e-5, 1e-2))  # noqa: E731
        assert math.isclose(f(1e-3, 0.05), 1e-3 / 1.5, rel_tol=1e-6)  # KL > 2 target
        assert math.isclose(f(1e-3, 0.001), 1e-3 * 1.5, rel_tol=1e-6)  # 0 < KL < target / 2
        assert math.isclose(f(1e-3, 0.01), 1e-3, rel_tol=1e-6)  # in band
        assert math.isclose(f(1e-3, 0.0), 1e-3, rel_tol=1e-6)  # zero KL: unchanged
        assert math.isclose(f(9e-3, 0.001), 1e-2, rel_tol=1e-6)  # upper bound
        assert math.isclose(f(1.2e-5, 1.0), 1e-5, rel_tol=1e-6)  # lower bound
