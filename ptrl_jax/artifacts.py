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


def load_checkpoint(path: Path) -> dict[str, Any]:
    """Return {"params", "normalizer", "frozen": nested dicts of arrays, "meta": dict}."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} does not exist")
    try:
        with np.load(path) as z:
            flat = {k: z[k] for k in z.files}
    except Exception as e:  # zipfile / pickle / value errors of a damaged file
        raise CheckpointError(f"checkpoint {path} is unreadable (truncated or corrupted?): {e}") from None
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
