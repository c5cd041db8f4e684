"""The gate networks as they were at a git revision, importable beside today's (for old-vs-new timings).

``baseline_gate_class(rev, name)`` reads the torch-gate and network files of revision ``rev`` with
``git show`` (read-only), renames their imports of each other to a private ``gate_baseline_<rev>``
package and executes them; the rest (``ges_core.gating.inputs``, checkpoints, training) is today's. The
returned class builds the old network, whose state dict has the same keys as today's, so both can carry
the same weights and be timed on the same input in the same process.
"""

from __future__ import annotations

import subprocess
import sys
import types
from pathlib import Path

__all__ = ["BASELINE_REV", "baseline_gate_class"]

BASELINE_REV = "affc6ef9f9ae8fccd15bc4766f9839b8a9e9401d"
"""The last commit before the gate inference rewrite of December 2026 (CurveNet 26.4 ms at 1024 points)."""

ROOT = Path(__file__).resolve().parent.parent
FILES = {  # module name today -> (file, short name in the baseline package)
    "ges_core.gating.ops": ("ges_core/gating/ops.py", "ops"),
    "ges_core.gating.layers": ("ges_core/gating/layers.py", "layers"),
    "ges_core.gating.torch_gate": ("ges_core/gating/torch_gate.py", "torch_gate"),
    "ges_plugins.gates.curvenet.blocks": ("plugins/gates/curvenet/blocks.py", "curvenet_blocks"),
    "ges_plugins.gates.curvenet.model": ("plugins/gates/curvenet/model.py", "curvenet_model"),
    "ges_plugins.gates.curvenet.gate": ("plugins/gates/curvenet/gate.py", "curvenet_gate"),
    "ges_plugins.gates.pointnet2.model": ("plugins/gates/pointnet2/model.py", "pointnet2_model"),
    "ges_plugins.gates.pointnet2.gate": ("plugins/gates/pointnet2/gate.py", "pointnet2_gate"),
}
GATE_CLASSES = {"curvenet": ("curvenet_gate", "CurveNetGate"), "pointnet2": ("pointnet2_gate", "PointNet2Gate")}


def _load(rev: str) -> str:
    """Execute the baseline files of ``rev`` (once) and return their package name."""
    package = f"gate_baseline_{rev[:12]}"
    if package in sys.modules:
        return package
    sys.modules[package] = types.ModuleType(package)
    sys.modules[package].__path__ = []  # a package: its submodules are the entries below
    for _, (path, short) in FILES.items():  # in dependency order (the dict's order)
        source = subprocess.run(
            ["git", "show", f"{rev}:{path}"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout
        for today, (_, other) in FILES.items():
            source = source.replace(today, f"{package}.{other}")
        module = types.ModuleType(f"{package}.{short}")
        module.__file__ = f"{rev}:{path}"
        sys.modules[module.__name__] = module
        exec(compile(source, module.__file__, "exec"), module.__dict__)  # noqa: S102 - our own repository's code
    return package


def baseline_gate_class(rev: str, name: str) -> type:
    """The ``name`` gate class (curvenet, pointnet2) as it was at git revision ``rev``."""
    module, cls = GATE_CLASSES[name]
    return getattr(sys.modules[f"{_load(rev)}.{module}"], cls)
