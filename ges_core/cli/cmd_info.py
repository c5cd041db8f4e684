"""``ges info hand NAME``: the resolved description of a hand (joints, limits, gains, fingers)."""

from __future__ import annotations

import argparse

from ges_core.contact import FINGER_SLOTS
from ges_core.hand import HandDescription


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges info``."""
    p = sub.add_parser("info", help="show one plugin in detail")
    p.add_argument("kind", choices=["hand", "sim", "expert"], help="what to show")
    p.add_argument("name", help="registry name")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print the plugin's details."""
    from ges_core.cli import registry_from_args

    registry = registry_from_args(args)
    spec = registry.spec(args.kind, args.name)
    print(f"{spec.kind} '{spec.name}': {spec.description}\n  source: {spec.source}\n  entry point: {spec.entry_point}")
    if spec.requires:
        missing = spec.missing()
        state = f"missing {', '.join(missing)}: {spec.install}" if missing else "installed"
        print(f"  requires: {', '.join(spec.requires)} ({state})")
    settings = registry.checked_settings(args.kind, spec.name)  # a bad --set value is an error here too
    print(f"  settings: {', '.join(f'{k}={v!r}' for k, v in settings.items()) or '(none)'}")
    if args.kind == "hand":
        hand = registry.build_hand(args.name)
        print(f"  urdf: {hand.urdf_path()}")
        print(format_hand(hand.description))
    return 0


def format_hand(d: HandDescription) -> str:
    """A human-readable table of a hand description."""
    lines = [
        f"  base link: {d.base_link}   wrist link: {d.wrist.link}",
        f"  palm normal (wrist frame): {d.wrist.palm_normal}   finger direction: {d.wrist.finger_direction}",
        f"  middle-finger length l_p: {d.middle_finger_length:.4f} m   scale alpha: {d.scale:.3f}",
        "  finger slots:",
    ]
    for slot in FINGER_SLOTS:
        finger = d.finger_for_slot(slot)
        via = "" if finger.slot == slot else f"  (filled by rule: {slot} -> {finger.name})"
        lines.append(f"    {slot:<7} {finger.name:<8} tip {finger.tip_link}{via}")
    width = max(14, *(len(name) + 1 for name in d.joint_names))  # long names (the Inspire's) keep the columns
    head = f"{'lower':>9}{'upper':>9}{'open':>9}{'kp':>10}{'kd':>9}{'effort':>9}{'armature':>10}"
    lines.append(f"  {'joint':<{width}}{head}")
    effort = d.effort_limits or (None,) * d.num_joints  # -: no cap declared
    rows = zip(d.joint_names, d.joint_limits, d.open_pose, d.pd_stiffness, d.pd_damping, effort, strict=True)
    for (name, (lo, hi), q0, kp, kd, cap), arm in zip(rows, d.armature_array, strict=True):
        cap_text = "-" if cap is None else f"{cap:.3g}"
        lines.append(f"  {name:<{width}}{lo:>9.3f}{hi:>9.3f}{q0:>9.3f}{kp:>10.3g}{kd:>9.3g}{cap_text:>9}{arm:>10.3g}")
    lines.append("  units: rad, N·m/rad, N·m·s/rad, N·m (effort: the actuator's torque cap), kg·m² (armature)")
    lines.extend(f"  coupling: {c.follower} = {c.ratio:g} x {c.leader} + {c.offset:g} rad" for c in d.couplings)
    lines.extend(f"  self-collision left out: {a} / {b}" for a, b in d.self_collision_exclude)
    lines.append(f"  settings (over the run config's, docs/hands/format.md): {d.settings or 'none'}")
    return "\n".join(lines)
