"""Export a trained actor for deployment outside JAX: ONNX, or a plain ``.npz`` with a numpy forward.

    python -m ptrl_jax.export ckpt=runs/go2_to_xbot/<stamp>/source.npz format=onnx [out=policy.onnx]
    python -m ptrl_jax.export ckpt=... format=npz

Both formats compute the deterministic action (the Gaussian's mean) from the *raw* observation:
the running observation normalisation is part of the exported graph,

    z = clip((obs - mean) * inv_std, -clip, clip),   inv_std = 1 / sqrt(var + eps)
    a = W3 elu(W2 elu(W1 elu(W0 z + b0) + b1) + b2) + b3

so a deployment feeds the observation exactly as the env builds it (its own scales included) and
gets the action the env expects (joint target = default pose + action_scale * a). The clip keeps
the normalisation from folding into the first layer exactly, hence the explicit nodes.

ONNX is optional (``pip install ptrl_jax[onnx]``); the ``.npz`` needs only numpy.
"""

from __future__ import annotations

import io
import json
import sys
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ptrl_jax.io.artifacts import CheckpointError, atomic_write_bytes
from ptrl_jax.config import NetworkConfig
from ptrl_jax.core.normalization import RunningStats, variance
from ptrl_jax.io.overrides import ConfigError, parse_cli

EXPORT_FORMAT = 1
NORMALIZER_CLIP = 10.0
NORMALIZER_EPS = 1e-8
ONNX_IR_VERSION = 10
"""onnx >= 1.23 writes IR 14 by default, which onnxruntime 1.31 refuses; 10 is read by both."""
ONNX_OPSET = 17


def actor_arrays(policy: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """The deterministic actor as numpy arrays: normaliser (mean, inv_std) and layer weights.

    ``policy`` is what ``ptrl_jax.evaluate.policy_from_checkpoint`` returns."""
    actor = policy["params"]["actor"]
    n_layers = len(actor)
    arrays: dict[str, np.ndarray] = {}
    obs_size = int(np.asarray(actor["layer_0"]["w"]).shape[0])
    if policy.get("normalize_observations", True):
        stats = policy["normalizer"]["state"]
        stats = RunningStats(*(np.asarray(x) for x in stats))
        arrays["obs_mean"] = np.asarray(stats.mean, np.float32)
        arrays["obs_inv_std"] = (1.0 / np.sqrt(np.asarray(variance(stats)) + NORMALIZER_EPS)).astype(np.float32)
    else:
        arrays["obs_mean"] = np.zeros(obs_size, np.float32)
        arrays["obs_inv_std"] = np.ones(obs_size, np.float32)
    for i in range(n_layers):
        arrays[f"layer_{i}/w"] = np.asarray(actor[f"layer_{i}"]["w"], np.float32)
        arrays[f"layer_{i}/b"] = np.asarray(actor[f"layer_{i}"]["b"], np.float32)
    return arrays


def _activation(name: str):
    if name == "elu":
        return lambda x: np.where(x > 0, x, np.expm1(np.minimum(x, 0)))
    if name == "tanh":
        return np.tanh
    if name == "relu":
        return lambda x: np.maximum(x, 0)
    raise ValueError(f"unknown activation {name!r}")


def numpy_forward(arrays: Mapping[str, np.ndarray], obs: np.ndarray, activation: str = "elu",
                  clip: float = NORMALIZER_CLIP) -> np.ndarray:
    """The exported actor in plain numpy: raw observation ``[..., obs]`` -> mean action."""
    act = _activation(activation)
    x = np.clip((np.asarray(obs, np.float32) - arrays["obs_mean"]) * arrays["obs_inv_std"], -clip, clip)
    n_layers = sum(1 for k in arrays if k.startswith("layer_") and k.endswith("/w"))
    for i in range(n_layers):
        x = x @ arrays[f"layer_{i}/w"] + arrays[f"layer_{i}/b"]
        if i < n_layers - 1:
            x = act(x)
    return x.astype(np.float32)


def deployment_meta(policy: Mapping[str, Any]) -> dict[str, Any]:
    """What a deployment needs besides the weights: the robot and how actions become targets."""
    env_cfg = policy["env"]
    network: NetworkConfig = policy["network"]
    actor = policy["params"]["actor"]
    return {
        "format": EXPORT_FORMAT,
        "robot": policy["robot"],
        "observation_size": int(np.asarray(actor["layer_0"]["w"]).shape[0]),
        "action_size": int(np.asarray(actor[f"layer_{len(actor) - 1}"]["w"]).shape[1]),
        "activation": network.activation,
        "normalizer_clip": NORMALIZER_CLIP,
        "action_scale": float(env_cfg.action_scale),
        "control_dt": float(env_cfg.ctrl_dt),
        "kp": [float(k) for k in env_cfg.kp],
        "kd": [float(k) for k in env_cfg.kd],
    }


def export_npz(policy: Mapping[str, Any], path: Path) -> Path:
    arrays = actor_arrays(policy)
    meta = deployment_meta(policy)
    buf = io.BytesIO()
    np.savez(buf, **arrays, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8))
    atomic_write_bytes(Path(path), buf.getvalue())
    return Path(path)


