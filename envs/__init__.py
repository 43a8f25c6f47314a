"""Legged-robot environments on Brax + MuJoCo MJX. This package never imports the trainer.

    import envs
    env = envs.make("go2")                      # default config
    env = envs.make("go2", envs.default_config("go2"))
    gym_env = gymnasium.make("ptrl/Go2-v0")     # MuJoCo C, numpy (envs.gym_env)
"""

import os
import warnings

# Offscreen rendering (Gymnasium's rgb_array, filmstrips) on headless machines: EGL. MuJoCo reads
# this when it first loads, so it is set before anything imports mujoco; a user's choice wins.
os.environ.setdefault("MUJOCO_GL", "egl")

# Brax warns on every model load that its own pipelines are unmaintained; we only use its
# PipelineEnv structure on MuJoCo MJX, which is maintained.
warnings.filterwarnings("ignore", message="Brax System, piplines and environments", category=UserWarning)


def _import_mjx_quietly() -> None:
    """Import MJX with its optional Warp backend's import report swallowed. MJX tries Warp (a GPU
    backend these envs do not use) on import and prints "Failed to import warp" twice to standard
    output when it is absent, ahead of any command's output. Anything else it prints goes to
    standard error."""
    import contextlib
    import io
    import sys

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        import mujoco.mjx  # noqa: F401
    other = [line for line in buf.getvalue().splitlines()
             if not line.startswith(("Failed to import warp:", "Failed to import mujoco_warp:"))]
    if other:
        print("\n".join(other), file=sys.stderr)


_import_mjx_quietly()

from envs.base import asset_sha256  # noqa: E402
from envs.registry import ROBOTS, default_config, family, make, robot_names  # noqa: E402
from envs.gym_env import GYM_IDS, LocomotionGymEnv, register as _register_gymnasium  # noqa: E402

_register_gymnasium()  # gymnasium.make("ptrl/Go2-v0") works once `envs` is imported

__all__ = ["GYM_IDS", "ROBOTS", "LocomotionGymEnv", "asset_sha256", "default_config", "family", "make", "robot_names"]
