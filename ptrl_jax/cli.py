"""The ``ptrl-jax`` console script: ``ptrl-jax run|evaluate|export|transfer|table4 key=value ...``.

Each command is the module of the same name, as ``python -m ptrl_jax.<command>`` runs it:

    ptrl-jax run exp=go2_to_xbot scale=smoke
    ptrl-jax evaluate ckpt=runs/go2_to_xbot/<stamp>/source.npz check=true
    ptrl-jax export ckpt=... out=policy.onnx
    ptrl-jax transfer source=<run>/source.npz target=a1 mode=semantic out=a1_init.npz
    ptrl-jax table4 runs=[runs/go2_to_anymal_b/<stamp>,runs/go2_to_anymal_b_axis/<stamp>]
"""

from __future__ import annotations

import difflib
import importlib
import sys

COMMANDS = {
    "run": ("ptrl_jax.run", "train a preset: source, transfer, every target variant (exp=NAME)"),
    "evaluate": ("ptrl_jax.evaluate", "play a checkpoint: walking check, sim-to-sim, figures (ckpt=PATH)"),
    "export": ("ptrl_jax.export", "write a checkpoint's policy as ONNX (ckpt=PATH out=PATH)"),
    "transfer": ("ptrl_jax.transfer", "write a target robot's transferred initial checkpoint (source= target= out=)"),
    "table4": ("ptrl_jax.table4", "Table IV from finished runs, several programs paired by seed (runs=[DIR,...])"),
}


def usage() -> str:
    width = max(map(len, COMMANDS))
    lines = ["usage: ptrl-jax COMMAND key=value ...", "", "commands:"]
    lines += [f"  {name:<{width}}  {doc}" for name, (_, doc) in COMMANDS.items()]
    lines += ["", "Each is also `python -m ptrl_jax.<command>`; README.md lists the keys."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(usage())
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        near = difflib.get_close_matches(name, list(COMMANDS), n=1)
        hint = f"; did you mean '{near[0]}'?" if near else ""
        print(f"error: unknown command {name!r}{hint}\n\n{usage()}", file=sys.stderr)
        return 2
    if name == "run":
        # Before jax's backend exists, as `python -m ptrl_jax.run` does (ptrl_jax/io/xla_flags.py).
        from ptrl_jax.io.xla_flags import configure_from_argv

        configure_from_argv(rest)
        from ptrl_jax.io.hosts import HostsError, start_from_argv  # jax.distributed, as ptrl_jax.run does

        try:
            rest = start_from_argv(rest)
        except HostsError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
    module = importlib.import_module(COMMANDS[name][0])
    return module.main(rest)


if __name__ == "__main__":
    sys.exit(main())
