"""Stage 1: contact-guided grasp synthesis, one subpackage per step, in data-flow order.

======================  =====================================  ============================================
step                    entry point                            input -> output
======================  =====================================  ============================================
1 ``contacts/``         :func:`generate_contacts`              point cloud -> five contacts (ContactResult)
2 ``retarget/``         :class:`GraspRetargeter`               contacts -> wrist pose + joints (Grasp)
3 ``physics/refine``    :func:`refine_grasp`                   Grasp -> settled Grasp in a simulator (RefinedGrasp)
4 ``physics/pregrasp``  :func:`pregrasp`                       Grasp -> backed-off, opened Grasp (no simulator)
5 ``physics/validate``  :func:`validate_grasp`                 Grasp + pre-grasp -> lift-and-hold verdict
======================  =====================================  ============================================

``types`` holds what passes between the steps (:class:`ContactResult`, :class:`Grasp`,
:class:`RefinedGrasp`, :class:`ValidationResult`). ``run/`` takes many objects and hands through the five
steps: :class:`SynthesisConfig` (the run's settings, ``thumb_keep`` the one opened hand of steps 2-4),
:func:`run_synthesis` (tasks, workers, one :class:`~ges_core.dataset.GraspRecord` per pair, the dataset),
:func:`table_rows` / :func:`format_table` (the paper's Table 1) and :func:`run_demo` (``ges demo``).
Hands and simulators enter only through their interfaces.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

_EXPORTS: dict[str, str] = {
    "ContactConfig": "contacts",
    "generate_contacts": "contacts",
    "THUMB_KEEP": "physics",
    "PregraspConfig": "physics",
    "RefineConfig": "physics",
    "ValidateConfig": "physics",
    "pregrasp": "physics",
    "refine_grasp": "physics",
    "validate_grasp": "physics",
    "GraspRetargeter": "retarget",
    "RetargetConfig": "retarget",
    "RegistrySpec": "run",
    "RunReport": "run",
    "SynthesisConfig": "run",
    "format_table": "run",
    "run_demo": "run",
    "run_synthesis": "run",
    "table_rows": "run",
    "ContactResult": "types",
    "Grasp": "types",
    "RefinedGrasp": "types",
    "ValidationResult": "types",
}
"""Name -> the subpackage holding it. Imported on first use (PEP 562), so ``import
ges_core.synthesis.physics.squeeze`` (the env's scripted expert does) does not pull in the run, the dataset
writer and the object library."""

if TYPE_CHECKING:
    from ges_core.synthesis.contacts import ContactConfig, generate_contacts
    from ges_core.synthesis.physics import (
        THUMB_KEEP,
        PregraspConfig,
        RefineConfig,
        ValidateConfig,
        pregrasp,
        refine_grasp,
        validate_grasp,
    )
    from ges_core.synthesis.retarget import GraspRetargeter, RetargetConfig
    from ges_core.synthesis.run import (
        RegistrySpec,
        RunReport,
        SynthesisConfig,
        format_table,
        run_demo,
        run_synthesis,
        table_rows,
    )
    from ges_core.synthesis.types import ContactResult, Grasp, RefinedGrasp, ValidationResult


def __getattr__(name: str) -> object:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])


__all__ = [
    "THUMB_KEEP",
    "ContactConfig",
    "ContactResult",
    "Grasp",
    "GraspRetargeter",
    "PregraspConfig",
    "RefineConfig",
    "RefinedGrasp",
    "RegistrySpec",
    "RetargetConfig",
    "RunReport",
    "SynthesisConfig",
    "ValidateConfig",
    "ValidationResult",
    "format_table",
    "generate_contacts",
    "pregrasp",
    "refine_grasp",
    "run_demo",
    "run_synthesis",
    "table_rows",
    "validate_grasp",
]
