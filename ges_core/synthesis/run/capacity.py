"""A Stage 1 dataset's drive-limited perturbation trials against what the kept grasps' fingertips can hold.

For every record with a grasp and perturbation trials: the quasi-static fingertip capacity of its grasp
(:func:`ges_core.synthesis.physics.capacity.fingertip_capacity`, with the record's Stage 1 contacts) at the nominal
effective friction and at each friction trial's, as a multiple of the object's weight; each drive-limited trial's
ask follows (``limits``: 1x at the nominal friction, ``mass_xS``: S x, ``friction_F``: 1x at F; pose trials carry the
nominal weight and fail by geometry, so they are left out). A failed trial beyond its bound is one no closing of
those fingertips could pass. ``ges dataset capacity`` prints it, ``benchmarks/stage1_capacity.py`` stores it;
docs/synthesis/refine_validate.md ("What the fingertips can hold") has the figures.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from tqdm import tqdm

from ges_core.errors import ArrayError, ConfigError, SimulationError
from ges_core.synthesis.contacts.generate import LIBRARY_CENTER_OF_MASS
from ges_core.synthesis.physics.capacity import NEAR, fingertip_capacity
from ges_core.synthesis.physics.robust import effective_friction, perturbations
from ges_core.synthesis.run.config import SynthesisConfig
from ges_core.synthesis.types import Grasp

__all__ = ["CLOUD_POINTS", "bound_counts", "bounds_table", "counts_table", "trial_asks", "trial_bounds"]

CLOUD_POINTS = 4096
"""Surface samples per object for the touching test and the normals (about 2 mm apart on a 10 cm object)."""


def trial_bounds(
    folder: Path,
    registry,
    *,
    near: float = NEAR,
    hands: list[str] | None = None,
    pressing: str | None = None,
    progress: bool = False,
) -> list[dict]:
    """One row per record of the dataset at ``folder`` with a grasp and drive-limited perturbation trials (``hands``:
    only theirs): hand, object, mass (kg), fingers touching, the capacity over the weight per friction coefficient,
    and per drive-limited trial and simulator whether it passed and whether its ask is within the bound. Each trial's
    ask comes from the trial itself as the run made it (:func:`~ges_core.synthesis.physics.robust.perturbations` under
    the hand's settings of the dataset's config): its density factor at the friction it ran with. A name in ``hands``
    that no record is of is a ConfigError naming the hands the dataset holds.

    pressing: a simulator's name: the ``limits`` trial's close is run again there for each record (drives capped, the
    nominal object; :func:`~ges_core.synthesis.physics.validate.pressing_fingers`) and only the fingers it leaves
    pressing the object count (``fingers_pressing`` in the row): a finger that ends on another finger or short of the
    object carries nothing, though its pad may lie near its contact. About 0.1-0.5 s per record; ``progress``: a bar.
    A record whose replay blows up (SimulationError, ArrayError) gets a row with ``pressing_error`` (the message) and
    no trials, so it counts nowhere; the other records go on.
    """
    from ges_core.dataset import open_dataset
    from ges_core.env.grasp_source import library_for, record_asset

    dataset = open_dataset(folder)
    _check_hands_held(dataset, hands)
    config = SynthesisConfig.of_dataset(dataset)
    library = library_for(dataset)
    models, configs, clouds, rows = {}, {}, {}, []
    records = sorted(dataset.records(), key=lambda r: (r.hand, r.object_id))
    for record in tqdm(records, desc="replaying closes", unit="record", disable=not (progress and pressing)):
        trials = {sim: v.trials for sim, v in record.validations.items() if v.trials}
        if record.grasp is None or not trials or (hands and record.hand not in hands):
            continue
        if record.hand not in models:
            models[record.hand] = registry.build_hand(record.hand)
            configs[record.hand] = config.for_hand(record.hand, models[record.hand].description.settings)
        cfg = configs[record.hand]
        if not cfg.robust.drive_limits:  # the trials ran uncapped: no actuator bound applies
            continue
        if record.object_id not in clouds:
            clouds[record.object_id] = library.point_cloud(record.object_id, CLOUD_POINTS, seed=0)
        asset = library.get(record.object_id)
        nominal = effective_friction(cfg.scene.hand_friction, asset.friction)
        asks = trial_asks(cfg, asset, record.seed)
        grasp = Grasp(record.hand, record.grasp.wrist_pose, record.grasp.q)
        pressed = None
        if pressing is not None:
            pre = Grasp(record.hand, record.pregrasp.wrist_pose, record.pregrasp.q)
            checked = record_asset(library, record)  # the object as Stage 2 builds it for this record
            try:
                pressed = _pressing(registry, pressing, cfg, models[record.hand], checked, grasp, pre)
            except (SimulationError, ArrayError) as error:  # no pressing fingers to bound with: say so, go on
                rows.append({
                    "hand": record.hand, "object": record.object_id, "mass": asset.mass, "fingers_touching": None,
                    "ratio_by_mu": {}, "trials": {}, "pressing_error": f"{type(error).__name__}: {error}",
                })  # fmt: skip
                continue
        ratio, fingers = {}, 0
        for mu in sorted({nominal} | {mu for _, mu in asks.values()}):
            tip = fingertip_capacity(
                models[record.hand], grasp, *clouds[record.object_id], mu, center=LIBRARY_CENTER_OF_MASS, near=near,
                contacts=record.contacts, fingers=pressed,
            )  # fmt: skip
            ratio[mu], fingers = tip.ratio(asset.mass, abs(cfg.scene.gravity)), len(tip.fingers)
        outcomes: dict[str, dict[str, dict[str, bool]]] = {}
        for sim, ts in sorted(trials.items()):
            for t in ts:
                if t.name in asks:  # pose trials carry the nominal weight: not bounded
                    scale, mu = asks[t.name]
                    outcomes.setdefault(t.name, {})[sim] = {"passed": t.success, "bound_ok": ratio[mu] >= scale}
        rows.append({
            "hand": record.hand, "object": record.object_id, "mass": asset.mass, "fingers_touching": fingers,
            "ratio_by_mu": {f"{mu:g}": r for mu, r in ratio.items()}, "trials": outcomes,
        } | ({} if pressed is None else {"fingers_pressing": list(pressed)}))  # fmt: skip
    return rows


def _pressing(registry, sim: str, cfg: SynthesisConfig, hand, asset, grasp: Grasp, pre: Grasp) -> tuple[str, ...]:
    """The fingers the ``limits`` trial's close leaves pressing the object, run again in ``sim`` (a fresh backend)."""
    from ges_core.synthesis.physics.robust import trial_limits
    from ges_core.synthesis.physics.scene import TrialScenes
    from ges_core.synthesis.physics.validate import pressing_fingers

    scenes = TrialScenes(registry.build_sim, sim, cfg.scene, hand)
    with scenes.open() as backend:
        return pressing_fingers(
            backend, hand, asset, grasp, pre, cfg.validate_, drive_limits=trial_limits(scenes, cfg.robust),
            squeeze_mass=asset.mass,
        )  # fmt: skip


