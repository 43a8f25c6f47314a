import os

import jax
import pytest

# Repeated CI runs and test processes reuse compiled XLA programs (MJX steps take ~25 s to compile).
_CACHE = os.environ.get("PTRL_JAX_CACHE", os.path.join(os.path.dirname(__file__), "..", ".jax_cache"))
jax.config.update("jax_compilation_cache_dir", os.path.abspath(_CACHE))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 2.0)


@pytest.fixture(scope="session")
def go2_env():
    import envs

    return envs.make("go2")


@pytest.fixture(scope="session")
def xbot_env():
    import envs

    return envs.make("xbot_l")
