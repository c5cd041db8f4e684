"""Grasp pictures drawn headless with PyBullet's CPU TinyRenderer: :class:`PybulletRenderer`.

The scene of :mod:`ges_core.render.base`: the object's surface mesh, the contacts as coloured spheres
with a short stick along each outward normal, and the hand at its grasp pose, drawn half-transparent.
Contact markers are always drawn, at half strength where the object or a finger hides them (the thumb
often sits on the far side). That takes up to three renders: the full scene, the scene without the hand
(blended in on the hand's pixels) and the markers alone. The camera looks at the object from a 3/4 view,
from the side away from the hand's base link when a hand is drawn.

PyBullet is imported when a renderer is built (the plugin's ``SimSpec.renderer``), never at import. Hands
without visual geometry (the converted Shadow URDF) are drawn with their collision shapes, which PyBullet
uses as visuals when a link has none.
"""

from __future__ import annotations

import contextlib
import functools
import math
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np

from ges_core.contact import FINGER_SLOTS, ContactSet
from ges_core.errors import AssetError, BackendUnavailable, UnknownNameError
from ges_core.hand import HandModel
from ges_core.objects.asset import ObjectAsset
from ges_core.render.base import HAND_COLOR, OBJECT_COLOR, SLOT_COLORS, TABLE_COLOR, RenderConfig, Renderer
from ges_core.transforms import quat_from_z_axis, wxyz_to_xyzw
from ges_plugins.sims.pybullet.hand_urdf import pybullet_hand_urdf

__all__ = ["MIN_RADIUS", "PybulletRenderer"]

MIN_RADIUS = 0.03
"""Metres: the camera frames at least a 6 cm sphere, so a small object does not fill the picture."""
_HIDDEN = (0.0, 0.0, -100.0)
"""Where unused hands wait, far outside every camera frustum (a body cannot be made invisible)."""


@functools.lru_cache(maxsize=256)
def _mesh_bounds(path: str) -> np.ndarray:
    """(2, 3) min and max corner of a mesh file's vertices, metres; AssetError if unreadable or empty."""
    import trimesh

    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise AssetError(f"cannot read mesh {path}: {exc}") from exc
    if len(getattr(mesh, "vertices", ())) == 0:
        raise AssetError(f"mesh {path} has no vertices")
    return np.asarray(mesh.bounds, dtype=np.float64)