def trial_asks(cfg: SynthesisConfig, asset, seed: int) -> dict[str, tuple[float, float]]:
    """Trial name -> (weight multiple, effective friction) of each trial of ``cfg.robust`` that changes the load
    (limits, mass, friction), as :func:`~ges_core.synthesis.physics.robust.perturbations` makes them."""
    hand_mu = cfg.scene.hand_friction
    return {
        p.name: (p.density_scale, effective_friction(hand_mu, asset.friction if p.friction is None else p.friction))
        for p in perturbations(cfg.robust, hand_mu, asset, seed)
        if p.shift is None
    }


def _check_hands_held(dataset, hands: list[str] | None) -> None:
    """ConfigError naming the hands of ``dataset``'s records (read off its index, no record loaded) when ``hands``
    names one that no record is of: a typo, or another dataset's hand, would otherwise read as "no record with
    trials"."""
    held = sorted({entry["hand"] for entry in dataset.entries})
    missing = [hand for hand in hands or () if hand not in held]
    if missing:
        of = ", ".join(held) or "none"
        raise ConfigError(f"{dataset.root} holds no record of hand {', '.join(missing)}; its records are of: {of}")


def bound_counts(rows: list[dict]) -> dict[str, dict[str, int]]:
    """Per hand, over every simulator: trials ``failed_beyond``, ``failed_within``, ``passed_within``,
    ``passed_beyond`` the bound."""
    out: dict[str, Counter] = {}
    for row in rows:
        tally = out.setdefault(row["hand"], Counter())
        for by_sim in row["trials"].values():
            for o in by_sim.values():
                tally[("passed" if o["passed"] else "failed") + ("_within" if o["bound_ok"] else "_beyond")] += 1
    return {hand: dict(tally) for hand, tally in out.items()}


def bounds_table(rows: list[dict]) -> str:
    """Markdown: one line per record, each trial's outcome per simulator, ``!`` beyond the bound; then the records
    whose replay of the close failed (``pressing_error``), one line each."""
    failed = [row for row in rows if "pressing_error" in row]
    rows = [row for row in rows if "pressing_error" not in row]
    not_replayed = [
        f"not replayed: {row['hand']} / {row['object']}: {row['pressing_error']} (no bound; counted nowhere)"
        for row in failed
    ]
    if not rows:
        return "\n".join(not_replayed)
    trials = sorted({name for row in rows for name in row["trials"]})
    lines = [
        "| hand | object | kg | tips | capacity / weight | " + " | ".join(trials) + " |",
        "|" + "---|" * (5 + len(trials)),
    ]
    for row in rows:
        caps = ", ".join(f"{r:.2f} at mu {mu}" for mu, r in row["ratio_by_mu"].items())
        cells = [
            " ".join(
                f"{sim[:2]}{'+' if o['passed'] else '-'}{'' if o['bound_ok'] else '!'}"
                for sim, o in row["trials"].get(name, {}).items()
            )
            for name in trials
        ]
        tips = str(row["fingers_touching"])
        if "fingers_pressing" in row:  # the close's pressing fingers: the bound's candidates
            tips += f" of {'+'.join(row['fingers_pressing']) or 'none'}"
        lines.append(
            f"| {row['hand']} | {row['object']} | {row['mass']:.3f} | {tips} | {caps} | "
            + " | ".join(cells) + " |"
        )  # fmt: skip
    lines.append("(+ held, - failed; ! beyond the fingertips' bound: no closing of them could pass)")
    return "\n".join(lines + not_replayed)


def counts_table(counts: dict[str, dict[str, int]]) -> str:
    """Markdown: :func:`bound_counts` per hand."""
    lines = [
        "| hand | failed, beyond the bound | failed, within it | passed, within it | passed, beyond it |",
        "|---|---|---|---|---|",
    ]
    for hand, c in sorted(counts.items()):
        cells = [c.get(k, 0) for k in ("failed_beyond", "failed_within", "passed_within", "passed_beyond")]
        lines.append(f"| {hand} | " + " | ".join(str(v) for v in cells) + " |")
    return "\n".join(lines) + "\n(drive-limited trials in every validating simulator; pose trials left out)"
