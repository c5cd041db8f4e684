"""``ges demo``: Stage 1 on about 20 built-in objects with both hands, pictures and a Table 1 summary.

Output folder (default ``runs/demo/``)::

    dataset/              the grasp dataset (docs/dataset.md); a second run resumes it
    pictures/<hand>/*.png one picture per grasp
    contact_sheet.png     every picture, green frame = validated grasp, red = failed
    table.md              the summary table printed at the end
"""

from __future__ import annotations

import time
from pathlib import Path

from pydantic import Field, field_validator

from ges_core.config import ConfigModel, load_config
from ges_core.dataset import open_dataset
from ges_core.paths import atomic_write_text
from ges_core.synthesis.run.config import SynthesisConfig
from ges_core.synthesis.run.pipeline import run_synthesis
from ges_core.synthesis.run.table import format_table, table_rows
from ges_core.synthesis.run.tasks import RegistrySpec

__all__ = ["DEMO_OBJECTS", "DemoConfig", "default_demo_config", "draw_contact_sheet", "run_demo"]

DEMO_OBJECTS: tuple[str, ...] = (
    "procedural/can/000",
    "procedural/box/000",
    "procedural/cube/000",
    "pybullet/classic/jenga",
    "procedural/sphere/000",
    "procedural/capsule/000",
    "procedural/cone/000",
    "procedural/ellipsoid/000",
    "procedural/wedge/000",
    "procedural/l_bracket/000",
    "procedural/plate/000",
    "pybullet/classic/cylinder",
    "pybullet/classic/prism",
    "pybullet/classic/domino",
    "pybullet/random_urdfs/000",
    "pybullet/random_urdfs/001",
    "pybullet/random_urdfs/002",
    "procedural/can/001",
    "procedural/box/001",
    "procedural/sphere/001",
)
"""Built-in objects of every convex or pre-decomposed kind (no CoACD run needed), categories interleaved
so that the first few already span several categories (``-o objects=3``)."""

DEMO_CONFIG = Path(__file__).resolve().parents[3] / "configs" / "demo.yaml"


class DemoConfig(ConfigModel):
    """Settings of ``ges demo`` (``configs/demo.yaml``; ``-o key=value`` overrides)."""

    objects: int | list[str] = Field(
        len(DEMO_OBJECTS), description="how many of the built-in demo objects (first N), or a list of object ids"
    )
    hands: list[str] = Field(["shadow", "allegro"], min_length=1, description="registry names of the hands")
    out: str = Field("runs/demo", description="output folder")
    workers: int = Field(1, ge=1, description="worker processes")
    pictures: bool = Field(True, description="draw a PNG per grasp and a contact sheet")
    synthesis: SynthesisConfig = Field(default_factory=SynthesisConfig)

    @field_validator("objects", mode="before")
    @classmethod
    def _some_objects(cls, objects: object) -> object:
        """A count from 1 to len(DEMO_OBJECTS) or a non-empty list (a slice would take ``-2`` as "all but two")."""
        count = isinstance(objects, int) and not isinstance(objects, bool) and 1 <= objects <= len(DEMO_OBJECTS)
        if not (count or (isinstance(objects, list) and objects)):
            raise ValueError(
                f"{objects!r}: give a count from 1 to {len(DEMO_OBJECTS)} (the first N demo objects) "
                "or a non-empty list of object ids"
            )
        return objects

    def object_ids(self) -> list[str]:
        """The objects of this demo run."""
        if isinstance(self.objects, int):
            return list(DEMO_OBJECTS[: self.objects])
        return list(self.objects)


def default_demo_config(path: str | Path | None = None, overrides: tuple[str, ...] = ()) -> DemoConfig:
    """The demo config from ``path`` (default ``configs/demo.yaml`` when present) with overrides."""
    if path is None and DEMO_CONFIG.is_file():
        path = DEMO_CONFIG
    return load_config(DemoConfig, path, overrides)


def run_demo(
    config: DemoConfig,
    *,
    registry: RegistrySpec | None = None,
    progress: bool = True,
    executor: str = "local",
    address: str | None = None,
) -> str:
    """Run the demo and return the text it prints at the end (summary table and where things are).

    ``executor``/``address``: where the tasks run (:func:`~ges_core.synthesis.run.pipeline.run_synthesis`)."""
    start = time.perf_counter()
    out = Path(config.out)
    ids, hands = config.object_ids(), list(config.hands)
    pictures = out / "pictures" if config.pictures else None
    report = run_synthesis(
        ids, hands, config.synthesis, out / "dataset", workers=config.workers, progress=progress,
        registry=registry, pictures=pictures, executor=executor, address=address,
    )  # fmt: skip
    wanted = {(o, h) for o in ids for h in hands}
    records = [r for r in open_dataset(out / "dataset") if r.key in wanted]
    table = format_table(table_rows(records))
    atomic_write_text(out / "table.md", table + "\n")
    lines = [table, "", _failures(records)]
    if pictures is not None:
        lines.append(f"contact sheet: {draw_contact_sheet(records, out / 'contact_sheet.png')}")
    lines.append(
        f"{len(report.written)} grasps synthesized, {len(report.skipped)} already in {out / 'dataset'} (resumed); "
        f"wall time {time.perf_counter() - start:.1f} s"
    )
    return "\n".join(lines)


def _failures(records) -> str:
    counts: dict[str, int] = {}
    for r in records:
        if r.failed_step is not None:
            key = f"{r.hand} {r.failed_step}:{r.steps[r.failed_step].reason}"
            counts[key] = counts.get(key, 0) + 1
    return "failures: " + (", ".join(f"{k} x{n}" for k, n in sorted(counts.items())) or "none")


def draw_contact_sheet(records, path: Path) -> Path | str:
    """Every record's picture in one PNG at ``path`` (green frame: validated, red: failed); the path, or
    ``"no pictures"`` when no record has one (also used by ``ges synth --pictures``)."""
    from ges_core.render import contact_sheet

    shown = [r for r in records if r.picture is not None and Path(r.picture).is_file()]
    if not shown:
        return "no pictures"
    labels = [f"{r.hand[:2]} {r.object_id.split('/', 1)[-1]}" for r in shown]
    colors = [(40, 170, 60) if r.success else (210, 50, 40) for r in shown]
    return contact_sheet([r.picture for r in shown], path, columns=8, labels=labels, frame_colors=colors)
