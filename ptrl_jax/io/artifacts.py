"""What a run leaves on disk: config, metrics.csv, checkpoints, curves and report.

Everything here runs on the host after (or around) the jitted program; nothing is traced.
Files are written atomically (temp file, then ``os.replace``), so a crash never leaves a
half-written checkpoint or CSV behind.
"""

from __future__ import annotations

import csv
import io
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Mapping, Sequence

import jax
import numpy as np
import yaml

CHECKPOINT_FORMAT = 1
STATE_FORMAT = 2
"""Layout of the resumable program state (``save_state``). 2 (2026-12-05): Adam's step count per
parameter entry, and ``PPOHparams.critic_warmup``. A state of another layout is refused by name."""


def atomic_write_bytes(path: Path, data: bytes) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, text.encode())


def write_config(path: Path, config: Mapping[str, Any]) -> None:
    atomic_write_text(path, yaml.safe_dump(config, sort_keys=False))


def flatten_tree(tree: Any, prefix: str) -> dict[str, np.ndarray]:
    out = {}
    for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
        parts = [str(getattr(k, "key", getattr(k, "name", getattr(k, "idx", k)))) for k in path]
        out["/".join([prefix, *parts])] = np.asarray(leaf)
    return out


def save_checkpoint(
    path: Path, params: Any, normalizer: Any, frozen: Any, meta: Mapping[str, Any]
) -> None:
    """``.npz`` keyed by parameter path: ``params/actor/layer_1/w``, ``normalizer/state/mean``,
    ``frozen/actor/layer_1/w``, plus ``meta`` (JSON: robot, preset, sizes, format)."""
    arrays = {
        **flatten_tree(params, "params"),
        **flatten_tree(normalizer, "normalizer"),
        **flatten_tree(frozen, "frozen"),
    }
    arrays["meta"] = np.frombuffer(json.dumps({"format": CHECKPOINT_FORMAT, **meta}).encode(), np.uint8)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())


class CheckpointError(ValueError):
    pass


def _read_npz(path: Path, what: str) -> dict[str, np.ndarray]:
    """Every array of an ``.npz``; a missing or damaged file is a CheckpointError naming it."""
    if not path.is_file():
        raise CheckpointError(f"{what} {path} does not exist")
    try:
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    except Exception as e:  # zipfile / pickle / value errors of a damaged file
        raise CheckpointError(f"{what} {path} is unreadable (truncated or corrupted?): {e}") from None


def load_checkpoint(path: Path) -> dict[str, Any]:
    """Return {"params", "normalizer", "frozen": nested dicts of arrays, "meta": dict}."""
    path = Path(path)
    flat = _read_npz(path, "checkpoint")
    if "meta" not in flat:
        raise CheckpointError(f"checkpoint {path} has no 'meta' entry: not a ptrl_jax checkpoint")
    meta = json.loads(bytes(flat.pop("meta")).decode())
    out: dict[str, Any] = {"params": {}, "normalizer": {}, "frozen": {}, "meta": meta}
    for key, value in flat.items():
        group, *parts = key.split("/")
        if group not in out:
            raise CheckpointError(f"checkpoint {path}: unexpected entry {key!r}")
        node = out[group]
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = value
    return out


def write_metrics_csv(path: Path, rows: Sequence[Mapping[str, Any]]) -> None:
    fields: list[str] = []
    for row in rows:
        for k in row:
            if k not in fields:
                fields.append(k)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields)
    writer.writeheader()
    for row in rows:
        writer.writerow({k: _fmt(row.get(k, "")) for k in fields})
    atomic_write_text(path, buf.getvalue())


def _fmt(v: Any) -> Any:
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.6g}"
    if isinstance(v, np.integer):
        return int(v)
    return v


def read_metrics_csv(path: Path) -> list[dict[str, Any]]:
    with open(path) as f:
        rows = list(csv.DictReader(f))
    for row in rows:
        for k, v in row.items():
            try:
                row[k] = float(v) if v not in ("",) and k not in ("stage", "robot", "preset") else v
            except ValueError:
                pass
    return rows


# ----- resumable program state ---------------------------------------------------------------------
def _state_key(path) -> str:
    return jax.tree_util.keystr(path)


def save_state(path: Path, state: Any, meta: Mapping[str, Any]) -> None:
    """Every leaf of a pytree (the whole program state), keyed by its path, plus JSON ``meta``.
    Atomic: a kill at any moment leaves the previous file or the new one, never half of one."""
    arrays = {_state_key(p): np.asarray(leaf) for p, leaf in jax.tree_util.tree_leaves_with_path(state)}
    arrays["__meta__"] = np.frombuffer(
        json.dumps({"format": CHECKPOINT_FORMAT, "state_format": STATE_FORMAT, **meta}).encode(), np.uint8)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())


def load_state(path: Path, template: Any) -> tuple[Any, dict[str, Any]]:
    """Load a state saved by ``save_state`` into the structure of ``template`` (a pytree of
    arrays or ShapeDtypeStructs). Every missing, extra or differently shaped leaf is an error
    that names the leaf."""
    path = Path(path)
    flat = _read_npz(path, "resume state")
    if "__meta__" not in flat:
        raise CheckpointError(f"{path} has no '__meta__' entry: not a ptrl_jax resume state")
    meta = json.loads(bytes(flat.pop("__meta__")).decode())
    layout = meta.get("state_format", 1)  # states written before the layout was numbered are 1
    if layout != STATE_FORMAT:
        raise CheckpointError(
            f"resume state {path} has state layout {layout}, this ptrl_jax writes and reads "
            f"{STATE_FORMAT} (ptrl_jax/io/artifacts.py, STATE_FORMAT): resume it with the ptrl_jax "
            f"that wrote it; its checkpoints (source.npz, target_*.npz) load in any version")
    leaves_with_path, treedef = jax.tree_util.tree_flatten_with_path(template)
    expected = [_state_key(p) for p, _ in leaves_with_path]
    missing = [k for k in expected if k not in flat]
    extra = sorted(set(flat) - set(expected))
    if missing or extra:
        raise CheckpointError(
            f"resume state {path} does not match this experiment: "
            f"missing {missing[:3]}{'...' if len(missing) > 3 else ''} "
            f"unexpected {extra[:3]}{'...' if len(extra) > 3 else ''} (another robot or config?)"
        )
    leaves = []
    for (p, like), key in zip(leaves_with_path, expected):
        value = flat[key]
        if value.shape != tuple(like.shape) or value.dtype != like.dtype:
            raise CheckpointError(
                f"resume state {path}: {key} is {value.dtype}{list(value.shape)}, this experiment "
                f"needs {like.dtype}{list(like.shape)} (another robot, network or num_envs?)"
            )
        leaves.append(value)
    return jax.tree_util.tree_unflatten(treedef, leaves), meta


def read_state_meta(path: Path) -> dict[str, Any]:
    """Only the JSON meta of a saved state (iterations, timings), without loading the arrays."""
    try:
        with np.load(path) as z:
            return json.loads(bytes(z["__meta__"]).decode())
    except Exception as e:
        raise CheckpointError(f"resume state {path} is unreadable: {e}") from None


def new_run_dir(runs_dir: str | Path, name: str) -> Path:
    """A new folder ``<runs_dir>/<name>/<timestamp>[-k]/``, created (never an existing one)."""
    from datetime import datetime

    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    base = Path(runs_dir) / name
    run_dir = base / stamp
    k = 1
    while run_dir.exists():
        run_dir = base / f"{stamp}-{k}"
        k += 1
    run_dir.mkdir(parents=True)
    return run_dir
