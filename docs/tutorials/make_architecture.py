"""Draw docs/tutorials/architecture.png, the one picture of docs/tutorials/architecture.md.

    python docs/tutorials/make_architecture.py [OUT.png]

The picture is data: :data:`BOXES` (what each box says and which modules of the repository it stands for) and
:data:`ARROWS` (what flows where). ``tests/test_tutorial_architecture.py`` checks that every module a box names
exists and that the committed PNG is what this script draws. Edit the data, run the script, commit both.
Only matplotlib (a dependency of pytorch-kinematics, so always installed) is needed.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

__all__ = ["ARROWS", "BOXES", "DRAWN_WITH", "Box", "draw"]

OUT = Path(__file__).with_name("architecture.png")
"""Default output: beside this script."""
DRAWN_WITH = "3.11.2"
"""matplotlib version that drew the committed PNG: with it, a rerun gives the same bytes (the test checks that);
another version may place text a pixel apart (the test then checks the size only)."""


@dataclass(frozen=True)
class Box:
    """One box: position and size in figure units (16 x 10, origin bottom left), a title, text lines, the
    repository paths it stands for (checked by the test), and a fill colour."""

    key: str
    x: float
    y: float
    w: float
    h: float
    title: str
    lines: tuple[str, ...]
    modules: tuple[str, ...]
    colour: str


CORE, PLUGIN, STAGE1, DATA, STAGE2, CLI = "#dbe7f5", "#fde9c9", "#d9f0d9", "#eeeeee", "#f3dcef", "#ffffff"

BOXES: tuple[Box, ...] = (
    Box("cli", 0.3, 9.05, 15.4, 0.7, "ges (command line)", (
        "list · info · hand lint/prepare · objects list/prepare · sim check · synth · demo · retarget · dataset "
        "info/validate · env baseline",
    ), ("ges_core/cli",), CLI),
    Box("hooks", 0.3, 6.85, 3.6, 1.75, "hook specs", (
        "ges_register_hands", "ges_register_sims", "ges_register_experts", "ges_register_gates",
    ), ("ges_core/hookspecs.py", "ges_core/specs.py"), CORE),
    Box("discovery", 4.2, 6.85, 3.8, 1.75, "plugin manager (pluggy)", (
        "1. built-ins (plugins/)", "2. entry points 'ges.plugins'", "3. registry.yaml plugins: [...]",
        "--no-plugin NAME skips one",
    ), ("ges_core/plugins.py", "ges_core/builtins.py"), CORE),
    Box("registry", 8.3, 6.85, 3.9, 1.75, "Registry", (
        "specs by kind and name", "defaults.hand / defaults.sim", "settings.<kind>.<name>",
        "build_hand() · build_sim() · ...",
    ), ("ges_core/registry.py", "registry.yaml"), CORE),
    Box("ifaces", 12.5, 6.85, 3.2, 1.75, "interfaces", (
        "HandModel, HandDescription", "SimBackend, SceneConfig", "ContactSet (5 slots)", "Expert, Gate",
    ), ("ges_core/hand.py", "ges_core/sim.py", "ges_core/contact.py", "ges_core/policy.py"), CORE),
    Box("hands", 0.3, 5.0, 5.0, 1.45, "hand plugins", (
        "shadow, allegro (built-in)", "outside packages, e.g. ges-ability-hand", "YAML description + URDF",
    ), ("plugins/hands/shadow", "plugins/hands/allegro", "examples/ges-ability-hand", "ges_core/hand_yaml.py"),
        PLUGIN),
    Box("sims", 5.6, 5.0, 5.0, 1.45, "simulator plugins", (
        "sapien (SAPIEN 3, CPU PhysX)", "pybullet (PyBullet 3.2.7)", "same contract, tests/test_sim_contract.py",
    ), ("plugins/sims/sapien", "plugins/sims/pybullet", "tests/test_sim_contract.py"), PLUGIN),
    Box("policies", 10.9, 5.0, 4.8, 1.45, "expert and gate plugins", (
        "Stage 2 policies", "(ges list expert / gate)",
    ), ("plugins/experts", "plugins/gates"), PLUGIN),
    Box("objects", 0.3, 2.75, 1.85, 1.6, "objects", (
        "procedural, pybullet,", "real, --user-dir;", "CoACD parts (cached)",
    ), ("ges_core/objects/library.py", "ges_core/objects/decompose.py"), STAGE1),
    Box("contacts", 2.39, 2.75, 1.85, 1.6, "1 contacts", (
        "5 contacts + normals", "from a point cloud,", "force closure",
    ), ("ges_core/synthesis/contacts",), STAGE1),
    Box("retarget", 4.48, 2.75, 1.85, 1.6, "2 retargeting", (
        "wrist search + IK:", "fingertips to the", "contacts, per hand",
    ), ("ges_core/synthesis/retarget",), STAGE1),
    Box("refine", 6.57, 2.75, 1.85, 1.6, "3 refinement", (
        "close in physics", "on a fixed object,", "no penetration",
    ), ("ges_core/synthesis/physics/refine.py", "ges_core/synthesis/physics/squeeze.py"), STAGE1),
    Box("pregrasp", 8.66, 2.75, 1.85, 1.6, "4 pre-grasp", (
        "2 cm back along", "the approach,", "fingers opened",
    ), ("ges_core/synthesis/physics/pregrasp.py",), STAGE1),
    Box("validate", 10.75, 2.75, 1.85, 1.6, "5 validation", (
        "lift and hold (paper)", "+ robust trials,", "each simulator",
    ), ("ges_core/synthesis/physics/validate.py", "ges_core/synthesis/physics/robust.py"), STAGE1),
    Box("dataset", 0.3, 0.3, 12.0, 1.65, "grasp dataset", (
        "one GraspRecord per (object, hand): contacts, grasp, pre-grasp, verdicts; times beside it",
        "manifest.json + records/<hand>/*.npz; resumable writer, one lock per folder",
        "ges dataset info / validate; ges retarget reuses its contacts for another hand",
    ), ("ges_core/dataset/record.py", "ges_core/dataset/store.py"), DATA),
    Box("env", 12.9, 0.3, 2.8, 4.25, "Stage 2", (
        "grasp_source:", "  records -> targets", "GraspEnv: N envs on", "  any SimBackend",
        "observation, reward,", "  success (paper)", "gymnasium Env,", "  rsl-rl VecEnv", "evaluate: experts",
        "  per split", "  (ges env baseline)",
    ), ("ges_core/env/grasp_source.py", "ges_core/env/grasp_env.py", "ges_core/env/gym_env.py",
        "ges_core/env/vec_env.py", "ges_core/env/evaluate"), STAGE2),
)  # fmt: skip
"""Every box of the picture."""

ARROWS: tuple[tuple[str, str, str], ...] = (
    ("hooks", "discovery", ""),
    ("discovery", "registry", ""),
    ("registry", "hands", "build_hand"),
    ("registry", "sims", "build_sim"),
    ("registry", "policies", "build_expert"),
    ("hands", "retarget", "kinematics"),
    ("sims", "refine", "physics"),
    ("sims", "validate", ""),
    ("objects", "contacts", ""),
    ("contacts", "retarget", ""),
    ("retarget", "refine", ""),
    ("refine", "pregrasp", ""),
    ("pregrasp", "validate", ""),
    ("validate", "dataset", "records"),
    ("dataset", "env", "grasps"),
    ("sims", "env", ""),
    ("policies", "env", "actions"),
)
"""(from, to, label): what flows between boxes."""

STAGE1_BAND = (0.15, 2.3, 12.6, 2.2)
"""x, y, w, h of the band around the Stage 1 steps (ges_core/synthesis/run: chunks, workers, resume)."""


def _anchor(box: Box, other: Box) -> tuple[float, float]:
    """Point on ``box``'s edge facing ``other``: side edges when they sit side by side, else top/bottom."""
    cx, cy = box.x + box.w / 2, box.y + box.h / 2
    ox, oy = other.x + other.w / 2, other.y + other.h / 2
    if abs(oy - cy) < (box.h + other.h) / 2:  # side by side: mid-height of the rows' overlap
        y = (max(box.y, other.y) + min(box.y + box.h, other.y + other.h)) / 2
        return (box.x + box.w, y) if ox > cx else (box.x, y)
    x = min(max(ox, box.x + 0.3), box.x + box.w - 0.3)
    return (x, box.y) if oy < cy else (x, box.y + box.h)


