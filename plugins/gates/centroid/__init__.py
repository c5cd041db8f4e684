"""Nearest-centroid gate: the baseline that picks the expert of the closest cluster centre in shape-feature space."""

from __future__ import annotations

from collections.abc import Callable

from ges_core import hookimpl
from ges_core.specs import GateSpec


@hookimpl
def ges_register_gates(register: Callable[[GateSpec], None]) -> None:
    """Register the ``centroid`` gate."""
    register(
        GateSpec(
            name="centroid",
            entry_point="ges_plugins.gates.centroid.gate:CentroidGate",
            description="baseline: expert of the nearest cluster centre in shape-feature space (no learning)",
        )
    )
