"""Stage 1 grasps for the Stage 2 environment: dataset records -> object asset + :class:`GraspTargets`.

The paper's Stage 2 starts every episode at the pre-grasp ``g_init`` of a Stage 1 grasp ``g``. Here
they come from a ContactGrasp-style dataset (``docs/dataset.md``)::

    dataset = open_grasp_dataset("runs/demo/dataset")
    chosen = select_records(dataset, "allegro", split="train", selection="validated")
    library = library_for(dataset)
    for record in chosen.records:                       # one GraspEnv per object, many envs each
        asset = record_asset(library, record)           # checked: the record's contacts lie on it
        pose = object_rest_pose(registry, "sapien", asset)  # the env's object frame in the world
        targets = grasp_targets(record, hand.description, num_envs=8, object_pose=pose)
        env = GraspEnv(sim, hand, asset, targets, EnvConfig())

Frames: a record stores poses in the **object frame** (the object's resting frame, table plane z = 0);
:class:`GraspTargets` are in the **world frame**. ``grasp_targets`` maps them through the object's
pose in the world right after ``load_object`` (resting at the origin, lifted by the backend's rest
margin, 0.2 mm in both built-in backends), exactly as Stage 1 validation does. Joint vectors are
matched to the hand **by name** (the record carries its ``joint_names``), and coupled joints are set
from their leaders (``HandDescription.apply_couplings``), as validation does.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ges_core.arrays import checked_poses
from ges_core.dataset import Dataset, GraspRecord, open_dataset
from ges_core.dataset.object_fit import CONTACT_TOLERANCE, contacts_off_surface
from ges_core.dataset.object_fit import misfit as record_misfit
from ges_core.env.grasp_env import GraspTargets
from ges_core.errors import AssetError, ConfigError, GesError
from ges_core.hand import HandDescription
from ges_core.objects.asset import ObjectAsset
from ges_core.objects.splits import SPLITS
from ges_core.sim import SceneConfig
from ges_core.transforms import compose

__all__ = [
    "CONTACT_TOLERANCE",
    "SELECTIONS",
    "GraspSelection",
    "contacts_off_surface",
    "grasp_targets",
    "library_for",
    "load_grasp",
    "object_problems",
    "object_rest_pose",
    "open_grasp_dataset",
    "record_asset",
    "rejection",
    "select_records",
]

SELECTIONS: dict[str, str] = {
    "validated": "every Stage 1 step succeeded (physics validation included)",
    "refined": "refinement succeeded (validation may have failed or not run)",
    "any": "any record holding a grasp and a pre-grasp (refinement may have failed)",
}
"""Which records give grasps: name -> rule. ``validated`` is the default; the Shadow hand validates
no grasp yet (``runs/demo/table.md``), so its baseline uses ``refined``."""


def open_grasp_dataset(path: str | Path) -> Dataset:
    """The Stage 1 dataset at ``path``; AssetError saying how to make one if there is none."""
    root = Path(path)
    if not root.is_dir():
        raise AssetError(
            f"no grasp dataset at {root}: the folder does not exist. Generate one with Stage 1 "
            f"(`ges synth --hands allegro --out {root}` or `ges demo`)"
        )
    return open_dataset(root)


def dataset_hand(path: str | Path, registry, given: str | None = None) -> str:
    """The hand a Stage 2 command runs when ``--hand`` is not ``given``: the dataset's only hand, else the
    registry's default hand if the dataset holds it; a ConfigError naming the dataset's hands otherwise. A given
    hand is returned as is (a dataset without its records says so where the records are chosen)."""
    if given:
        return given
    root = Path(path)
    hands = sorted({e["hand"] for e in open_grasp_dataset(root).entries})
    if len(hands) == 1:
        return hands[0]
    default = registry.default("hand")
    if default in hands or not hands:
        return default
    raise ConfigError(
        f"dataset {root} holds records of the hands {hands} and not of the default hand '{default}'; "
        "choose one with --hand"
    )


def rejection(record: GraspRecord, selection: str) -> str:
    """Why ``record`` does not give a grasp under ``selection`` ('' when it does)."""
    _check_selection(selection)
    if record.grasp is None or record.pregrasp is None:
        return f"no grasp stored ({_failure(record) or 'no grasp'})"
    if selection == "validated" and not record.success:
        return f"not validated ({_failure(record)})"
    if selection == "refined" and not record.steps["refinement"].ok:
        return f"not refined ({_failure(record)})"
    return ""


def _failure(record: GraspRecord) -> str:
    step = record.failed_step
    if step is None:
        return "validation not run" if record.steps["validation"].reason == "not_run" else ""
    return f"failed at {step}: {record.steps[step].reason}"


def _check_selection(selection: str) -> None:
    if selection not in SELECTIONS:
        raise ConfigError(f"unknown grasp selection '{selection}'; choose one of {', '.join(SELECTIONS)}")


@dataclass(frozen=True)
class GraspSelection:
    """Records of one hand chosen by a selection rule, and the ones left out with their reasons."""

    hand: str
    selection: str
    records: tuple[GraspRecord, ...]
    """The usable records, dataset order (hand, then object id)."""
    rejected: dict[str, str] = field(default_factory=dict)
    """object_id -> why its record was left out."""
    splits: dict[str, str] = field(default_factory=dict)
    """object_id -> split, for every record considered (chosen or not)."""


def select_records(
    dataset: Dataset,
    hand: str,
    *,
    simulator: str | None = None,
    split: str | None = None,
    selection: str = "validated",
) -> GraspSelection:
    """The records of ``hand`` (and ``simulator``, ``split`` when given) that pass ``selection``.

    AssetError when the dataset holds no record of that hand / simulator / split at all (naming
    what it does hold); an empty ``records`` when records exist but none passes the rule.
    """
    _check_selection(selection)
    if split is not None and split not in SPLITS:
        raise ConfigError(f"unknown split '{split}'; choose one of {', '.join(SPLITS)}")
    entries = _matching_entries(dataset, hand, simulator, split)
    chosen, rejected, splits = [], {}, {}
    for record in dataset.records(hand=hand):
        if (record.object_id, record.hand) not in entries:
            continue
        splits[record.object_id] = record.split
        why = rejection(record, selection)
        if why:
            rejected[record.object_id] = why
        else:
            chosen.append(record)
    return GraspSelection(hand, selection, tuple(chosen), rejected, splits)


def _matching_entries(dataset: Dataset, hand: str, simulator: str | None, split: str | None) -> set:
    """(object_id, hand) of the index entries that match; AssetError naming what exists when none does."""
    entries = [e for e in dataset.entries if e["hand"] == hand]
    if not entries:
        hands = sorted({e["hand"] for e in dataset.entries})
        raise AssetError(
            f"dataset {dataset.root} holds no record of hand '{hand}' (it holds: {', '.join(hands) or 'none'}); "
            f"generate them with `ges synth --hands {hand} --out {dataset.root}`"
        )
    for key, value in (("simulator", simulator), ("split", split)):
        if value is None:
            continue
        present = sorted({e.get(key, "") for e in entries})
        entries = [e for e in entries if e.get(key) == value]
        if not entries:
            raise AssetError(
                f"dataset {dataset.root} holds no record of hand '{hand}' with {key} '{value}' "
                f"(its {key}s for that hand: {', '.join(present)})"
            )
    return {(e["object_id"], e["hand"]) for e in entries}


def library_for(dataset: Dataset):
    """The :class:`~ges_core.objects.library.ObjectLibrary` the dataset was generated from (its run config)."""
    from ges_core.config import parse_model
    from ges_core.objects.library import LibraryConfig

    settings = dataset.run_config.get("library") if isinstance(dataset.run_config, dict) else None
    if not isinstance(settings, dict):
        raise ConfigError(
            f"dataset {dataset.root}: its run_config has no 'library' section, so its objects cannot be "
            "rebuilt; it was not written by the Stage 1 pipeline (ges synth / ges demo)"
        )
    return parse_model(LibraryConfig, settings, where=f"{dataset.root} run_config.library").build()


def record_asset(library, record: GraspRecord, *, tolerance: float = CONTACT_TOLERANCE) -> ObjectAsset:
    """The ``library``'s :class:`ObjectAsset` of ``record``'s object, checked to be the object the grasp was made on.

    AssetError (naming the object, the distance and what to do) when a contact of the record lies farther than
    ``tolerance`` m from the asset's surface mesh: the library now builds that object with another mesh or resting
    frame than when Stage 1 ran. A record without contacts (none generated, or imported without them) is not
    checked.
    """
    asset = library.get(record.object_id)
    misfit = record_misfit(record, asset.mesh_path, tolerance)
    if misfit:
        raise AssetError(
            f"record of ({record.object_id}, {record.hand}): {misfit}, so the stored grasp would run in the wrong "
            f"place; regenerate its records (`ges synth --objects {record.object_id} --hands {record.hand}` into a "
            "new dataset folder)"
        )
    return asset


def object_problems(dataset: Dataset, *, tolerance: float = CONTACT_TOLERANCE) -> list[str]:
    """One line per record whose object the dataset's library cannot build any more, or whose contacts lie farther
    than ``tolerance`` m off that object's surface (``ges dataset validate --objects``); [] when every record fits.

    Only the placed surface mesh is built (no collision decomposition), so it is quick; the check is
    :func:`record_asset`'s.
    """
    library = library_for(dataset)
    problems = []
    for record in dataset.records():
        if record.contacts is None:
            continue
        try:
            mesh = library.processed(record.object_id).mesh_path
        except GesError as error:
            problems.append(f"({record.object_id}, {record.hand}): the library cannot build the object: {error}")
            continue
        misfit = record_misfit(record, mesh, tolerance)
        if misfit:
            problems.append(f"({record.object_id}, {record.hand}): {misfit}")
    return problems


def grasp_targets(
    record: GraspRecord, hand: HandDescription, num_envs: int, object_pose: np.ndarray | None = None
) -> GraspTargets:
    """The record's grasp and pre-grasp for ``num_envs`` envs, world frame, joints in ``hand``'s order.

    object_pose: (7,) the object's pose in the world (m, wxyz), e.g. :func:`object_rest_pose`;
    None: the object frame is the world frame.
    """
    if num_envs < 1:
        raise ConfigError(f"grasp_targets: num_envs={num_envs}; give at least 1")
    if record.hand != hand.name:
        raise ConfigError(
            f"record of object '{record.object_id}' is for hand '{record.hand}', not '{hand.name}'; "
            f"select records with hand='{hand.name}'"
        )
    if record.grasp is None or record.pregrasp is None:
        raise AssetError(
            f"record of ({record.object_id}, {record.hand}) holds no grasp to execute "
            f"({_failure(record) or 'no grasp'}); pick records with select_records()"
        )
    order = _joint_order(record, hand)
    world = None if object_pose is None else _checked_pose(object_pose)
    rows = []
    for pose in (record.grasp, record.pregrasp):
        wrist = pose.wrist_pose if world is None else compose(world, pose.wrist_pose)
        rows += [wrist, hand.apply_couplings(pose.q[order])]
    return GraspTargets(*(np.tile(np.asarray(r, dtype=np.float64), (num_envs, 1)) for r in rows))


def _checked_pose(pose: np.ndarray) -> np.ndarray:
    """(7,) float64 ``pose``; ArrayError unless finite with a non-zero quaternion."""
    return checked_poses(pose, None, "grasp_targets: object_pose")


def _joint_order(record: GraspRecord, hand: HandDescription) -> np.ndarray:
    """Indices taking the record's joint vector to ``hand.joint_names`` order; ConfigError on a mismatch."""
    stored = list(record.joint_names)
    missing = [n for n in hand.joint_names if n not in stored]
    extra = [n for n in stored if n not in hand.joint_names]
    if missing or extra:
        raise ConfigError(
            f"record of ({record.object_id}, {record.hand}) names other joints than hand '{hand.name}': "
            f"missing {missing}, unknown {extra}; the hand definition changed since Stage 1 ran; "
            "regenerate the records"
        )
    return np.array([stored.index(n) for n in hand.joint_names], dtype=np.int64)


