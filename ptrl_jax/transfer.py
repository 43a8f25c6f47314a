"""The transfer as a tool outside a run: write a target robot's initial checkpoint from a source.

    python -m ptrl_jax.transfer source=runs/go2_to_xbot/<stamp>/source.npz target=a1 mode=semantic out=a1_init.npz
    python -m ptrl_jax.run exp=a1_from_scratch init_checkpoint=a1_init.npz freeze_presets=[none,scratch]

``mode=semantic`` maps the whole agent through the robots' declarations (``ptrl_jax.core.semantic``),
``mode=semantic_actor`` the same with a fresh critic, ``mode=semantic_input`` maps only the actor's
input layer and the normaliser (its hidden layers copied, output layer, log-std and critic fresh),
``mode=semantic_output`` maps only its output layer and log-std (input layer, normaliser and
critic fresh, hidden layers copied),
``mode=paper`` copies the actor's L1 and L2 into a fresh network (``freeze.transfer``). The
checkpoint holds the parameters, the normaliser statistics, an all-false freeze mask and, in
its metadata, the map (each target joint's source joint and factor, the matched observation
entries), so a transfer can be inspected, evaluated (``ptrl_jax.evaluate ckpt=...``: the
zero-shot policy) or fine-tuned with any settings (``init_checkpoint=``). Optional keys:
``seed=K`` (the fresh initialisation of what is not transferred), ``joint_map=[t:s,...]``,
``unmapped_blocks=[...]``, ``knee=axis|flexion`` and ``noise_std=S`` as ``transfer.joint_map`` /
``transfer.unmapped_blocks`` / ``transfer.knee`` / ``transfer.noise_std`` of a run.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import jax
import numpy as np

import envs
from ptrl_jax.core import normalization, semantic
from ptrl_jax.io import artifacts
from ptrl_jax.io.artifacts import CheckpointError
from ptrl_jax.config import TransferConfig
from ptrl_jax.core.freeze import TRANSFER_MODES, empty_mask, transfer
from ptrl_jax.core.networks import init_actor_critic
from ptrl_jax.io.overrides import ConfigError, coerce, parse_known_cli, to_dict

KEYS = ("source", "target", "mode", "out", "seed", "joint_map", "unmapped_blocks", "knee", "noise_std")


def transfer_policy(policy: dict[str, Any], target_robot: str, mode: str = "semantic", seed: int = 0,
                    transfer_cfg: TransferConfig | None = None, target_env_cfg: Any = None) -> dict[str, Any]:
    """A target robot's initial ``{"params", "normalizer", "meta"}`` from a source policy
    (``evaluate.policy_from_checkpoint``'s dict)."""
    if mode not in TRANSFER_MODES:
        raise ConfigError(f"mode={mode!r}: choose one of {list(TRANSFER_MODES)}")
    transfer_cfg = transfer_cfg or TransferConfig(mode=mode)
    try:
        target_env = envs.make(target_robot, target_env_cfg)
    except ValueError as e:
        raise ConfigError(f"target: {e}") from None
    source_env = envs.make(policy["robot"], policy["env"])
    obs = jax.eval_shape(target_env.reset, jax.random.PRNGKey(0)).obs
    sizes = {k: int(v.shape[-1]) for k, v in obs.items()}
    network = policy["network"]
    fresh = init_actor_critic(jax.random.PRNGKey(seed), network, sizes["state"], sizes["privileged_state"],
                              target_env.action_size)
    fresh_norm = {k: normalization.init(n) for k, n in sizes.items()}
    meta: dict[str, Any] = {"robot": target_robot, "stage": "transfer", "preset": mode, "seed": seed,
                            "source_robot": policy["robot"], "network": to_dict(network),
                            "env": to_dict(target_env.config), "normalize_observations": policy["normalize_observations"]}
    if mode == "paper":
        params, norm = transfer(policy["params"], fresh, True), fresh_norm
        meta["transfer"] = {"mode": "paper", "copied": ["actor/layer_1", "actor/layer_2"]}
    else:
        try:
            tmap = semantic.build_map(source_env, target_env, transfer_cfg.joint_map, transfer_cfg.unmapped_blocks,
                                      transfer_cfg.knee)
        except ValueError as e:
            raise ConfigError(str(e)) from None
        mapped = semantic.fresh_switches(mode)
        params, norm = semantic.apply(tmap, policy["params"], policy["normalizer"], fresh, fresh_norm,
                                      transfer_cfg.noise_std, **mapped)
        said = lambda kept: "mapped" if kept else "fresh"  # noqa: E731
        meta["transfer"] = {"mode": mode, "noise_std": transfer_cfg.noise_std, "knee": transfer_cfg.knee,
                            "critic": said(mapped["critic"]), "input_layer": said(mapped["input_layer"]),
                            "output_layer": said(mapped["output"]), **tmap.describe()}
    to_np = lambda t: jax.tree.map(np.asarray, t)  # noqa: E731
    return {"params": to_np(params), "normalizer": to_np(norm), "meta": meta}


def main(argv: list[str] | None = None) -> int:
    from ptrl_jax.evaluate import policy_from_checkpoint

    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(__doc__)
        return 0
    try:
        args = parse_known_cli(argv, KEYS)
        for key in ("source", "target", "out"):
            if key not in args:
                raise ConfigError(f"{key}= is required: python -m ptrl_jax.transfer source=SRC.npz "
                                  f"target=ROBOT mode={'|'.join(TRANSFER_MODES)} out=OUT.npz")
        mode = args.get("mode", "semantic")
        out = Path(args["out"])
        if out.exists() and out.resolve() == Path(args["source"]).resolve():
            raise ConfigError(f"out={out} is the source checkpoint; choose another file")
        transfer_cfg = TransferConfig(
            mode=mode if mode in TRANSFER_MODES else "paper",
            joint_map=coerce(args.get("joint_map", ()), tuple[str, ...], "joint_map"),
            unmapped_blocks=coerce(args.get("unmapped_blocks", ()), tuple[str, ...], "unmapped_blocks"),
            knee=str(args.get("knee", TransferConfig.knee)),
            noise_std=coerce(args.get("noise_std", 0.0), float, "noise_std"))
        policy = policy_from_checkpoint(args["source"])
        result = transfer_policy(policy, args["target"], mode, coerce(args.get("seed", 0), int, "seed"), transfer_cfg)
    except (ConfigError, CheckpointError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    params = result["params"]
    artifacts.save_checkpoint(out, params, result["normalizer"], jax.tree.map(np.asarray, empty_mask(params)),
                              result["meta"])
    t = result["meta"]["transfer"]
    if t["mode"] != "paper":
        pairs = ", ".join(f"{j['target']}<-{j['source'] or 'fresh'}" for j in t["joints"])
        print(f"{t['mode']} transfer {result['meta']['source_robot']} -> {args['target']}: joints {pairs}; "
              f"observation entries matched {t['matched_entries']} of {t['entries']}", file=sys.stderr)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
