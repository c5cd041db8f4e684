"""Expert checkpoints: written atomically, found again for ``--resume``, read by the PPO expert plugin.

A run folder holds ``checkpoints/last.pt`` (the newest) and ``checkpoints/model_<iterations>.pt`` (the last
``keep_checkpoints`` numbered ones). Every file is written through a temporary file and a rename
(:func:`ges_core.paths.atomic_write_bytes`): a kill while writing leaves the previous file whole and loadable.

Contents (one ``torch.save`` dict): rsl-rl's own (``actor_state_dict``, ``critic_state_dict``,
``optimizer_state_dict``, ``iter`` = iterations done, ``infos``) and ``ges``: the :data:`FORMAT` tag and version,
``made_for`` (:class:`~ges_core.policy.ExpertScope` as a dict), ``model`` (what rebuilds the actor: observation
groups and their sizes, the actor's rsl-rl config, the action size), ``action_mode``, ``residual_scale``,
``base_expert``, the run's ``train_config``, ``hand``, ``sim``, the curriculum's state, the random-number states
and running totals (``state``).
"""

from __future__ import annotations

import io
import re
from pathlib import Path

import torch

from ges_core.errors import AssetError
from ges_core.paths import atomic_write_bytes

__all__ = ["FORMAT", "VERSION", "find_checkpoints", "read_checkpoint", "write_checkpoint"]

FORMAT = "ges.ppo_expert"
VERSION = 1
_NUMBERED = re.compile(r"model_(\d+)\.pt$")


def write_checkpoint(folder: Path, data: dict, iterations: int, keep: int) -> Path:
    """Write ``data`` as ``model_<iterations>.pt`` and ``last.pt`` in ``folder`` (atomically); drop numbered
    files beyond the newest ``keep``. Returns the numbered file."""
    buf = io.BytesIO()
    torch.save(data, buf)
    raw = buf.getvalue()
    numbered = atomic_write_bytes(folder / f"model_{iterations}.pt", raw)
    atomic_write_bytes(folder / "last.pt", raw)
    for old in find_checkpoints(folder)[keep:]:
        old.unlink(missing_ok=True)
    return numbered


def find_checkpoints(folder: Path) -> list[Path]:
    """Numbered checkpoints in ``folder``, newest (most iterations) first."""
    if not folder.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in folder.iterdir() if (m := _NUMBERED.search(p.name))]
    return [p for _, p in sorted(found, reverse=True)]


def read_checkpoint(path: str | Path) -> dict:
    """The checkpoint dict at ``path``; AssetError saying what is wrong (missing, unreadable, not an expert's)."""
    path = Path(path)
    if not path.is_file():
        raise AssetError(f"no expert checkpoint at {path}; train one with 'ges train-expert' (docs/training.md)")
    try:
        data = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # torch raises many types for a truncated or foreign file
        raise AssetError(
            f"cannot read expert checkpoint {path} ({type(exc).__name__}: {exc}); it is damaged or not a torch "
            "file: use an earlier checkpoints/model_<N>.pt of the run"
        ) from exc
    meta = data.get("ges") if isinstance(data, dict) else None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise AssetError(f"{path} is not a GES PPO expert checkpoint (no '{FORMAT}' section); was it written by "
                         "'ges train-expert'?")  # fmt: skip
    if meta.get("version") != VERSION:
        raise AssetError(f"{path}: checkpoint version {meta.get('version')}, this code reads {VERSION}")
    return data


def latest_loadable(folder: Path) -> tuple[Path, dict] | None:
    """The newest checkpoint of ``folder`` that reads (``last.pt``, then numbered ones newest first); None if none.

    A damaged newest file (a kill during a write on a file system without atomic renames) falls back to the
    previous one instead of losing the run."""
    for path in [folder / "last.pt", *find_checkpoints(folder)]:
        if path.is_file():
            try:
                return path, read_checkpoint(path)
            except AssetError:
                continue
    return None
