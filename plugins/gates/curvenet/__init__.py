"""CurveNet gate (Xiang et al., "Walk in the Cloud", ICCV 2021). torch only."""

from __future__ import annotations

from collections.abc import Callable

from ges_core import hookimpl
from ges_core.specs import GateSpec


@hookimpl
def ges_register_gates(register: Callable[[GateSpec], None]) -> None:
    """Register the ``curvenet`` gate."""
    register(
        GateSpec(
            name="curvenet",
            entry_point="ges_plugins.gates.curvenet.gate:CurveNetGate",
            description="CurveNet (curve grouping and aggregation, LPFA, CIC) on the object cloud -> expert softmax",
        )
    )
