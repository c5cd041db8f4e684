"""Expert success grouped by how Stage 1 judged each object's grasp.

Stage 2 executes the Stage 1 grasp of each object, so an expert's failures may come from the grasp rather than from
the policy. This groups a success matrix's objects by their Stage 1 record (the primary simulator's verdict, the
one of ``ges dataset info``'s "validation" step):

=============  ===================================================================================================
group          the record's grasp
=============  ===================================================================================================
``robust``     held the nominal trial (the paper's) and every perturbation trial of robust validation
``validated``  held the nominal trial, but not every perturbation trial (or robust validation did not run)
``refined``    refined in physics, failed the nominal trial
``other``      no refined grasp (the retargeted pose), or no verdict
=============  ===================================================================================================

:func:`by_grasp` returns the matrix with these groups in place of its splits, so the split tables and comparisons of
:mod:`ges_core.experts.table` and :mod:`ges_core.experts.compare` read per group (``ges compare-experts --by-grasp``).
Every object's grasp is checked against the record's (the matrix cell stores the grasp key it ran): a dataset
whose record changed since the evaluation would otherwise group outcomes by another grasp's verdict.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from ges_core.dataset import Dataset, GraspRecord, open_dataset
from ges_core.env.evaluate.store import grasp_key
from ges_core.errors import ConfigError
from ges_core.experts.matrix import SuccessMatrix, read_matrix_json

__all__ = ["GRASP_GROUPS", "by_grasp", "by_grasp_of_file", "grasp_group"]

GRASP_GROUPS: dict[str, str] = {
    "robust": "held the nominal trial and every perturbation trial",
    "validated": "held the nominal trial, not every perturbation trial",
    "refined": "refined, failed the nominal trial",
    "other": "no refined grasp, or no verdict",
}
"""Group -> what its records' grasps did in Stage 1 (module docs)."""


def grasp_group(record: GraspRecord) -> str:
    """The :data:`GRASP_GROUPS` key of ``record``'s grasp, from its primary simulator's verdict."""
    verdict = record.validations.get(record.simulator)
    if verdict is not None and verdict.robust:
        return "robust"
    if verdict is not None and verdict.success:
        return "validated"
    if record.grasp_stage == "refinement":
        return "refined"
    return "other"


def by_grasp(matrix: SuccessMatrix, grasp_keys: dict[str, str | None], dataset: Dataset, hand: str) -> SuccessMatrix:
    """``matrix`` with each object's :func:`grasp_group` in place of its split.

    grasp_keys: object id -> the grasp key its cells ran (the matrix file's ``objects[id]["grasp_key"]``; None: not
    stored, not checked). ConfigError naming the object when ``dataset`` holds no record of it for ``hand``, or a
    record whose grasp is not the one evaluated.
    """
    groups = []
    for oid in matrix.object_ids:
        try:
            record = dataset.get(oid, hand)
        except KeyError:
            raise ConfigError(
                f"dataset {dataset.root} holds no '{hand}' record of '{oid}', an object of the matrix; give the "
                "dataset the matrix was evaluated on"
            ) from None
        ran = grasp_keys.get(oid)
        if ran is not None and ran != grasp_key(record):
            raise ConfigError(
                f"the matrix ran another grasp of '{oid}' than dataset {dataset.root} holds now (grasp key {ran} vs "
                f"{grasp_key(record)}): the record changed after the evaluation; rerun ges eval-experts on it"
            )
        groups.append(grasp_group(record))
    return replace(matrix, splits=tuple(groups))


def by_grasp_of_file(matrix: SuccessMatrix, path: str | Path, dataset: str | Path | None = None) -> SuccessMatrix:
    """:func:`by_grasp` of ``matrix`` with the hand, the grasp keys and (``dataset`` None or empty) the dataset
    read from the matrix file at ``path`` (``matrix`` may pool that file with other seeds' files)."""
    data = read_matrix_json(path)
    keys = {oid: entry.get("grasp_key") for oid, entry in data.get("objects", {}).items()}
    return by_grasp(matrix, keys, open_dataset(dataset or data["dataset"]), data["run"]["hand"])
