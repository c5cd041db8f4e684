"""PointNet++ gate (Qi et al., NeurIPS 2017, single-scale grouping). torch only."""

from __future__ import annotations

from collections.abc import Callable

from ges_core import hookimpl
from ges_core.specs import GateSpec


@hookimpl
def ges_register_gates(register: Callable[[GateSpec], None]) -> None:
    """Register the ``pointnet2`` gate."""
    register(
        GateSpec(
            name="pointnet2",
            entry_point="ges_plugins.gates.pointnet2.gate:PointNet2Gate",
            description="PointNet++ SSG (FPS, ball query, shared MLP, max-pool) on the object cloud -> expert softmax",
        )
    )
