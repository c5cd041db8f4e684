"""Mimic joints as couplings, measured on mani-skill's Ability hand in SAPIEN and PyBullet.

For each engine: (1) FK of the follower links: the engine's link poses for random coupled joint values
against pytorch-kinematics, and the followers' joint values against ``multiplier * q_leader + offset``
after 2 s of PD driving toward a coupled target; (2) stability: the largest joint speed while the hand
closes halfway and holds (2 s at 1/120 s, fixed base, mani-skill's gains Kp 1e3 / Kd 1e2). SAPIEN is also
run the way it loads the raw URDF (its mimic tendons built) to show what the couplings replace.
Gravity acts on the hand (-9.81 m/s^2): the drives hold the fingers against it.

    python benchmarks/hand_mimic.py [--results NAME]   # prints a table, writes benchmarks/results/NAME.json

NAME defaults to ``hand_mimic``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from ges_core.hand_files import FileHand
from ges_core.kinematics import HandKinematics
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig

from _results import code_state, results_path, write_results

ROOT = Path(__file__).resolve().parents[1]
YAML = ROOT / "tests" / "data" / "ability_raw" / "ability_right.yaml"
STEPS = 240
"""2 s at the default 1/120 s step."""


def ability_urdf() -> Path:
    """mani-skill's right Ability hand URDF (OBJ visuals; the _glb variant differs only in visuals)."""
    from ges_core.hand_files import installed_file

    return installed_file(
        "mani_skill", "assets/robots/ability_hand/ability_hand_right.urdf", what="benchmarks/hand_mimic.py",
        distribution="mani-skill", install="pip install mani-skill",
    )  # fmt: skip


def follower_links(hand: FileHand) -> list[str]:
    """The child link of every follower joint."""
    from ges_core.lint.urdf_tree import UrdfTree

    tree = UrdfTree.from_text(hand.urdf_text())
    return [tree.joint_child[c.follower] for c in hand.description.couplings]


def measure(hand: FileHand, sim_name: str, registry, *, samples: int = 8) -> dict:
    """FK errors and stability of ``hand`` in ``sim_name``."""
    d = hand.description
    links = follower_links(hand)
    lim = d.limits_array
    q = d.apply_couplings(np.random.default_rng(0).uniform(lim[:, 0], lim[:, 1], size=(samples, d.num_joints)))
    expected = HandKinematics.from_hand(hand).link_poses(torch.as_tensor(q), links).numpy()
    config = SceneConfig(hand_gravity=True, self_collision=False)  # the PD drives hold the fingers up
    with registry.build_sim(sim_name, config) as sim:
        sim.load_hand(hand, floating=False)
        fk_err = 0.0
        for i in range(samples):
            sim.set_hand_state(q[i : i + 1])
            got = sim.link_poses(links)[0]
            fk_err = max(fk_err, float(np.abs(got[:, :3] - expected[i, :, :3, 3]).max()))
        return {"fk_position_error_m": fk_err, **hold(sim, d)}


def hold(sim, d) -> dict:
    """Hold a half-closed coupled pose for 2 s, then close onto it from the open pose for 2 s.

    Returns the largest joint speed of each phase and the followers' distance from the formula at the end."""
    target = d.closed_pose(0.5)
    start = time.perf_counter()
    sim.set_hand_state(target[None])
    sim.set_joint_targets(target[None])
    holding = _max_speed(sim)
    sim.set_hand_state(d.apply_couplings(np.asarray(d.open_pose))[None])
    sim.set_joint_targets(target[None])
    closing = _max_speed(sim)
    q = sim.joint_state()[0][0]
    formula = max(
        abs(q[d.joint_index([c.follower])[0]] - (c.ratio * q[d.joint_index([c.leader])[0]] + c.offset))
        for c in d.couplings
    )
    return {
        "max_joint_speed_rad_s": holding,
        "max_joint_speed_closing_rad_s": closing,
        "follower_formula_error_rad": float(formula),
        "target_error_rad": float(np.abs(q - target).max()),
        "seconds": time.perf_counter() - start,
    }


def _max_speed(sim) -> float:
    speed = 0.0
    for _ in range(STEPS):
        sim.step()
        speed = max(speed, float(np.abs(sim.joint_state()[1]).max()))
    return speed


def sapien_with_tendons(hand: FileHand) -> dict:
    """SAPIEN loading the URDF with its <mimic> tags (its own tendons), every joint PD-driven as usual."""
    import sapien

    from ges_core.urdf import absolutize_mesh_paths, strip_render_data

    d = hand.description
    path = Path("/tmp") / "ges_ability_with_mimic.urdf"
    path.write_text(absolutize_mesh_paths(strip_render_data(hand.urdf_text()), hand.urdf_path().parent))
    scene = sapien.Scene([sapien.physx.PhysxCpuSystem()])
    scene.set_timestep(1 / 120)
    loader = scene.create_urdf_loader()
    builder = loader.parse(str(path))[0][0]
    for link in builder.link_builders:
        link.visual_records.clear()
    art = builder.build(fix_root_link=True)  # build_mimic_joints=True: SAPIEN's default
    joints = art.get_active_joints()
    order = [d.joint_names.index(j.name) for j in joints]
    target = d.closed_pose(0.5)[order]
    art.set_qpos(target)  # hold the pose, as measure() does first
    for j, k in zip(joints, order, strict=True):
        j.set_drive_property(d.pd_stiffness[k], d.pd_damping[k])
    for j, t in zip(joints, target, strict=True):
        j.set_drive_target(float(t))
    speed, blew_up = 0.0, None
    for step in range(STEPS):
        scene.step()
        speed = max(speed, float(np.nan_to_num(np.abs(art.get_qvel()), nan=np.inf).max()))
        if blew_up is None and speed > 100.0:
            blew_up = step + 1
    return {
        "max_joint_speed_rad_s": speed,
        "first_step_over_100_rad_s": blew_up,
        "target_error_rad": float(np.nan_to_num(np.abs(art.get_qpos() - target), nan=np.inf).max()),
    }


def main() -> None:
    """Measure both engines (and SAPIEN's own tendons), print the table, write the results file."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])  # --help answers, runs nothing
    parser.add_argument("--results", default="hand_mimic", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    out = results_path(args.results)  # a bad name stops here, not after the measurements
    registry = load_registry(autoload=False)
    hand = FileHand(YAML, ability_urdf(), strict=False)
    rows = {name: measure(hand, name, registry) for name in ("sapien", "pybullet")}
    rows["sapien (mimic tendons built, before)"] = sapien_with_tendons(hand)
    print(
        f"{'engine':<38}{'FK err (m)':>12}{'follower-formula err (rad)':>28}{'hold max |qd|':>15}{'close max |qd|':>16}"
    )
    for name, r in rows.items():
        fk = f"{r['fk_position_error_m']:.2e}" if "fk_position_error_m" in r else "-"
        formula = f"{r['follower_formula_error_rad']:.2e}" if "follower_formula_error_rad" in r else "-"
        closing = f"{r['max_joint_speed_closing_rad_s']:.3g}" if "max_joint_speed_closing_rad_s" in r else "-"
        print(f"{name:<38}{fk:>12}{formula:>28}{r['max_joint_speed_rad_s']:>15.3g}{closing:>16}")
    couplings = [c.__dict__ for c in hand.description.couplings]
    write_results(out, {"code": code_state(), "hand": str(ability_urdf()), "couplings": couplings, "rows": rows})


if __name__ == "__main__":
    main()