def draw(out: Path = OUT) -> Path:
    """Draw the picture to ``out`` (PNG, 1600 x 1000 px, no timestamp so a rerun gives the same bytes)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

    fig = plt.figure(figsize=(16, 10), dpi=100)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(0, 16)
    ax.set_ylim(0, 10)
    ax.axis("off")
    x, y, w, h = STAGE1_BAND
    ax.add_patch(FancyBboxPatch((x, y), w, h, boxstyle="round,pad=0.02", fc="#f4fbf4", ec="#6a9f6a", ls="--"))
    ax.text(x + 0.15, y + 0.04, "Stage 1 pipeline (ges_core/synthesis/run): per object and hand, in worker processes",
            fontsize=10, va="bottom", color="#3d6b3d", style="italic")  # fmt: skip
    ax.text(0.3, 8.75, "plugin core (ges_core/)", fontsize=10, color="#34608f", style="italic")
    by_key = {b.key: b for b in BOXES}
    for box in BOXES:
        ax.add_patch(FancyBboxPatch((box.x, box.y), box.w, box.h, boxstyle="round,pad=0.02", fc=box.colour,
                                    ec="#555555", lw=1.2))  # fmt: skip
        ax.text(box.x + 0.12, box.y + box.h - 0.12, box.title, fontsize=12, fontweight="bold", va="top")
        for i, line in enumerate(box.lines):
            ax.text(box.x + 0.12, box.y + box.h - 0.5 - 0.3 * i, line, fontsize=9.5, va="top")
    for src, dst, label in ARROWS:
        a, b = by_key[src], by_key[dst]
        start, end = _anchor(a, b), _anchor(b, a)
        ax.add_patch(FancyArrowPatch(start, end, arrowstyle="-|>", mutation_scale=14, lw=1.3, color="#444444"))
        if label:
            mx, my = (start[0] + end[0]) / 2, (start[1] + end[1]) / 2
            level = abs(end[1] - start[1]) < 1e-9  # a side-by-side arrow: label above it, else beside it
            ax.text(mx if level else mx + 0.08, my + 0.14 if level else my, label, fontsize=8.5, color="#444444",
                    ha="center" if level else "left", va="center")  # fmt: skip
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100, metadata={"Software": None})
    plt.close(fig)
    return out


if __name__ == "__main__":
    print(draw(Path(sys.argv[1]) if len(sys.argv) > 1 else OUT))
