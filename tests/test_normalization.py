import jax.numpy as jnp
import numpy as np

from ptrl_jax.core import normalization


class TestRunningStats:
    def test_batched_updates_match_numpy(self):
        rng = np.random.default_rng(1)
        data = rng.normal(3.0, 2.0, size=(50, 4)).astype(np.float32)
        s = normalization.init(4)
        for chunk in np.split(data, [7, 20, 21]):
            s = normalization.update(s, jnp.asarray(chunk))
        np.testing.assert_allclose(s.mean, data.mean(0), rtol=1e-5)
        np.testing.assert_allclose(normalization.variance(s), data.var(0), rtol=1e-4)
        z = normalization.normalize(s, jnp.asarray(data))
        np.testing.assert_allclose(np.asarray(z).mean(0), 0.0, atol=1e-4)

    def test_non_finite_rows_are_skipped(self):
        s = normalization.update(normalization.init(2), jnp.array([[1.0, 1.0], [jnp.nan, 5.0], [3.0, 3.0]]))
        np.testing.assert_allclose(s.mean, [2.0, 2.0])
        assert float(s.count) == 2
