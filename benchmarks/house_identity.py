"""Bit-identity check of a refactor: Stage 1 records, grasp pictures and the scripted baseline, before vs after.

``--write DIR`` runs a fixed scenario through the CLI into DIR (one thread):

1. ``ges demo`` on the first 12 demo objects, both hands, refinement in SAPIEN, validation in SAPIEN and
   PyBullet, pictures on;
2. ``ges synth`` on 8 demo objects (10..17), both hands, refinement and validation in PyBullet;
3. ``ges env baseline`` (scripted expert, ``--select refined``) on the demo dataset for both hands in both
   simulators, and once more for Allegro in PyBullet with 3 envs per object.

``--compare BEFORE AFTER`` reads both folders with the *current* code (so a dataset written by an older
record version goes through the reader of old versions) and compares everything but wall-clock times,
software versions and absolute picture paths: every array bit for bit, every verdict, flag and figure, every
picture byte for byte, every baseline episode. It prints one line per difference and a summary, writes
``benchmarks/results/NAME.json`` (``--results NAME``, default ``house_identity``) and exits 1 on any difference.

    python benchmarks/house_identity.py --write /tmp/after
    python benchmarks/house_identity.py --compare /tmp/before /tmp/after [--results NAME]
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ges_core.synthesis.run.demo import DEMO_OBJECTS

from _results import code_state, results_path, write_results

TIMING_KEYS = {"seconds", "setup_seconds", "time", "updated", "created", "versions", "picture"}
"""Keys left out of the comparison: wall-clock times, software versions, absolute picture paths."""
PROVENANCE_KEYS = {"run_config_hash"}
"""Also left out: the hash of the run config a record was made with, which version-1 records (the "before" of a
comparison across that change) do not carry; the configs themselves are the same by construction."""
SYNTH_OBJECTS = DEMO_OBJECTS[10:18]
"""Demo objects 10..17, refined and validated in PyBullet."""
BASELINES = [
    ("allegro", "sapien", 1),
    ("allegro", "pybullet", 1),
    ("shadow", "sapien", 1),
    ("shadow", "pybullet", 1),
    ("allegro", "pybullet", 3),
]


def write(out: Path) -> None:
    """Run the fixed scenario into ``out`` through the installed ``ges`` command."""
    env = dict(os.environ, OMP_NUM_THREADS="1")
    ges = [sys.executable, "-m", "ges_core.cli"]
    steps = [
        [*ges, "demo", "--no-progress", "-o", "objects=12", "-o", f"out={out / 'demo'}"]
        + ["-o", "synthesis.validate_sims=[sapien,pybullet]"],
        [*ges, "synth", "--hands", "allegro", "shadow", "--objects", *SYNTH_OBJECTS, "--sim", "pybullet"]
        + ["--no-progress", "--out", str(out / "synth_pb")],
    ]
    for hand, sim, envs in BASELINES:
        folder = out / ("baseline" if envs == 1 else f"baseline_e{envs}")
        steps.append(
            [*ges, "env", "baseline", str(out / "demo" / "dataset"), "--hand", hand, "--sim", sim]
            + ["--envs", str(envs), "--select", "refined", "--out", str(folder), "--no-progress"]
        )
    for cmd in steps:
        print("$", " ".join(cmd[2:]), flush=True)
        subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)


def canonical(value: Any) -> Any:
    """``value`` as plain JSON data: arrays by dtype, shape and SHA-256 of their bytes; timing keys dropped."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        value = {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {
            str(k): canonical(v)
            for k, v in sorted(value.items(), key=lambda kv: str(kv[0]))
            if k not in TIMING_KEYS | PROVENANCE_KEYS
        }
    if isinstance(value, np.ndarray):
        data = np.ascontiguousarray(value)
        return {
            "dtype": str(data.dtype),
            "shape": list(data.shape),
            "sha256": hashlib.sha256(data.tobytes()).hexdigest(),
        }
    if isinstance(value, list | tuple):
        return [canonical(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def dataset_view(folder: Path) -> dict[str, Any]:
    from ges_core.dataset import open_dataset

    return {f"{r.object_id}|{r.hand}": canonical(r) for r in open_dataset(folder)}


def pictures_view(folder: Path) -> dict[str, str]:
    return {
        p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*.png"))
    }


def baseline_view(path: Path) -> dict[str, Any]:
    data = json.loads(path.read_text())
    return {oid: canonical(entry) for oid, entry in data["objects"].items()}


def differences(a: Any, b: Any, where: str = "") -> list[str]:
    """Paths at which ``a`` and ``b`` differ (one line each)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = [f"{where}.{k}: only in {'before' if k in a else 'after'}" for k in sorted(set(a) ^ set(b))]
        for k in sorted(set(a) & set(b)):
            out += differences(a[k], b[k], f"{where}.{k}")
        return out
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True)) for d in differences(x, y, f"{where}[{i}]")]
    return [] if a == b else [f"{where}: {json.dumps(a, default=str)[:120]} != {json.dumps(b, default=str)[:120]}"]


def compare(before: Path, after: Path, results: Path) -> int:
    parts: dict[str, tuple[Any, Any]] = {}
    for name in ("demo/dataset", "synth_pb"):
        parts[name] = (dataset_view(before / name), dataset_view(after / name))
    parts["demo/pictures"] = (pictures_view(before / "demo" / "pictures"), pictures_view(after / "demo" / "pictures"))
    for path in sorted(before.glob("baseline*/*.json")):
        rel = path.relative_to(before)
        parts[rel.as_posix()] = (baseline_view(path), baseline_view(after / rel))
    summary, lines = {}, []
    for name, (a, b) in parts.items():
        diffs = differences(a, b, name)
        summary[name] = {"items": len(a), "differences": len(diffs)}
        lines += diffs
        print(f"{name:40s} {len(a):4d} items  {'identical' if not diffs else f'{len(diffs)} differences'}")
    for line in lines[:50]:
        print("  ", line)
    made_by = before / "COMMIT"  # the commit that wrote BEFORE, if whoever ran it noted it there
    before_commit = made_by.read_text().strip() if made_by.is_file() else None
    data = {"before": str(before), "before_commit": before_commit, "after": str(after), "parts": summary}
    write_results(results, {**data, "code": code_state()})
    print(f"{'IDENTICAL' if not lines else 'DIFFERENT'}; written to {results}")
    return 1 if lines else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--write", type=Path, metavar="DIR")
    group.add_argument("--compare", type=Path, nargs=2, metavar=("BEFORE", "AFTER"))
    parser.add_argument("--results", default="house_identity", help="--compare: benchmarks/results/NAME.json")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the comparison
    if args.write:
        write(args.write)
        return 0
    return compare(*args.compare, results)


if __name__ == "__main__":
    raise SystemExit(main())