def load_npz(path: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files if k != "meta"}
        meta = json.loads(bytes(z["meta"]).decode())
    return arrays, meta


def onnx_model(policy: Mapping[str, Any]):
    """The actor as an ONNX graph: Sub, Mul, Clip (normaliser), then Gemm (+ activation) per layer."""
    try:
        import onnx
        from onnx import TensorProto, helper, numpy_helper
    except ImportError:  # pragma: no cover - exercised only without the extra
        raise ImportError("format=onnx needs the onnx package: pip install 'ptrl_jax[onnx]' "
                          "(or use format=npz, which needs only numpy)") from None

    arrays = actor_arrays(policy)
    meta = deployment_meta(policy)
    act_op = {"elu": "Elu", "tanh": "Tanh", "relu": "Relu"}[meta["activation"]]
    init = [
        numpy_helper.from_array(arrays["obs_mean"], "obs_mean"),
        numpy_helper.from_array(arrays["obs_inv_std"], "obs_inv_std"),
        numpy_helper.from_array(np.array(-NORMALIZER_CLIP, np.float32), "clip_lo"),
        numpy_helper.from_array(np.array(NORMALIZER_CLIP, np.float32), "clip_hi"),
    ]
    nodes = [
        helper.make_node("Sub", ["obs", "obs_mean"], ["centred"]),
        helper.make_node("Mul", ["centred", "obs_inv_std"], ["scaled"]),
        helper.make_node("Clip", ["scaled", "clip_lo", "clip_hi"], ["h_in"]),
    ]
    n_layers = sum(1 for k in arrays if k.endswith("/w"))
    x = "h_in"
    for i in range(n_layers):
        w, b = f"layer_{i}_w", f"layer_{i}_b"
        init += [numpy_helper.from_array(arrays[f"layer_{i}/w"], w), numpy_helper.from_array(arrays[f"layer_{i}/b"], b)]
        out = "action" if i == n_layers - 1 else f"pre_{i}"
        nodes.append(helper.make_node("Gemm", [x, w, b], [out]))
        if i < n_layers - 1:
            nodes.append(helper.make_node(act_op, [out], [f"h_{i}"]))
            x = f"h_{i}"
    graph = helper.make_graph(
        nodes, f"ptrl_actor_{meta['robot']}",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", meta["observation_size"]])],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", meta["action_size"]])],
        init,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", ONNX_OPSET)],
                              producer_name="ptrl_jax")
    model.ir_version = ONNX_IR_VERSION
    for k, v in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = k, json.dumps(v)
    onnx.checker.check_model(model)
    return model


def export_onnx(policy: Mapping[str, Any], path: Path) -> Path:
    model = onnx_model(policy)
    atomic_write_bytes(Path(path), model.SerializeToString())
    return Path(path)


FORMATS = {"onnx": (export_onnx, ".onnx"), "npz": (export_npz, ".policy.npz")}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(__doc__)
        return 0
    from ptrl_jax.evaluate import policy_from_checkpoint

    try:
        args = parse_cli(argv)
        if "ckpt" not in args:
            raise ConfigError("ckpt=PATH is required (a source.npz or target_*.npz of a run)")
        fmt = args.pop("format", "onnx")
        if fmt not in FORMATS:
            raise ConfigError(f"format={fmt!r}: choose one of {sorted(FORMATS)}")
        ckpt = Path(args.pop("ckpt"))
        fn, suffix = FORMATS[fmt]
        out = Path(args.pop("out", str(ckpt.with_suffix("")) + suffix))
        if args:
            raise ConfigError(f"unknown argument(s) {sorted(args)}; known: ckpt, format, out")
        policy = policy_from_checkpoint(str(ckpt))
        path = fn(policy, out)
    except (ConfigError, CheckpointError, ImportError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
