"""summary.json: the one machine-readable result of a run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .atomic import atomic_path

__all__ = ["write_summary", "to_jsonable"]


def to_jsonable(obj):
    """Convert numpy scalars/arrays and paths inside ``obj`` to plain JSON types."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, float) and not np.isfinite(obj):
        raise ValueError(f"summary: non-finite value {obj}")
    return obj


def write_summary(out_dir, summary: dict) -> Path:
    """Write ``summary`` (a dict; numpy values converted) as ``out_dir``/summary.json, atomically; returns its path."""
    path = Path(out_dir) / "summary.json"
    with atomic_path(path, ".json") as tmp:
        tmp.write_text(json.dumps(to_jsonable(summary), indent=2) + "\n")
    return path
