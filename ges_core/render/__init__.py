"""Grasp pictures: a PNG per grasp (object, contacts, hand) and a contact sheet per run.

>>> with open_renderer(registry) as renderer:               # one engine client for many pictures
...     render_grasp(hand, obj, contacts, grasp, "pics/mug.png", renderer=renderer)
>>> contact_sheet(["pics/mug.png", "pics/can.png"], "pics/sheet.png", columns=4)

The core holds what is engine-free (:mod:`.base`: :class:`RenderConfig`, :data:`SLOT_COLORS`, the
:class:`Renderer` interface; :mod:`.png`: PNG files and contact sheets). The drawing comes from a
simulator plugin that offers a renderer (``SimSpec.renderer``; the built-in PyBullet plugin draws with
its CPU TinyRenderer, headless): :func:`open_renderer` builds one through the registry. No engine and
no Pillow is imported when ``ges_core`` is.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from ges_core.render.base import HAND_COLOR, OBJECT_COLOR, SLOT_COLORS, RenderConfig, Renderer
from ges_core.render.png import contact_sheet, read_png, write_png

if TYPE_CHECKING:
    from ges_core.contact import ContactSet
    from ges_core.dataset.record import GraspRecord
    from ges_core.hand import HandModel
    from ges_core.objects.asset import ObjectAsset
    from ges_core.registry import Registry
    from ges_core.synthesis.types import Grasp

__all__ = [
    "HAND_COLOR",
    "OBJECT_COLOR",
    "SLOT_COLORS",
    "RenderConfig",
    "Renderer",
    "contact_sheet",
    "open_renderer",
    "read_png",
    "render_grasp",
    "render_record",
    "write_png",
]


def open_renderer(
    registry: Registry | None = None, config: RenderConfig | None = None, *, sim: str | None = None
) -> Renderer:
    """A grasp-picture renderer from the simulator plugin ``sim``, or from the first simulator offering one.

    registry: where to look (default: :func:`ges_core.registry.load_registry`). config: camera, size and
    styling (default :class:`RenderConfig`). BackendUnavailable when no simulator offers a renderer (or
    its engine is missing), UnknownNameError for an unknown ``sim``. Close it when done (or use ``with``).
    """
    if registry is None:
        from ges_core.registry import load_registry

        registry = load_registry()
    return registry.build_renderer(sim, config)


def render_grasp(
    hand: HandModel | None,
    obj: ObjectAsset | None,
    contacts: ContactSet | None,
    grasp: Grasp | None,
    path: str | Path,
    size: tuple[int, int] = (320, 240),
    *,
    renderer: Renderer | None = None,
) -> Path:
    """Draw one grasp and write it as a PNG; returns the path.

    Any of ``contacts`` and ``grasp`` may be None (a failed step): what exists is drawn.
    ``grasp.wrist_pose`` is the hand's base-link pose in the object frame and ``grasp.q`` follows
    ``hand.description.joint_names``. ``renderer`` (reused across pictures) overrides ``size``; without
    one, :func:`open_renderer` builds one for this picture.
    """
    if grasp is not None and hand is None:
        raise ValueError("render_grasp: a grasp needs its hand (got hand=None)")
    joints = dict(zip(hand.description.joint_names, grasp.q, strict=True)) if grasp is not None else None
    wrist = grasp.wrist_pose if grasp is not None else None
    return _render_to(path, size, renderer, obj, contacts, hand if grasp is not None else None, wrist, joints)


def render_record(
    record: GraspRecord,
    hand: HandModel,
    obj: ObjectAsset,
    path: str | Path,
    size: tuple[int, int] = (320, 240),
    *,
    renderer: Renderer | None = None,
) -> Path:
    """Draw a dataset record (its contacts and final grasp, joints matched by the record's names)."""
    grasp = record.grasp
    joints = dict(zip(record.joint_names, grasp.q, strict=True)) if grasp is not None else None
    wrist = grasp.wrist_pose if grasp is not None else None
    return _render_to(path, size, renderer, obj, record.contacts, hand if grasp is not None else None, wrist, joints)


def _render_to(
    path: str | Path,
    size: tuple[int, int],
    renderer: Renderer | None,
    obj: ObjectAsset | None,
    contacts: ContactSet | None,
    hand: HandModel | None,
    wrist_pose,
    joints: Mapping[str, float] | None,
) -> Path:
    if renderer is not None:
        return write_png(path, renderer.render(obj, contacts, hand, wrist_pose, joints))
    with open_renderer(config=RenderConfig(size=tuple(size))) as own:
        return write_png(path, own.render(obj, contacts, hand, wrist_pose, joints))
