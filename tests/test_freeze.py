"""Freezing: frozen leaves bitwise unchanged under Adam with non-zero moments; unfrozen move."""

import jax
import jax.numpy as jnp
import numpy as np

from ptrl_jax.config import NetworkConfig
from ptrl_jax.core.freeze import (FREEZE_PRESETS, count_frozen, frozen_fraction, frozen_share, masked, preset_mask,
                                  variant)
from ptrl_jax.core.networks import init_actor_critic
from ptrl_jax.core.optim import AdamState, apply_updates, chain, clip_by_global_norm, global_norm, scale_by_adam

NET = NetworkConfig(actor_hidden=(16, 8, 4), critic_hidden=(8, 8, 8))


def small_params(key=0):
    return init_actor_critic(jax.random.PRNGKey(key), NET, obs_size=5, privileged_obs_size=6, action_size=3)


def random_like(tree, key, scale=1.0):
    leaves, treedef = jax.tree.flatten(tree)
    keys = jax.random.split(jax.random.PRNGKey(key), len(leaves))
    return jax.tree.unflatten(treedef, [scale * jax.random.normal(k, x.shape) for k, x in zip(keys, leaves)])


class TestMasks:
    def test_presets_freeze_the_named_layers_only(self):
        p = small_params()
        for name, preset in FREEZE_PRESETS.items():
            mask = preset_mask(p, name)
            for path, leaf in jax.tree_util.tree_leaves_with_path(mask):
                keys = [k.key for k in path]
                expected = keys[0] == "actor" and keys[1] in {
                    {"L1": "layer_1", "L2": "layer_2"}[layer] for layer in preset.frozen
                }
                assert bool(leaf.all()) == expected and bool(leaf.any()) == expected, (name, keys)
        assert count_frozen(preset_mask(p, "L1")) == 16 * 8 + 8
        assert count_frozen(preset_mask(p, "L1+L2")) == 16 * 8 + 8 + 8 * 4 + 4


class TestFreezeRatio:
    """rho freezes the first ceil(rho n) output units of L1 (16x8 here) and L2 (8x4)."""

    def test_quarter_freezes_the_first_units_of_each_layer(self):
        mask = preset_mask(small_params(), "rho0.25")
        l1, l2 = mask["actor"]["layer_1"], mask["actor"]["layer_2"]
        # ceil(0.25 * 8) = 2 of L1's units, ceil(0.25 * 4) = 1 of L2's: columns and biases.
        np.testing.assert_array_equal(l1["w"], np.broadcast_to(np.arange(8) < 2, (16, 8)))
        np.testing.assert_array_equal(l1["b"], np.arange(8) < 2)
        np.testing.assert_array_equal(l2["w"], np.broadcast_to(np.arange(4) < 1, (8, 4)))
        np.testing.assert_array_equal(l2["b"], np.arange(4) < 1)
        assert count_frozen(mask) == 2 * 17 + 1 * 9  # nothing outside L1 and L2

    def test_rounds_up_to_whole_units(self):
        # 0.3 * 8 = 2.4 -> 3 units; 0.3 * 4 = 1.2 -> 2 units.
        mask = preset_mask(small_params(), "rho0.3")
        assert count_frozen(mask) == 3 * 17 + 2 * 9
        assert abs(frozen_fraction(mask) - (3 * 17 + 2 * 9) / (8 * 17 + 4 * 9)) < 1e-12

    def test_ends_equal_the_paper_presets(self):
        p = small_params()
        for rho, preset in ((0.0, "none"), (1.0, "L1+L2")):
            got, want = preset_mask(p, f"rho{rho:g}"), preset_mask(p, preset)
            assert jax.tree.all(jax.tree.map(lambda a, b: bool((a == b).all()), got, want)), rho
        assert frozen_fraction(preset_mask(p, "rho1")) == 1.0
        assert frozen_fraction(preset_mask(p, "rho0")) == 0.0

    def test_frozen_share_from_sizes_alone(self):
        """The x axis of merged freeze-ratio curves: L1 and L2 of the paper's sizes hold
        512*256+256 = 131,328 and 256*128+128 = 32,896 parameters."""
        assert frozen_share(variant("L2@semantic_output")) == 32896 / (131328 + 32896)  # 0.2003
        assert frozen_share(variant("L1")) == 131328 / (131328 + 32896)
        assert frozen_share(variant("rho0.5")) == 0.5  # 128 * 513 + 64 * 257 = half of 164,224
        assert frozen_share(variant("none")) == 0.0 and frozen_share(variant("scratch")) == 0.0
        assert frozen_share(variant("rho1@semantic")) == 1.0

    def test_frozen_share_agrees_with_the_mask(self):
        p = small_params()  # actor hidden (16, 8, 4)
        for name in ("L1", "L2", "rho0.3", "rho0.25@semantic_actor", "L1+L2"):
            assert abs(frozen_share(variant(name), (16, 8, 4)) - frozen_fraction(preset_mask(p, name))) < 1e-12, name

    def test_ratio_variants_transfer(self):
        assert variant("rho0.5").transfer and variant("rho0.5").ratio == 0.5

    def test_bad_names_are_refused(self):
        for bad in ("rho1.5", "rho-0.1", "rhox", "L3"):
            try:
                variant(bad)
            except ValueError as e:
                assert bad in str(e) or "[0, 1]" in str(e)
            else:
                raise AssertionError(f"{bad} was accepted")


