"""The resumable results file ``<out>/baseline-<hand>-<sim>.json``: one entry per object, keyed by object id.

The file holds a header (:func:`results_header`: the expert, its defaults and every setting but the record
choice) and the per-object results; each result carries the :func:`grasp_key` of the record it ran. A run
with another header is refused (ConfigError listing the differences); a stored object whose grasp key still
matches its record is reused. Rewritten atomically after every object (a killed run loses at most one).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from ges_core.config import stored_dump
from ges_core.dataset import GraspRecord
from ges_core.dataset.layout import config_differences, utc_now
from ges_core.env.evaluate.config import BaselineConfig
from ges_core.errors import AssetError, ConfigError
from ges_core.experts.gained import with_gained_settings
from ges_core.paths import atomic_write_text

__all__ = [
    "RESULTS_FORMAT",
    "RESULTS_VERSION",
    "grasp_key",
    "read_results",
    "results_header",
    "results_path",
    "write_results",
]

RESULTS_FORMAT = "ges.baseline_results"
RESULTS_VERSION = 1


def grasp_key(record: GraspRecord) -> str:
    """16 hex digits identifying the record's grasp and pre-grasp (a changed record is evaluated again)."""
    h = hashlib.sha256()
    for pose in (record.grasp, record.pregrasp):
        if pose is not None:
            h.update(np.ascontiguousarray(pose.wrist_pose).tobytes() + np.ascontiguousarray(pose.q).tobytes())
    h.update(",".join(record.joint_names).encode())
    return h.hexdigest()[:16]


def results_path(out: str | Path, config: BaselineConfig) -> Path:
    """``<out>/baseline-<hand>-<sim>.json``."""
    return Path(out) / f"baseline-{config.hand}-{config.sim}.json"


def results_header(config: BaselineConfig, defaults: dict) -> dict:
    """What a stored result depends on: the expert, its registered settings (``defaults``: the plugin's, then
    registry.yaml's) and every setting but the record choice (``config.expert_settings`` included), as stored
    (:func:`~ges_core.config.stored_dump`: a setting added later is left out at what its absence means)."""
    settings = stored_dump(config)
    settings.pop("selection", None)
    settings.pop("splits", None)
    return {"expert": config.expert, "expert_defaults": defaults, "config": settings}


def read_results(path: Path, header: dict, registry) -> dict[str, dict]:
    """Stored per-object results of a run with ``header``; {} if there is no file yet. A setting the expert gained
    since the file was written counts at the plugin's default (:mod:`ges_core.experts.gained`)."""
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise AssetError(f"cannot read baseline results {path}: {exc}; delete the file to start over") from exc
    if not isinstance(data, dict) or data.get("format") != RESULTS_FORMAT:
        raise AssetError(f"{path} is not a baseline results file (format {RESULTS_FORMAT!r}); choose another --out")
    if data.get("version") != RESULTS_VERSION:
        raise AssetError(
            f"{path} holds baseline results of version {data.get('version')!r}, this code reads {RESULTS_VERSION}; "
            "choose another --out or delete the file to start over"
        )
    run = data.get("run")
    if isinstance(run, dict) and isinstance(run.get("expert_defaults"), dict):
        run = {**run, "expert_defaults": with_gained_settings(run["expert_defaults"], str(run.get("expert")), registry)}
    diffs = config_differences(run, header)
    if diffs:
        raise ConfigError(
            f"baseline results {path} were written with other settings ({'; '.join(diffs)}); choose another "
            "--out, rerun with those settings, or delete the file to start over",
            problems=diffs,
        )
    return dict(data.get("objects", {}))


def write_results(path: Path, header: dict, dataset: Path, objects: dict[str, dict]) -> None:
    """Write every stored object's result (``objects``: object id -> result) under ``header``, atomically."""
    data = {
        "format": RESULTS_FORMAT,
        "version": RESULTS_VERSION,
        "updated": utc_now(),
        "dataset": str(dataset),
        "run": header,
        "objects": objects,
    }
    atomic_write_text(path, json.dumps(data, indent=1) + "\n")