def object_rest_pose(registry, sim_name: str, asset: ObjectAsset, scene: SceneConfig | None = None) -> np.ndarray:
    """(7,) world pose of ``asset`` resting on the table after ``load_object`` in simulator ``sim_name``.

    Built in a throw-away one-env scene (``GraspEnv`` loads the object itself, after the hand).
    """
    scene = (scene or SceneConfig()).model_copy(update={"num_envs": 1})
    with registry.build_sim(sim_name, scene) as sim:
        sim.load_object(asset)
        return np.asarray(sim.object_pose()[0], dtype=np.float64)


def load_grasp(
    dataset: Dataset | str | Path,
    object_id: str,
    hand: HandDescription,
    num_envs: int,
    *,
    selection: str = "validated",
    registry=None,
    sim_name: str | None = None,
) -> tuple[ObjectAsset, GraspTargets]:
    """(object asset, grasp targets for ``num_envs`` envs) of one object's record for ``hand``.

    With ``registry`` and ``sim_name`` the targets are in that simulator's world (the object's rest
    pose, :func:`object_rest_pose`); without, in the object frame. AssetError when the record is
    missing, does not pass ``selection`` (saying why) or does not fit the library's object (:func:`record_asset`).
    """
    if not isinstance(dataset, Dataset):
        dataset = open_grasp_dataset(dataset)
    _matching_entries(dataset, hand.name, None, None)
    try:
        record = dataset.get(object_id, hand.name)
    except KeyError:
        raise AssetError(
            f"dataset {dataset.root} holds no record of object '{object_id}' with hand '{hand.name}'"
        ) from None
    why = rejection(record, selection)
    if why:
        raise AssetError(
            f"record of ({object_id}, {hand.name}) in {dataset.root} gives no grasp under selection "
            f"'{selection}' ({SELECTIONS[selection]}): {why}"
        )
    asset = record_asset(library_for(dataset), record)
    pose = None if registry is None or sim_name is None else object_rest_pose(registry, sim_name, asset)
    return asset, grasp_targets(record, hand, num_envs, pose)