class TestMaskedAdam:
    def test_frozen_leaves_bitwise_unchanged_with_nonzero_moments(self):
        params = small_params()
        frozen = preset_mask(params, "L1+L2")
        opt = masked(chain(clip_by_global_norm(1.0), scale_by_adam()), frozen)
        # Moments restored from "pretraining": non-zero everywhere, frozen leaves included.
        clip_state, adam = opt.init(params)
        adam = AdamState(count=jax.tree.map(lambda p: jnp.full(p.shape, 100, jnp.int32), params),
                         mu=random_like(params, 1), nu=jax.tree.map(jnp.abs, random_like(params, 2)))
        state = (clip_state, adam)
        start = params

        @jax.jit
        def step(params, state, i):
            grads = random_like(params, i + 10, scale=5.0)
            d, state = opt.update(grads, state, params)
            return apply_updates(params, d, 1e-2), state

        for i in range(50):
            params, state = step(params, state, i)
        for (path, a), b, m in zip(jax.tree_util.tree_leaves_with_path(start), jax.tree.leaves(params), jax.tree.leaves(frozen)):
            a, b, m = map(np.asarray, (a, b, m))
            assert np.array_equal(a[m], b[m]), jax.tree_util.keystr(path)  # bitwise
            if (~m).any():
                assert not np.allclose(a[~m], b[~m]), jax.tree_util.keystr(path)
        # Frozen leaves' moments are untouched.
        for m0, m1, msk in zip(jax.tree.leaves(adam.mu), jax.tree.leaves(state[1].mu), jax.tree.leaves(frozen)):
            assert np.array_equal(np.asarray(m0)[np.asarray(msk)], np.asarray(m1)[np.asarray(msk)])

    def test_frozen_gradients_do_not_count_in_clipping(self):
        params = {"a": jnp.zeros(1), "b": jnp.zeros(1)}
        frozen = {"a": jnp.array([True]), "b": jnp.array([False])}
        seen = {}

        def spy_update(grads, state, p):
            seen["norm"] = global_norm(grads)
            return grads, state

        from ptrl_jax.core.optim import Optimizer

        opt = masked(chain(Optimizer(lambda p: (), spy_update), clip_by_global_norm(1.0)), frozen)
        d, _ = opt.update({"a": jnp.array([100.0]), "b": jnp.array([0.5])}, opt.init(params), params)
        np.testing.assert_allclose(seen["norm"], 0.5)
        np.testing.assert_allclose(d["b"], [0.5])  # not shrunk by the frozen 100
        assert float(d["a"][0]) == 0.0

    def test_nan_in_frozen_gradient_does_not_leak(self):
        params = {"a": jnp.ones(2), "b": jnp.ones(2)}
        frozen = {"a": jnp.array([True, True]), "b": jnp.array([False, False])}
        opt = masked(chain(clip_by_global_norm(1.0), scale_by_adam()), frozen)
        d, _ = opt.update({"a": jnp.array([jnp.nan, 1.0]), "b": jnp.array([0.1, 0.2])}, opt.init(params), params)
        assert np.all(np.isfinite(d["b"])) and np.all(np.asarray(d["a"]) == 0.0)

    def test_masks_vmap_in_one_program(self):
        params = small_params()
        masks = jax.tree.map(lambda *m: jnp.stack(m), *[preset_mask(params, p) for p in ("none", "L1", "L2")])
        grads = random_like(params, 3)

        def one(mask):
            opt = masked(scale_by_adam(), mask)
            d, _ = opt.update(grads, opt.init(params), params)
            return apply_updates(params, d, 0.1)

        out = jax.jit(jax.vmap(one))(masks)
        l1 = np.asarray(out["actor"]["layer_1"]["w"])
        assert not np.array_equal(l1[0], params["actor"]["layer_1"]["w"])  # none: moves
        assert np.array_equal(l1[1], params["actor"]["layer_1"]["w"])  # L1: frozen
        assert not np.array_equal(l1[2], params["actor"]["layer_1"]["w"])  # L2: L1 moves
