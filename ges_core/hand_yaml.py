"""Read a :class:`~ges_core.hand.HandDescription` from YAML text plus the hand's URDF text.

Joint limits always come from the URDF (one source of truth). Per-joint values (open pose,
PD gains) are mappings whose keys are full-match regular expressions over joint names plus an
optional ``default``; they are expanded once here, and a pattern that matches no joint is an
error. ``ges info hand NAME`` prints the resolved table.

The format, field by field with units and frames and the built-in hands as examples:
``docs/hands/format.md``. Abridged from ``plugins/hands/allegro/allegro.yaml``::

    name: allegro
    fingers:
      - {name: index, slot: index, joints: [joint_0.0, joint_1.0, joint_2.0, joint_3.0], tip_link: link_3.0_tip,
         tip_offset: [0.012, 0.0, 0.0], pad_normal: [1.0, 0.0, 0.0],
         keypoint_links: [link_1.0, link_2.0, link_3.0, link_3.0_tip]}
      # middle, ring, thumb alike
    slot_fill: {little: ring}
    wrist: {link: base_link, palm_normal: [1.0, 0.0, 0.0], finger_direction: [0.0, 0.0, 1.0]}
    middle_finger_length: 0.1311
    scale: 1.311
    open_pose: {default: 0.0, "joint_12\\\\.0": 0.263}
    pd_stiffness: {default: 400.0}
    pd_damping: {default: 10.0}
    effort_limit: {default: 0.5}     # optional: the real actuators' torque limits, N·m
    armature: {default: 0.0}         # optional: the actuators' reflected inertia, kg·m² (0: none)
    couplings: []                    # optional: {follower, leader, ratio, offset}
    self_collision_exclude: []       # optional: [[link_a, link_b], ...] pairs that never collide
    settings: {}                     # optional: the hand's own Stage 1 settings (ges_core.hand_settings)
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from collections.abc import Callable
from typing import Any

import yaml
from pydantic import Field, ValidationError, field_validator

from ges_core.config import ConfigModel
from ges_core.contact import FINGER_SLOTS
from ges_core.errors import AssetError, ConfigError
from ges_core.hand import FingerSpec, HandDescription, JointCoupling, WristConvention
from ges_core.urdf import parse_urdf, root_link, solid_links

__all__ = ["description_from_yaml", "expand_per_joint", "urdf_joint_limits"]

PerJoint = float | dict[str, float] | list[float]


class _Finger(ConfigModel):
    name: str
    slot: str
    joints: list[str]
    tip_link: str
    tip_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    pad_normal: tuple[float, float, float] | None = None
    keypoint_links: list[str] = Field(default_factory=list)

    @field_validator("pad_normal")
    @classmethod
    def _unit_pad_normal(cls, v: tuple[float, float, float] | None) -> tuple[float, float, float] | None:
        if v is None:
            return None
        norm = sum(x * x for x in v) ** 0.5
        if not norm > 1e-6 or norm != norm:
            raise ValueError(f"must be a non-zero direction in the tip link's frame, got {list(v)}")
        return (v[0] / norm, v[1] / norm, v[2] / norm)


class _Wrist(ConfigModel):
    link: str
    palm_normal: tuple[float, float, float]
    finger_direction: tuple[float, float, float]


class _Coupling(ConfigModel):
    follower: str
    leader: str
    ratio: float = 1.0
    offset: float = 0.0


class _HandFile(ConfigModel):
    name: str
    joint_names: list[str] | None = None
    fingers: list[_Finger]
    slot_fill: dict[str, str] = Field(default_factory=dict)
    wrist: _Wrist
    middle_finger_length: float = Field(gt=0)
    scale: float = Field(gt=0)
    open_pose: PerJoint = 0.0
    pd_stiffness: PerJoint
    pd_damping: PerJoint
    effort_limit: PerJoint | None = None
    armature: PerJoint | None = None
    couplings: list[_Coupling] = Field(default_factory=list)
    self_collision_exclude: list[tuple[str, str]] = Field(default_factory=list)
    settings: dict[str, Any] = Field(default_factory=dict)


def urdf_joint_limits(urdf_text: str) -> dict[str, tuple[float, float] | None]:
    """Movable joints in URDF file order -> (lower, upper), or None when the joint has no limit."""
    out: dict[str, tuple[float, float] | None] = {}
    for joint in parse_urdf(urdf_text).findall("joint"):
        if joint.get("type") in ("fixed", None):
            continue
        limit = joint.find("limit")
        out[joint.get("name")] = _limit_pair(limit, joint.get("type"))
    return out


def _limit_pair(limit: ET.Element | None, kind: str | None) -> tuple[float, float] | None:
    if kind == "continuous" or limit is None or limit.get("lower") is None or limit.get("upper") is None:
        return None
    return float(limit.get("lower")), float(limit.get("upper"))


def expand_per_joint(value: PerJoint, joint_names: list[str], what: str) -> tuple[float, ...]:
    """Expand a scalar, a list, or a {regex|default: value} mapping to one value per joint."""
    if isinstance(value, int | float):
        return tuple(float(value) for _ in joint_names)
    if isinstance(value, list):
        if len(value) != len(joint_names):
            raise AssetError(f"{what}: list has {len(value)} values for {len(joint_names)} joints")
        return tuple(float(v) for v in value)
    resolved: dict[str, float] = {}
    for pattern, v in value.items():
        if pattern == "default":
            continue
        hits = [n for n in joint_names if re.fullmatch(pattern, n)]
        if not hits:
            raise AssetError(f"{what}: pattern '{pattern}' matches no joint (joints: {', '.join(joint_names)})")
        resolved.update({n: float(v) for n in hits if n not in resolved})
    missing = [n for n in joint_names if n not in resolved]
    if missing and "default" not in value:
        raise AssetError(f"{what}: no value for {', '.join(missing)}; add them or a 'default'")
    return tuple(resolved.get(n, float(value.get("default", 0.0))) for n in joint_names)


def _check_joint_names(hand: str, names: list[str], urdf_joints: list[str]) -> None:
    """joint_names must list every movable URDF joint exactly once."""
    repeated = sorted({n for n in names if names.count(n) > 1})
    unknown = [n for n in names if n not in urdf_joints]
    missing = [n for n in urdf_joints if n not in names]
    problems = [
        f"{what} {items}"
        for what, items in (("repeated", repeated), ("not in the URDF", unknown), ("missing", missing))
        if items
    ]
    if problems:
        raise AssetError(f"hand '{hand}': joint_names must list every movable URDF joint once: " + "; ".join(problems))


def _check_references(data: _HandFile, names: list[str]) -> None:
    """Fingers, slot_fill and couplings may only name joints, fingers and slots that exist."""
    fingers = [f.name for f in data.fingers]
    problems = [f"finger '{f.name}' has unknown slot '{f.slot}'" for f in data.fingers if f.slot not in FINGER_SLOTS]
    problems += [
        f"finger '{f.name}' names unknown joint '{j}'" for f in data.fingers for j in f.joints if j not in names
    ]
    problems += [f"slot_fill: unknown slot '{s}'" for s in data.slot_fill if s not in FINGER_SLOTS]
    problems += [f"slot_fill: '{s}' -> unknown finger '{f}'" for s, f in data.slot_fill.items() if f not in fingers]
    problems += [
        f"coupling names unknown joint '{j}'" for c in data.couplings for j in (c.follower, c.leader) if j not in names
    ]
    if problems:
        raise AssetError(
            f"hand '{data.name}': " + "; ".join(problems) + f" (known fingers {fingers}, slots {list(FINGER_SLOTS)})"
        )


def _check_exclusions(data: _HandFile, urdf_text: str) -> None:
    """self_collision_exclude may only pair two different links of the URDF that both have collision geometry."""
    root = parse_urdf(urdf_text)
    links = [link.get("name") for link in root.iter("link")]
    solid = set(solid_links(root))
    problems = []
    for a, b in data.self_collision_exclude:
        unknown = [n for n in (a, b) if n not in links]
        if unknown:
            problems.append(f"[{a}, {b}] names unknown link(s) {unknown}")
        elif a == b:
            problems.append(f"[{a}, {b}] pairs a link with itself")
        elif not {a, b} <= solid:
            problems.append(f"[{a}, {b}]: {sorted({a, b} - solid)} has no collision geometry (nothing to exclude)")
    if problems:
        raise AssetError(
            f"hand '{data.name}': self_collision_exclude " + "; ".join(problems) + f" (links with collision geometry: "
            f"{sorted(solid)})"
        )


def _effort_limits(data: _HandFile, names: list[str]) -> tuple[float, ...]:
    """(K,) ``effort_limit`` per joint, N·m (N), or () when the file gives none; AssetError unless each is > 0."""
    return _actuator_values(
        data, names, "effort_limit", lambda v: 0 < v < float("inf"), "a finite torque > 0 N·m",
        "give the actuator's data-sheet value or leave effort_limit out",
    )  # fmt: skip


def _armature(data: _HandFile, names: list[str]) -> tuple[float, ...]:
    """(K,) ``armature`` per joint, kg·m² (kg), or () when the file gives none; AssetError unless each is finite and
    >= 0."""
    return _actuator_values(
        data, names, "armature", lambda v: 0 <= v < float("inf"), "a finite inertia >= 0 kg·m²",
        "give the actuator's reflected inertia (the asset's value) or leave armature out",
    )  # fmt: skip


def _actuator_values(
    data: _HandFile, names: list[str], key: str, ok: Callable[[float], bool], rule: str, fix: str
) -> tuple[float, ...]:
    """The optional per-joint actuator table ``key`` expanded to (K,), or () when the file gives none; one AssetError
    naming every joint whose value breaks ``rule``."""
    value = getattr(data, key)
    if value is None:
        return ()
    values = expand_per_joint(value, names, f"{data.name}.{key}")
    bad = [f"{n}={v}" for n, v in zip(names, values, strict=True) if not ok(v)]
    if bad:
        raise AssetError(f"hand '{data.name}': {key} must be {rule} per joint, got {', '.join(bad)}; {fix}")
    return values


def description_from_yaml(
    yaml_text: str, urdf_text: str, *, strict: bool = True, source: str | None = None, **overrides: Any
) -> HandDescription:
    """Build a HandDescription; ``overrides`` replace top-level YAML keys (registry settings), except ``settings``,
    which merges into the YAML's key by key (:func:`ges_core.hand_settings.merge_settings`): ``ges --set
    settings.hand.NAME.settings.validate.max_squeeze=1.0`` changes that one key and keeps the hand's others.

    strict: reject joints without limits (the hand linter passes False to report every problem).
    source: the YAML file's name, for messages (e.g. ``"shadow.yaml"``).
    """
    try:
        raw = yaml.safe_load(yaml_text) or {}
    except yaml.YAMLError as exc:
        raise AssetError(f"hand description is not valid YAML: {exc}") from exc
    if not isinstance(raw, dict):
        raise AssetError("hand description must be a YAML mapping")
    if isinstance(overrides.get("settings"), dict) and isinstance(raw.get("settings"), dict):
        from ges_core.hand_settings import merge_settings

        overrides = {**overrides, "settings": merge_settings(raw["settings"], overrides["settings"])}
    raw.update(overrides)
    try:
        data = _HandFile.model_validate(raw)
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in exc.errors())
        where = f" (in {source})" if source else ""
        raise AssetError(f"invalid description of hand '{raw.get('name', '?')}': {problems}{where}") from None
    limits = urdf_joint_limits(urdf_text)
    names = data.joint_names or list(limits)
    _check_joint_names(data.name, names, list(limits))
    if strict:
        _check_references(data, names)
        _check_exclusions(data, urdf_text)
    unlimited = [n for n in names if limits[n] is None]
    joint_limits = tuple(limits[n] or (0.0, 0.0) for n in names)
    fingers = tuple(
        FingerSpec(**{**f.model_dump(), "joints": tuple(f.joints), "keypoint_links": tuple(f.keypoint_links)})
        for f in data.fingers
    )
    if unlimited and strict:
        raise AssetError(f"hand '{data.name}': joints {unlimited} have no limits in the URDF; give each a <limit>")
    return HandDescription(
        name=data.name,
        joint_names=tuple(names),
        joint_limits=joint_limits,
        fingers=fingers,
        wrist=WristConvention(**data.wrist.model_dump()),
        middle_finger_length=data.middle_finger_length,
        scale=data.scale,
        open_pose=expand_per_joint(data.open_pose, names, f"{data.name}.open_pose"),
        pd_stiffness=expand_per_joint(data.pd_stiffness, names, f"{data.name}.pd_stiffness"),
        pd_damping=expand_per_joint(data.pd_damping, names, f"{data.name}.pd_damping"),
        effort_limits=_effort_limits(data, names),
        armature=_armature(data, names),
        slot_fill=dict(data.slot_fill),
        couplings=tuple(JointCoupling(**c.model_dump()) for c in data.couplings),
        self_collision_exclude=tuple(tuple(sorted(pair)) for pair in data.self_collision_exclude),
        base_link=root_link(urdf_text),
        settings=_settings(data, source),
    )


def _settings(data: _HandFile, source: str | None) -> dict[str, Any]:
    """The YAML's ``settings:`` checked against the run config's models; AssetError naming the file and path."""
    if not data.settings:
        return {}
    from ges_core.hand_settings import check_settings

    try:
        return check_settings(data.settings, "settings")
    except ConfigError as exc:
        where = f" ({source})" if source else ""
        raise AssetError(f"hand '{data.name}'{where}: {exc}") from None