class PybulletRenderer(Renderer):
    """A private PyBullet DIRECT client that draws grasp pictures; reuse one for many pictures.

    Hands are loaded once per hand name and kept; objects and markers are rebuilt per picture.
    """

    def __init__(self, config: RenderConfig | None = None) -> None:
        super().__init__(config)
        try:
            from .engine import p, silenced
        except ImportError as exc:
            raise BackendUnavailable("grasp pictures need PyBullet: pip install 'ges-unigrasp[pybullet]'") from exc
        self._p = p
        with silenced(1):  # PyBullet prints "argv[0]=" for every client
            self._cid = p.connect(p.DIRECT)
        self._hands: dict[str, tuple[int, dict[str, int]]] = {}
        self._shapes: dict[tuple, int] = {}
        self._temporary: list[int] = []
        self._table = self._body(self._box_shape((0.6, 0.6, 0.002), TABLE_COLOR), (0.0, 0.0, -0.002))

    def close(self) -> None:
        """Disconnect the PyBullet client (idempotent)."""
        if self._cid is not None:
            self._p.disconnect(physicsClientId=self._cid)
            self._cid = None

    def _render(
        self,
        obj: ObjectAsset | None,
        contacts: ContactSet | None,
        hand: HandModel | None,
        wrist_pose: np.ndarray | None,
        joints: Mapping[str, float],
    ) -> np.ndarray:
        self._clear()
        focus, around = [], []
        obj_body = markers = hand_body = None
        if obj is not None:
            obj_body, corners = self._add_object(obj)
            focus.append(corners)
        if contacts is not None:
            markers, tips = self._add_contacts(contacts)
            focus.append(tips)
        self._hide_hands(except_name=hand.name if hand is not None else None)
        if hand is not None:
            hand_body = self._pose_hand(hand, wrist_pose, joints)
            around.append(self._finger_points(hand, hand_body))
        focus = focus or around or [np.zeros((1, 3))]
        base = None if wrist_pose is None else wrist_pose[:3]
        view, proj = self._camera(np.concatenate(focus), np.concatenate(focus + around), base)
        return self._shoot(view, proj, obj_body, markers, hand_body)

    def link_positions(self, hand: HandModel, links: Sequence[str]) -> np.ndarray:
        """(N, 3) object-frame origins of ``links`` of ``hand`` as last drawn, metres (for checks)."""
        p, body = self._p, self._load_hand(hand)[0]
        index = {self._link_name(body, j): j for j in range(p.getNumJoints(body, physicsClientId=self._cid))}
        base = p.getBodyInfo(body, physicsClientId=self._cid)[0].decode()
        out = []
        for name in links:
            if name == base:
                out.append(self._base_link_frame(body)[0])
            elif name in index:
                out.append(
                    p.getLinkState(body, index[name], computeForwardKinematics=True, physicsClientId=self._cid)[4]
                )
            else:
                raise UnknownNameError("link", name, [base, *index], where=f" in the URDF of hand '{hand.name}'")
        return np.asarray(out, dtype=np.float64)

    # --- scene building -------------------------------------------------------------------------

    def _clear(self) -> None:
        for body in self._temporary:
            self._p.removeBody(body, physicsClientId=self._cid)
        self._temporary = []

    def _hide_hands(self, except_name: str | None) -> None:
        for name, (body, _) in self._hands.items():
            if name != except_name:
                self._p.resetBasePositionAndOrientation(body, _HIDDEN, (0, 0, 0, 1), physicsClientId=self._cid)

    @contextlib.contextmanager
    def _hidden(self, bodies: Sequence[int | None]) -> Iterator[None]:
        """Move ``bodies`` out of sight for the duration of the block, then put them back."""
        bodies = [b for b in bodies if b is not None]
        saved = [self._p.getBasePositionAndOrientation(b, physicsClientId=self._cid) for b in bodies]
        for b in bodies:
            self._p.resetBasePositionAndOrientation(b, _HIDDEN, (0, 0, 0, 1), physicsClientId=self._cid)
        try:
            yield
        finally:
            for b, (pos, orn) in zip(bodies, saved, strict=True):
                self._p.resetBasePositionAndOrientation(b, pos, orn, physicsClientId=self._cid)

    def _body(self, shape: int, position: Sequence[float], orientation: Sequence[float] = (0, 0, 0, 1)) -> int:
        return self._p.createMultiBody(
            0, -1, shape, basePosition=list(position), baseOrientation=list(orientation), physicsClientId=self._cid
        )

    def _temp_body(self, shape: int, position: Sequence[float], orientation: Sequence[float] = (0, 0, 0, 1)) -> int:
        body = self._body(shape, position, orientation)
        self._temporary.append(body)
        return body

    def _box_shape(self, half: tuple[float, float, float], color: tuple[float, ...]) -> int:
        p = self._p
        return p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=[*color, 1], physicsClientId=self._cid)

    def _shape(self, key: tuple, **kwargs) -> int:
        """A cached visual shape (PyBullet never frees one, so equal shapes are made once)."""
        if key not in self._shapes:
            shape = self._p.createVisualShape(physicsClientId=self._cid, **kwargs)
            if shape < 0:
                raise AssetError(f"PyBullet could not create the visual shape {key}")
            self._shapes[key] = shape
        return self._shapes[key]

    def _add_object(self, obj: ObjectAsset) -> tuple[int, np.ndarray]:
        """The object's body at the origin and its (8, 3) bounding-box corners."""
        path = str(Path(obj.mesh_path))
        try:  # read first: PyBullet only prints a warning for a missing file and draws nothing
            lo, hi = _mesh_bounds(path)
        except AssetError as exc:
            raise AssetError(f"object '{obj.object_id}': cannot draw it: {exc}") from exc
        shape = self._shape(("mesh", path), shapeType=self._p.GEOM_MESH, fileName=path, rgbaColor=[*OBJECT_COLOR, 1])
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        return self._temp_body(shape, (0.0, 0.0, 0.0)), corners

    def _add_contacts(self, contacts: ContactSet) -> tuple[list[int], np.ndarray]:
        """Marker bodies (a ball and a normal stick per slot) and the (5, 3) stick ends."""
        p, cfg, bodies = self._p, self.config, []
        for slot, pos, nrm in zip(FINGER_SLOTS, contacts.positions, contacts.normals, strict=True):
            color = [*SLOT_COLORS[slot], 1]
            ball = self._shape(("ball", slot), shapeType=p.GEOM_SPHERE, radius=cfg.contact_radius, rgbaColor=color)
            stick = self._shape(
                ("stick", slot), shapeType=p.GEOM_CYLINDER, radius=0.0012, length=cfg.normal_length, rgbaColor=color
            )
            bodies.append(self._temp_body(ball, pos))
            along_normal = wxyz_to_xyzw(quat_from_z_axis(nrm)).tolist()
            bodies.append(self._temp_body(stick, pos + nrm * cfg.normal_length / 2, along_normal))
        return bodies, contacts.positions + contacts.normals * cfg.normal_length

    def _load_hand(self, hand: HandModel) -> tuple[int, dict[str, int]]:
        if hand.name not in self._hands:
            p = self._p
            # The URDF the PyBullet backend loads (meshes it can read: a .glb hand's OBJ copies), hung from a
            # massless link at the hand's root frame; the hand's own file would fail on .glb meshes.
            urdf = pybullet_hand_urdf(hand.urdf_text(), hand.name, floating=False, base_dir=hand.urdf_path().parent)
            body = p.loadURDF(str(urdf), useFixedBase=True, physicsClientId=self._cid)
            n = p.getNumJoints(body, physicsClientId=self._cid)
            joints = {p.getJointInfo(body, j, physicsClientId=self._cid)[1].decode(): j for j in range(n)}
            for link in range(-1, n):
                p.changeVisualShape(body, link, rgbaColor=[*HAND_COLOR, 1], physicsClientId=self._cid)
            self._hands[hand.name] = (body, joints)
        return self._hands[hand.name]

    def _pose_hand(self, hand: HandModel, wrist_pose: np.ndarray, joints: Mapping[str, float]) -> int:
        body, index = self._load_hand(hand)
        for name, value in joints.items():
            if name not in index:
                where = f" in the URDF of hand '{hand.name}' ({hand.urdf_path()})"
                raise UnknownNameError("joint", name, index, where=where)
            self._p.resetJointState(body, index[name], float(value), physicsClientId=self._cid)
        # PyBullet places a base by its inertial frame, not its link frame: compose the two.
        inertial_pos, inertial_orn = self._p.getDynamicsInfo(body, -1, physicsClientId=self._cid)[3:5]
        pos, orn = self._p.multiplyTransforms(
            wrist_pose[:3].tolist(), wxyz_to_xyzw(wrist_pose[3:]).tolist(), inertial_pos, inertial_orn
        )
        self._p.resetBasePositionAndOrientation(body, pos, orn, physicsClientId=self._cid)
        return body

    def _base_link_frame(self, body: int) -> tuple:
        """(position, xyzw) of the base's URDF link frame (PyBullet reports the inertial frame)."""
        com_pos, com_orn = self._p.getBasePositionAndOrientation(body, physicsClientId=self._cid)
        inertial_pos, inertial_orn = self._p.getDynamicsInfo(body, -1, physicsClientId=self._cid)[3:5]
        inv_pos, inv_orn = self._p.invertTransform(inertial_pos, inertial_orn)
        return self._p.multiplyTransforms(com_pos, com_orn, inv_pos, inv_orn)

    def _link_name(self, body: int, joint: int) -> str:
        return self._p.getJointInfo(body, joint, physicsClientId=self._cid)[12].decode()

    def _finger_points(self, hand: HandModel, body: int) -> np.ndarray:
        """(N, 3) origins of the finger links (children of finger joints): what wraps the object."""
        index = self._hands[hand.name][1]
        joints = [index[j] for f in hand.description.fingers for j in f.joints if j in index]
        states = [
            self._p.getLinkState(body, j, computeForwardKinematics=True, physicsClientId=self._cid) for j in joints
        ]
        return np.array([s[4] for s in states]).reshape(-1, 3)

    # --- camera and pixels ----------------------------------------------------------------------

    def _camera(self, focus: np.ndarray, points: np.ndarray, base: np.ndarray | None = None) -> tuple[list, list]:
        """View and projection looking at the centre of ``focus`` (N, 3), far enough to see ``points``;
        ``base`` (3,): the hand's base link position, which the camera looks away from (``away_from_base``)."""
        cfg = self.config
        centre = (focus.min(axis=0) + focus.max(axis=0)) / 2
        radius = max(float(np.linalg.norm(points - centre, axis=1).max()), MIN_RADIUS) * cfg.margin
        distance = radius / math.sin(math.radians(cfg.fov_deg) / 2)
        az, el = math.radians(cfg.azimuth_deg), math.radians(cfg.elevation_deg)
        if base is not None and cfg.away_from_base is not None and np.linalg.norm((base - centre)[:2]) > 0.01:
            az = math.atan2(centre[1] - base[1], centre[0] - base[0]) + math.radians(cfg.away_from_base)
        eye = centre + distance * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        view = self._p.computeViewMatrix(eye.tolist(), centre.tolist(), [0, 0, 1])
        w, h = self.config.size
        proj = self._p.computeProjectionMatrixFOV(cfg.fov_deg, w / h, distance / 20, distance * 4)
        return view, proj

    def _image(self, view: list, proj: list) -> tuple[np.ndarray, np.ndarray]:
        """(H, W, 3) float RGB and (H, W) body-id segmentation of one TinyRenderer frame."""
        w, h = self.config.size
        _, _, rgb, _, seg = self._p.getCameraImage(
            int(w), int(h), view, proj,
            renderer=self._p.ER_TINY_RENDERER,
            lightDirection=[0.4, -0.6, 1.0],
            lightAmbientCoeff=0.55,  # bright enough that faces turned from the light keep their colour
            lightDiffuseCoeff=0.55,
            lightSpecularCoeff=0.05,
            physicsClientId=self._cid,
        )  # fmt: skip
        rgb = np.asarray(rgb, dtype=np.uint8).reshape(h, w, 4)[..., :3].astype(np.float64)
        return rgb, np.asarray(seg).reshape(h, w)

    def _shoot(
        self, view: list, proj: list, obj: int | None, markers: list[int] | None, hand: int | None
    ) -> np.ndarray:
        """Compose the passes: full scene, hand blended over the scene without it, markers on top."""
        full, seg = self._image(view, proj)
        alpha = self.config.hand_opacity
        if hand is not None and alpha < 1.0:
            with self._hidden([hand]):
                behind, _ = self._image(view, proj)
            full = np.where((seg == hand)[..., None], alpha * full + (1 - alpha) * behind, full)
        if markers:
            with self._hidden([hand, obj]):
                alone, seg_alone = self._image(view, proj)
            drawn = np.isin(seg_alone, markers)
            strength = np.where(seg == seg_alone, 1.0, self.config.hidden_contact_opacity)[..., None]
            full = np.where(drawn[..., None], strength * alone + (1 - strength) * full, full)
        return np.clip(np.rint(full), 0, 255).astype(np.uint8)
