"""Transfer copies exactly the actor's L1 and L2 and nothing else."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ptrl_jax.config import NetworkConfig
from ptrl_jax.core.freeze import transfer
from ptrl_jax.core.networks import init_actor_critic

NET = NetworkConfig(actor_hidden=(16, 8, 4), critic_hidden=(8, 8, 8))


def leaves_by_path(tree):
    return {jax.tree_util.keystr(p): np.asarray(x) for p, x in jax.tree_util.tree_leaves_with_path(tree)}


class TestTransfer:
    def test_copies_l1_l2_only(self):
        source = init_actor_critic(jax.random.PRNGKey(0), NET, 45, 53, 12)  # quadruped-like
        target = init_actor_critic(jax.random.PRNGKey(1), NET, 705, 67, 10)  # biped-like, other sizes
        out = leaves_by_path(transfer(source, target))
        src, tgt = leaves_by_path(source), leaves_by_path(target)
        copied = {p for p in out if "'layer_1'" in p or "'layer_2'" in p}
        copied = {p for p in copied if p.startswith("['actor']")}
        assert copied == {"['actor']['layer_1']['w']", "['actor']['layer_1']['b']",
                          "['actor']['layer_2']['w']", "['actor']['layer_2']['b']"}
        for p in out:
            if p in copied:
                assert np.array_equal(out[p], src[p]), p
            else:
                assert np.array_equal(out[p], tgt[p]), p  # input/output layers, log_std, critic: fresh

    def test_disabled_transfer_is_the_scratch_baseline(self):
        source = init_actor_critic(jax.random.PRNGKey(0), NET, 45, 53, 12)
        target = init_actor_critic(jax.random.PRNGKey(1), NET, 47, 50, 12)
        out = jax.jit(transfer)(source, target, jnp.array(False))
        for a, b in zip(jax.tree.leaves(out), jax.tree.leaves(target)):
            assert np.array_equal(a, b)

    def test_mismatched_hidden_sizes_are_refused(self):
        source = init_actor_critic(jax.random.PRNGKey(0), NET, 45, 53, 12)
        other = init_actor_critic(jax.random.PRNGKey(1), NetworkConfig(actor_hidden=(16, 9, 4)), 45, 53, 12)
        with pytest.raises(ValueError, match="layer_1"):
            transfer(source, other)
