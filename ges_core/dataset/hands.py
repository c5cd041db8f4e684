"""What a dataset remembers of each hand: a hash of its full description, and the description field by field.

The manifest's ``hands`` maps each hand name to ``{"hash": 16 hex digits, "description": {field: value}}``. The
description is flat so that a change is named in one line (``pd_stiffness[FFJ1]: 1.0 -> 2.0``):

* every :class:`~ges_core.hand.HandDescription` field, per-joint values keyed by joint name
  (``joint_limits[J]``, ``open_pose[J]``, ``pd_stiffness[J]``, ``pd_damping[J]``, ``effort_limit[J]``;
  ``armature[J]`` only for a hand that declares armature, so a hand without keeps its hash), fingers by
  finger name (``fingers[ff].tip_offset``), couplings by follower, ``slot_fill[slot]``, each excluded link pair
  (``self_collision_exclude[a, b]``; a hand without any has no such key), the YAML's settings by
  dotted path (``settings.validate.min_squeeze``) but its ``train`` section (Stage 2 training values: they change
  no record, so setting one does not make a dataset refuse the hand);
* ``urdf``: the SHA-256 of the URDF the simulators load (converted meshes, prepared collision parts), with each
  mesh file name replaced by its content's hash (so the folder the files sit in, e.g. a cache directory, does not
  count), and ``mesh[LINK/collision/0]`` (and ``visual``) the hash of each mesh file's bytes; a missing mesh file
  hashes its name.

A resumed run compares this with the hands it builds (:meth:`ges_core.dataset.DatasetWriter`): a hand whose hash
changed is refused, the fields that differ named.
"""

from __future__ import annotations

import hashlib
import json
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

from ges_core.config import dotted_leaves
from ges_core.dataset.layout import utc_now
from ges_core.errors import ConfigError
from ges_core.hand import HandDescription, HandModel
from ges_core.hand_settings import TRAIN
from ges_core.paths import file_sha256
from ges_core.urdf import parse_urdf

__all__ = [
    "HandChangedWarning",
    "check_hands",
    "describe_hand",
    "hand_differences",
    "hand_entry",
    "urdf_fields",
    "warn_if_hand_changed",
]

MAX_NAMED = 12
"""Changed fields named in a refusal before '... and N more'."""


def hand_entry(hand: HandModel) -> dict:
    """``{"hash": ..., "description": ...}`` of ``hand`` as built now (its URDF read once)."""
    urdf_path = hand.urdf_path()
    fields = describe_hand(hand.description) | urdf_fields(urdf_path.read_text(), urdf_path.parent)
    text = json.dumps(fields, sort_keys=True, separators=(",", ":"))
    return {"hash": hashlib.sha256(text.encode()).hexdigest()[:16], "description": fields}


class HandChangedWarning(UserWarning):
    """Stage 2 is about to use a dataset's grasps with a hand other than the one Stage 1 made them with
    (:func:`warn_if_hand_changed`)."""


def warn_if_hand_changed(manifest: dict, root: Path, name: str, hand: HandModel) -> None:
    """:class:`HandChangedWarning` naming the changed fields when the dataset at ``root`` (its ``manifest``) keeps
    another description of hand ``name`` than ``hand`` as built now: its grasps were made, refined and validated
    for that one. Nothing for a dataset that keeps no description (written before datasets recorded them) or none
    of this hand. A warning, not an error: Stage 2 may run grasps on a changed hand on purpose (e.g. gains)."""
    stored = manifest.get("hands")
    stored = stored.get(name) if isinstance(stored, dict) else None
    if not isinstance(stored, dict):
        return
    entry = hand_entry(hand)
    if stored.get("hash") == entry["hash"]:
        return
    lines = hand_differences(stored.get("description", {}), entry["description"])
    shown = _named(lines)
    meshes = any(line.startswith(("mesh[", "urdf:")) for line in lines)
    fix = f"`ges hand prepare {name}` if the collision meshes are not decomposed here, " if meshes else ""
    warnings.warn(
        f"dataset {root}: its grasps of hand '{name}' were made with another description of the hand than this run "
        f"builds ({shown}); they may not fit it. Run {fix}or make the grasps again with `ges synth`",
        HandChangedWarning,
        stacklevel=2,
    )


def describe_hand(d: HandDescription) -> dict[str, object]:
    """The description's fields as a flat {name: JSON value} mapping (module docs)."""
    out: dict[str, object] = {
        "name": d.name,
        "joint_names": list(d.joint_names),
        "base_link": d.base_link,
        "middle_finger_length": d.middle_finger_length,
        "scale": d.scale,
        "fingers": [f.name for f in d.fingers],
        "wrist.link": d.wrist.link,
        "wrist.palm_normal": list(d.wrist.palm_normal),
        "wrist.finger_direction": list(d.wrist.finger_direction),
    }
    per_joint = {
        "joint_limits": [list(lim) for lim in d.joint_limits],
        "open_pose": d.open_pose,
        "pd_stiffness": d.pd_stiffness,
        "pd_damping": d.pd_damping,
        "effort_limit": d.effort_limits or [None] * d.num_joints,
    }
    for what, values in per_joint.items():
        out |= {f"{what}[{j}]": v for j, v in zip(d.joint_names, values, strict=True)}
    for f in d.fingers:
        spec = {"slot": f.slot, "joints": list(f.joints), "tip_link": f.tip_link, "tip_offset": list(f.tip_offset)}
        spec |= {"pad_normal": None if f.pad_normal is None else list(f.pad_normal)}
        out |= {f"fingers[{f.name}].{k}": v for k, v in (spec | {"keypoint_links": list(f.keypoint_links)}).items()}
    if d.armature:  # a hand without armature has no such key (its hash as before the field existed)
        out |= {f"armature[{j}]": v for j, v in zip(d.joint_names, d.armature, strict=True)}
    out |= {f"slot_fill[{slot}]": finger for slot, finger in sorted(d.slot_fill.items())}
    out |= {f"couplings[{c.follower}]": [c.leader, c.ratio, c.offset] for c in d.couplings}
    out |= {f"self_collision_exclude[{a}, {b}]": True for a, b in d.self_collision_exclude}  # none: no key
    out |= dotted_leaves({k: v for k, v in d.settings.items() if k != TRAIN}, "settings")
    return json.loads(json.dumps(out))  # tuples -> lists, as read back from the manifest


