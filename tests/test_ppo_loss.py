"""The PPO loss on hand-computed numbers."""

import math

import jax.numpy as jnp
import numpy as np

from ptrl_jax.core import distributions
from ptrl_jax.core.losses import LossInputs, ppo_loss


class TestPPOLoss:
    def test_hand_computed(self):
        # 1-D Gaussian, two samples. New policy: mean 0, std 1.
        mean = jnp.zeros((2, 1))
        std = jnp.ones((2, 1))
        action = jnp.array([[0.0], [1.0]])
        logp_new = np.array([-0.5 * math.log(2 * math.pi), -0.5 - 0.5 * math.log(2 * math.pi)])
        # Old log-probs chosen so that ratios are 1.5 and 0.5.
        old = logp_new - np.log([1.5, 0.5])
        adv = jnp.array([1.0, -2.0])
        batch = LossInputs(
            action=action, old_log_prob=jnp.asarray(old, jnp.float32), old_value=jnp.array([0.0, 1.0]),
            advantage=adv, target_return=jnp.array([1.0, 0.0]),
        )
        value = jnp.array([0.5, 2.0])
        terms = ppo_loss(mean, std, value, batch, clip_epsilon=0.2, value_coef=1.0, entropy_coef=0.01)
        # Policy: sample 0: max(-1*1.5, -1*1.2) = -1.2; sample 1: max(2*0.5, 2*0.8) = 1.6 -> mean 0.2
        np.testing.assert_allclose(terms.policy, 0.2, rtol=1e-5)
        # Value: sample 0: max((0.5-1)^2, (0+clip(0.5,-.2,.2)-1)^2 = 0.64) = 0.64
        #        sample 1: max((2-0)^2 = 4, (1+0.2-0)^2 = 1.44) = 4 -> mean 2.32
        np.testing.assert_allclose(terms.value, 2.32, rtol=1e-5)
        entropy = 0.5 * (1 + math.log(2 * math.pi))
        np.testing.assert_allclose(terms.entropy, entropy, rtol=1e-5)
        np.testing.assert_allclose(terms.total, 0.2 + 2.32 - 0.01 * entropy, rtol=1e-5)
        np.testing.assert_allclose(terms.clip_fraction, 1.0)

    def test_unclipped_value_loss(self):
        batch = LossInputs(jnp.zeros((1, 1)), jnp.zeros(1), jnp.array([0.0]), jnp.zeros(1), jnp.array([0.0]))
        terms = ppo_loss(jnp.zeros((1, 1)), jnp.ones((1, 1)), jnp.array([2.0]), batch, 0.2, 1.0, 0.0, clip_value=False)
        np.testing.assert_allclose(terms.value, 4.0)

    def test_a_traced_switch_picks_the_clipped_or_the_plain_value_loss(self):
        # old value 0, target 1, value 0.5: plain (0.5-1)^2 = 0.25; clipped (0.2-1)^2 = 0.64.
        batch = LossInputs(jnp.zeros((1, 1)), jnp.zeros(1), jnp.array([0.0]), jnp.zeros(1), jnp.array([1.0]))
        loss = lambda clip: ppo_loss(jnp.zeros((1, 1)), jnp.ones((1, 1)), jnp.array([0.5]), batch, 0.2, 1.0, 0.0,  # noqa: E731
                                     clip_value=clip).value
        np.testing.assert_allclose(loss(jnp.array(True)), 0.64, rtol=1e-6)
        np.testing.assert_allclose(loss(jnp.array(False)), 0.25, rtol=1e-6)
        np.testing.assert_allclose(loss(True), 0.64, rtol=1e-6)


class TestDistributions:
    def test_log_prob_matches_closed_form(self):
        a, m, s = jnp.array([[0.3, -1.0]]), jnp.array([[0.1, 0.0]]), jnp.array([[0.5, 2.0]])
        ref = sum(-0.5 * ((ai - mi) / si) ** 2 - math.log(si) - 0.5 * math.log(2 * math.pi)
                  for ai, mi, si in [(0.3, 0.1, 0.5), (-1.0, 0.0, 2.0)])
        np.testing.assert_allclose(distributions.log_prob(a, m, s), [ref], rtol=1e-6)

    def test_kl_zero_for_equal_and_positive_otherwise(self):
        m, s = jnp.array([[0.2, -0.1]]), jnp.array([[0.7, 1.3]])
        np.testing.assert_allclose(distributions.kl_divergence(m, s, m, s), [0.0], atol=1e-7)
        # KL(N(0,1) || N(1,1)) = 0.5
        np.testing.assert_allclose(distributions.kl_divergence(jnp.zeros((1, 1)), jnp.ones((1, 1)),
                                                               jnp.ones((1, 1)), jnp.ones((1, 1))), [0.5], rtol=1e-6)
