"""The viewer's side of a dataset: which records there are, and each one's object mesh, hand and scene.

Objects come from the object library the dataset was written with (its manifest's ``run_config.library``), hands
from the registry; both are built on first use and kept. A record whose object or hand cannot be built is still
shown (contacts, figures) with a note saying what is missing and why.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ges_core.errors import AssetError, GesError

if TYPE_CHECKING:
    from ges_core.dataset.record import GraspRecord
    from ges_core.objects.library import ObjectLibrary
    from ges_core.registry import Registry
    from ges_core.viewer.geometry import HandView
    from ges_core.viewer.scene import Scene, ViewerConfig

__all__ = ["ViewerData"]

ALL = "all"
"""The split choice that shows every split."""


class ViewerData:
    """A dataset opened for viewing (the folder is only read).

    path: the dataset folder. AssetError when it is not a dataset (no or a foreign ``manifest.json``) or holds no
    record. registry: where the hands are built (default: :func:`ges_core.registry.load_registry`, on first use).
    """

    def __init__(self, path: str | Path, registry: Callable[[], Registry] | None = None) -> None:
        from ges_core.dataset import open_dataset

        self.root = Path(path)
        if not self.root.is_dir():
            raise AssetError(
                f"ges view: {self.root} is not a folder; give a dataset folder (one holding manifest.json)"
            )
        self.dataset = open_dataset(self.root)
        if not len(self.dataset):
            raise AssetError(
                f"ges view: dataset {self.root} holds no grasp records (nothing to show); run 'ges demo' or "
                f"'ges synth' into it first, or check it with 'ges dataset info {self.root}'"
            )
        self._registry_factory = registry
        self._lock = threading.Lock()  # GUI callbacks run on viser's threads
        self._records: dict[tuple[str, str], GraspRecord] = {}
        self._objects: dict[str, tuple[tuple[np.ndarray, np.ndarray] | None, str]] = {}
        self._hands: dict[str, tuple[HandView | None, str]] = {}
        self._library: ObjectLibrary | None = None

    def __len__(self) -> int:
        return len(self.dataset)

    # -- what there is --------------------------------------------------------------------
    def splits(self) -> list[str]:
        """The splits present, sorted."""
        return sorted({e["split"] for e in self.dataset.entries})

    def objects(self, split: str = ALL, hand: str = ALL) -> list[str]:
        """Object ids with a record in ``split`` (``all``: any) of ``hand`` (``all``: any), sorted."""
        return sorted(
            {e["object_id"] for e in self.dataset.entries if split in (ALL, e["split"]) and hand in (ALL, e["hand"])}
        )

    def hands(self, object_id: str | None = None) -> list[str]:
        """Hands with a record of ``object_id`` (None: of any object), sorted."""
        return sorted({e["hand"] for e in self.dataset.entries if object_id in (None, e["object_id"])})

    def entry(self, object_id: str, hand: str) -> dict:
        """The index entry of (object, hand); KeyError naming both if the dataset has none."""
        for e in self.dataset.entries:
            if (e["object_id"], e["hand"]) == (object_id, hand):
                return e
        raise KeyError(f"dataset {self.root} holds no record of object '{object_id}' with hand '{hand}'")

    def contacts_gap(self, object_id: str, hand: str, other: str) -> float | None:
        """Largest distance (m) between the contacts of two hands' records of one object; None if one has none."""
        a, b = self.record(object_id, hand).contacts, self.record(object_id, other).contacts
        if a is None or b is None:
            return None
        return float(np.linalg.norm(a.positions - b.positions, axis=1).max())

    # -- what one record needs ------------------------------------------------------------
    def record(self, object_id: str, hand: str) -> GraspRecord:
        """The record of (object, hand), read once."""
        key = (object_id, hand)
        if key not in self._records:
            self._records[key] = self.dataset.get(object_id, hand)
        return self._records[key]

    def scene(self, object_id: str, hand: str, config: ViewerConfig | None = None) -> Scene:
        """The :class:`~ges_core.viewer.scene.Scene` of (object, hand), notes saying what could not be drawn."""
        from ges_core.viewer.scene import build_scene

        with self._lock:
            record = self.record(object_id, hand)
            mesh, object_note = self.object_mesh(object_id)
            view, hand_note = self.hand_view(hand)
        notes = tuple(n for n in (object_note, hand_note) if n)
        try:
            return build_scene(record, object_mesh=mesh, hand=view, config=config, notes=notes)
        except AssetError as exc:  # the record's joints are not the hand's: draw it without the hand
            return build_scene(record, object_mesh=mesh, hand=None, config=config, notes=(*notes, str(exc)))

    def object_mesh(self, object_id: str) -> tuple[tuple[np.ndarray, np.ndarray] | None, str]:
        """((vertices (V, 3), faces (F, 3)) of the object's surface mesh, object frame m, or None; a note why not)."""
        if object_id not in self._objects:
            self._objects[object_id] = self._load_object(object_id)
        return self._objects[object_id]

    def hand_view(self, hand: str) -> tuple[HandView | None, str]:
        """(the hand's :class:`~ges_core.viewer.geometry.HandView` or None, a note why not)."""
        if hand not in self._hands:
            self._hands[hand] = self._load_hand(hand)
        return self._hands[hand]

    def _load_object(self, object_id: str) -> tuple[tuple[np.ndarray, np.ndarray] | None, str]:
        import trimesh

        try:
            asset = self.library().get(object_id)
            mesh = trimesh.load(str(asset.mesh_path), force="mesh")
        except (GesError, KeyError, OSError, ValueError) as exc:
            return None, f"object mesh not drawn: {exc}"
        return (np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int32)), ""

    def _load_hand(self, hand: str) -> tuple[HandView | None, str]:
        from ges_core.viewer.geometry import HandView

        try:
            registry = self._registry_factory() if self._registry_factory else _default_registry()
            return HandView(registry.build_hand(hand)), ""
        except (GesError, KeyError, OSError) as exc:
            return None, f"hand '{hand}' not drawn: {exc}"

    def library(self) -> ObjectLibrary:
        """The object library of the dataset's run config (its ``library`` section; the defaults without one)."""
        if self._library is None:
            from ges_core.config import parse_model
            from ges_core.objects.library import LibraryConfig

            section = self.dataset.run_config.get("library")
            settings = section if isinstance(section, dict) else {}
            self._library = parse_model(LibraryConfig, settings, where=f"{self.root} run_config.library").build()
        return self._library


def _default_registry() -> Registry:
    from ges_core.registry import load_registry

    return load_registry()