def urdf_fields(text: str, base_dir: Path) -> dict[str, str]:
    """``urdf`` (the URDF the engines load, with mesh names replaced by their content hashes) and
    ``mesh[LINK/KIND/i]`` hashes.

    "The URDF the engines load" is :func:`ges_core.hand_prep.engine_urdf.engine_urdf`'s: meshes converted, mimic
    tags removed, and a collision mesh that ``ges hand prepare`` decomposed replaced by its convex parts (so
    preparing a hand after records were made changes its hash, as it changes the hand's collision).
    """
    from ges_core.hand_prep.engine_urdf import engine_urdf
    from ges_core.hand_prep.meshes import resolve_mesh_path

    root = parse_urdf(engine_urdf(text, base_dir))
    out: dict[str, str] = {}
    for link in root.findall("link"):
        for kind in ("collision", "visual"):
            for i, element in enumerate(link.findall(kind)):
                for mesh in element.iter("mesh"):
                    digest = _file_hash(resolve_mesh_path(mesh.get("filename", ""), base_dir))
                    out[f"mesh[{link.get('name')}/{kind}/{i}]"] = digest
                    mesh.set("filename", f"sha256:{digest}")
    canonical = ET.tostring(root, encoding="unicode")
    return {"urdf": hashlib.sha256(canonical.encode()).hexdigest()[:16]} | out


def _file_hash(path: Path) -> str:
    """16 hex digits of the file's SHA-256, or of ``missing:<name>`` when it cannot be read."""
    try:
        return file_sha256(path)
    except OSError:
        return hashlib.sha256(f"missing:{path.name}".encode()).hexdigest()[:16]


def hand_differences(old: dict, new: dict) -> list[str]:
    """``field: old -> new`` for every field of two stored descriptions that differs (sorted by field)."""
    keys = sorted(set(old) | set(new))
    return [
        f"{k}: {_show(old.get(k, '<absent>'))} -> {_show(new.get(k, '<absent>'))}"
        for k in keys
        if old.get(k, "<absent>") != new.get(k, "<absent>")
    ]


def _show(value: object) -> str:
    return value if isinstance(value, str) else json.dumps(value)


def check_hands(
    root: Path, manifest: dict, hands: dict | None, recorded: list[str], allow_change: bool
) -> tuple[dict, list[str]]:
    """The manifest with this run's ``hands`` entries put in, and notes for the writer's ``recovered``.

    recorded: the hand of every record in the folder. ConfigError when a hand with records there has another hash
    than stored, naming the hand and each changed field, unless ``allow_change`` (its old entry then goes to
    ``hands_history``). See :class:`~ges_core.dataset.DatasetWriter`.
    """
    if hands is None:
        return manifest, []
    stored = manifest.get("hands")
    if not isinstance(stored, dict):
        notes = []
        if recorded:
            names = ", ".join(sorted(set(recorded)))
            notes.append(
                f"the manifest keeps no hand descriptions (written before datasets recorded them): the hands of its "
                f"{len(recorded)} record(s) ({names}) cannot be checked; this run's hands are recorded from now on"
            )
        return dict(manifest, hands=hands), notes
    changed = {
        name: hand_differences(stored[name].get("description", {}), entry["description"])
        for name, entry in hands.items()
        if name in recorded and isinstance(stored.get(name), dict) and stored[name].get("hash") != entry["hash"]
    }
    if changed and not allow_change:
        raise ConfigError(_refusal(root, changed, recorded, stored, hands), problems=[*_problems(changed)])
    history = [{"until": utc_now(), "hands": {name: stored[name]}} for name in changed]
    out = dict(manifest, hands={**stored, **hands})
    if history:
        out["hands_history"] = [*manifest.get("hands_history", []), *history]
    return out, []


def _named(lines: list[str]) -> str:
    """The first :data:`MAX_NAMED` changed fields, joined, and how many more there are."""
    more = f"; ... and {len(lines) - MAX_NAMED} more" if len(lines) > MAX_NAMED else ""
    return "; ".join(lines[:MAX_NAMED]) + more


def _problems(changed: dict[str, list[str]]) -> list[str]:
    return [f"{name}: {line}" for name, lines in changed.items() for line in lines]


def _refusal(root: Path, changed: dict[str, list[str]], recorded: list[str], stored: dict, hands: dict) -> str:
    parts = []
    for name, lines in changed.items():
        shown = _named(lines)
        hashes = f"{stored[name].get('hash')} -> {hands[name]['hash']}"
        parts.append(f"hand '{name}' ({recorded.count(name)} record(s), description {hashes}): {shown or 'unnamed'}")
    return (
        f"dataset {root} was written with other hand descriptions than this run builds: {' | '.join(parts)}. "
        "Resuming would mix grasps of two different hands in one dataset. Restore the hand as it was (its YAML, or "
        "a setting of its plugin: ges --set settings.hand.NAME.KEY=VALUE ...), or start over (ges demo --fresh moves "
        "the folder aside) or write to a new folder (ges synth / ges retarget: --out DIR); "
        "in Python, DatasetWriter(..., allow_config_change=True) continues it and keeps the old description in the "
        "manifest's hands_history"
    )
