"""The viser page: the scene of one record at a time, and a side panel to browse and read its figures.

Panel: split, object and hand dropdowns (an object lists the hands that have a record of it), previous / next
object, a button that switches to the other hand on the same object (kept camera, kept contacts view), checkboxes
for each part of the scene, and the record's figures (:mod:`.figures`). Switching records moves the meshes the
new scene shares with the old one (same hand, same object) instead of sending their vertices again.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Any

from ges_core.viewer.data import ALL, ViewerData
from ges_core.viewer.figures import record_markdown

if TYPE_CHECKING:
    from ges_core.viewer.scene import MeshItem, Scene, ViewerConfig

__all__ = ["PARTS", "GraspViewer"]

PARTS = {
    "object": ("/object", "/table"),
    "contacts and normals": ("/contacts/", "/normals"),
    "hand at grasp": ("/grasp/",),
    "hand at pre-grasp": ("/pregrasp/",),
}
"""Checkbox label -> scene-name prefixes it shows or hides."""
_CAMERA_DISTANCE = 2.8
"""Camera distance in scene radii: with viser's default 75° vertical field of view the scene's sphere spans
2 asin(1 / 2.8) = 42°, a bit over half the view's height (room for the hand around the fingers)."""


class GraspViewer:
    """One viser server showing the records of ``data``; ``initial``: the (object, hand) shown first.

    :attr:`shown` is the (object, hand) on screen, :attr:`scene` its :class:`~ges_core.viewer.scene.Scene`;
    :meth:`show` switches (the GUI calls it; so can a script). Thread-safe: GUI callbacks run on viser's threads.
    """

    def __init__(
        self,
        data: ViewerData,
        server: Any,
        *,
        config: ViewerConfig | None = None,
        initial: tuple[str, str] | None = None,
    ) -> None:
        self.data, self.server, self.config = data, server, config
        self.url = f"http://{_reachable(server.get_host())}:{server.get_port()}"
        """Where the page is served."""
        self.shown: tuple[str, str] | None = None
        self.scene: Scene | None = None
        self._handles: dict[str, tuple[Any, str]] = {}
        self._lock = threading.RLock()
        self._syncing = False  # set while the code itself changes dropdowns, so their callbacks do nothing
        server.scene.set_up_direction("+z")
        self._build_gui()
        object_id, hand = initial or (data.objects()[0], data.hands(data.objects()[0])[0])
        self.show(object_id, hand)

    # -- GUI ------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        gui = self.server.gui
        gui.add_markdown(f"**GES-UniGrasp viewer** · {self.data.root} · {len(self.data)} records")
        with gui.add_folder("Browse"):
            self._split = gui.add_dropdown("split", [ALL, *self.data.splits()], initial_value=ALL)
            self._object = gui.add_dropdown("object", self.data.objects())
            self._hand = gui.add_dropdown("hand", self.data.hands())
            previous, following = gui.add_button("◀ previous object"), gui.add_button("next object ▶")
            self._other = gui.add_button("other hand, same contacts")
            self._position = gui.add_markdown("")
        with gui.add_folder("Show"):
            self._visible = {label: gui.add_checkbox(label, initial_value=True) for label in PARTS}
        self._figures = gui.add_markdown("")
        self._notes = gui.add_markdown("")
        self._split.on_update(lambda _: self._on_split())
        self._object.on_update(lambda _: self._on_pick(self._object.value, self._hand.value))
        self._hand.on_update(lambda _: self._on_pick(self._object.value, self._hand.value))
        previous.on_click(lambda _: self.step(-1))
        following.on_click(lambda _: self.step(+1))
        self._other.on_click(lambda _: self.other_hand())
        for checkbox in self._visible.values():
            checkbox.on_update(lambda _: self._apply_visibility())

    def _on_split(self) -> None:
        if self._syncing:
            return
        objects = self.data.objects(self._split.value)
        current = self.shown[0] if self.shown else None
        self.show(current if current in objects else objects[0], self._hand.value)

    def _on_pick(self, object_id: str, hand: str) -> None:
        if not self._syncing and (object_id, hand) != self.shown:
            self.show(object_id, hand)

    def step(self, delta: int) -> None:
        """Show the next (``delta`` = 1) or previous (-1) object of the current split, keeping the hand if it can."""
        objects = self.data.objects(self._split.value)
        i = objects.index(self.shown[0]) if self.shown and self.shown[0] in objects else -delta
        self.show(objects[(i + delta) % len(objects)], self.shown[1] if self.shown else self.data.hands()[0])

    def other_hand(self) -> None:
        """Switch to the next hand with a record of the shown object (the object, its contacts and camera stay)."""
        if self.shown is None:
            return
        hands = self.data.hands(self.shown[0])
        self.show(self.shown[0], hands[(hands.index(self.shown[1]) + 1) % len(hands)])

    # -- showing a record -----------------------------------------------------------------
    def show(self, object_id: str, hand: str) -> Scene:
        """Draw (object, hand): the hand is kept when the object has a record of it, else its first hand is shown."""
        with self._lock:
            hands = self.data.hands(object_id)
            if not hands:
                raise KeyError(f"dataset {self.data.root} holds no record of object '{object_id}'")
            hand = hand if hand in hands else hands[0]
            scene = self.data.scene(object_id, hand, self.config)
            new_object = self.shown is None or self.shown[0] != object_id
            with self.server.atomic():
                self._send(scene)
            self.shown, self.scene = (object_id, hand), scene
            self._sync_gui(hands)
            if new_object:
                self._frame_camera(scene)
            return scene

    def _send(self, scene: Scene) -> None:
        """Add, move or remove scene nodes so the page shows ``scene``."""
        wanted = {m.name for m in scene.meshes} | {line.name for line in scene.lines}
        for name in [n for n in self._handles if n not in wanted]:
            self._handles.pop(name)[0].remove()
        for item in scene.meshes:
            self._send_mesh(item)
        for line in scene.lines:
            if line.name in self._handles:
                self._handles.pop(line.name)[0].remove()
            handle = self.server.scene.add_line_segments(line.name, line.points, line.colors, thickness=0.001)
            self._handles[line.name] = (handle, "")
        self._apply_visibility()

    def _send_mesh(self, item: MeshItem) -> None:
        held = self._handles.get(item.name)
        if held is not None and held[1] == item.geometry and item.geometry:
            handle = held[0]
            handle.position, handle.wxyz = item.position, item.wxyz
            handle.color, handle.opacity = item.color, item.opacity
            return
        if held is not None:
            held[0].remove()
        handle = self.server.scene.add_mesh_simple(
            item.name, item.vertices, item.faces, color=item.color, opacity=item.opacity,
            position=item.position, wxyz=item.wxyz, side="double",
        )  # fmt: skip
        self._handles[item.name] = (handle, item.geometry)

    def set_visible(self, label: str, on: bool) -> None:
        """Show or hide one part of the scene, as its checkbox does (labels: ``object``, ``contacts and normals``,
        ``hand at grasp``, ``hand at pre-grasp``)."""
        with self._lock:
            self._visible[label].value = on
            self._apply_visibility()

    def _apply_visibility(self) -> None:
        for label, prefixes in PARTS.items():
            on = bool(self._visible[label].value)
            for name, (handle, _) in self._handles.items():
                if name.startswith(prefixes):
                    handle.visible = on

    def _sync_gui(self, hands: list[str]) -> None:
        """Dropdowns, position line, figures and notes of the shown record (without re-triggering show)."""
        object_id, hand = self.shown
        objects = self.data.objects(self._split.value)
        self._syncing = True
        try:
            if object_id not in objects:  # picked from another split (the step buttons keep to it): widen to all
                self._split.value, objects = ALL, self.data.objects()
            self._object.options, self._object.value = objects, object_id
            self._hand.options, self._hand.value = hands, hand
        finally:
            self._syncing = False
        self._other.disabled = len(hands) < 2
        others = [self._mate(object_id, hand, h) for h in hands if h != hand]
        mate = f" · also: {'; '.join(others)}" if others else " · no other hand has a record of it"
        self._position.content = f"object {objects.index(object_id) + 1} of {len(objects)}{mate}"
        self._figures.content = record_markdown(self.data.record(object_id, hand))
        self._notes.content = "\n\n".join(f"⚠ {n}" for n in self.scene.notes)

    def _mate(self, object_id: str, hand: str, other: str) -> str:
        """``other`` and how its contacts on the object compare with ``hand``'s."""
        gap = self.data.contacts_gap(object_id, hand, other)
        if gap is None:
            return f"{other} (contacts of one of the two missing)"
        # 1e-9 m: equal up to float rounding (a retargeted record copies its source's contacts exactly)
        return f"{other} (same contacts)" if gap < 1e-9 else f"{other} (contacts up to {1000 * gap:.1f} mm apart)"

    def _frame_camera(self, scene: Scene) -> None:
        """Aim the initial camera (and every connected client's) at the scene's centre."""
        position = scene.center + _CAMERA_DISTANCE * scene.radius * scene.view_direction
        cam = self.server.initial_camera
        cam.look_at, cam.position, cam.up = tuple(scene.center), tuple(position), (0.0, 0.0, 1.0)
        for client in self.server.get_clients().values():
            client.camera.look_at, client.camera.position = tuple(scene.center), tuple(position)


def _reachable(host: str) -> str:
    """A host to put in a URL: the loopback address for a server listening on every interface."""
    return "127.0.0.1" if host in ("", "0.0.0.0", "::") else host
