import os

# Headless offscreen rendering: MuJoCo picks its GL backend when first imported, and a test
# module may import mujoco before `envs` sets this default.
os.environ.setdefault("MUJOCO_GL", "egl")
# The suite is compile-bound (small env counts, few steps): the smoke run's XLA settings
# (ptrl_jax/io/xla_flags.py: about 2.5x faster XLA compiles). Set before jax creates its backend;
# the CLI subprocesses of the resume tests inherit them.
from ptrl_jax.io.xla_flags import use_fast_compile  # noqa: E402

use_fast_compile()

import jax  # noqa: E402
import pytest  # noqa: E402

# Repeated CI runs and test processes reuse compiled XLA programs (MJX steps take ~25 s to compile).
_CACHE = os.environ.get("PTRL_JAX_CACHE", os.path.join(os.path.dirname(__file__), "..", ".jax_cache"))
jax.config.update("jax_compilation_cache_dir", os.path.abspath(_CACHE))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 2.0)
# The CLI subprocess of tests/test_resume.py gets the same setting, so that it finds this
# process's compiled smoke program in the cache (measured: it hits, and then only traces, ~1 min).
jax.config.update("jax_include_full_tracebacks_in_locations", False)


# The costliest groups (minutes of tracing and compiling each) go first, so that the two xdist
# workers start on them and finish together; then the groups of one robot's MJX compile each; the
# rest is seconds-long tests that fill the gaps. pyproject's `--no-loadscope-reorder` makes xdist
# hand out the groups in this order (by default it sorts them by their number of tests, which put
# the 3-minute mit_to_xbot group near the end and left one worker idle for minutes).
_FIRST = ("xbot_to_all", "smoke_go2_to_xbot", "mit_to_xbot", "engine_mujoco_resume", "two_devices",
          "two_processes")
_COMPILE_GROUPS = ("walk_", "engine_", "closing_noise", "go2_step", "sim_to_sim", "brax_contract", "toy_robot")


def pytest_collection_modifyitems(config, items):
    def rank(item):
        groups = [m.args[0] for m in item.iter_markers("xdist_group") if m.args]
        first = min((_FIRST.index(g) for g in groups if g in _FIRST), default=None)
        if first is not None:
            return first
        return len(_FIRST) + (0 if any(g.startswith(_COMPILE_GROUPS) for g in groups) else 1)

    items.sort(key=rank)  # stable: the order within a rank is kept


@pytest.fixture(scope="session")
def go2_env():
    import envs

    return envs.make("go2")


@pytest.fixture(scope="session")
def xbot_env():
    import envs

    return envs.make("xbot_l")


@pytest.fixture(scope="session")
def smoke_run(tmp_path_factory):
    """One uninterrupted ``scale=smoke`` go2_to_xbot run, shared by the end-to-end and resume tests."""
    from ptrl_jax import run as run_cli
    from ptrl_jax.io.overrides import load_experiment

    runs = tmp_path_factory.mktemp("runs")
    cfg = load_experiment("go2_to_xbot", ["scale=smoke", f"runs_dir={runs}", "tensorboard=true"])
    result = run_cli.run(cfg)
    return cfg, result["run_dir"]
