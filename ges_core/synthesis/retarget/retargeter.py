"""Grasp retargeting (Stage 1, step 2): five contacts -> wrist pose and joint angles of one hand.

For each :class:`~ges_core.contact.ContactSet` (object frame):

1. topology descriptors ``(F, n_palm, d_palm, u_palm)`` and the wrist-link pose from them, the
   paper's constant roll/pitch coupling and the wrist origin (:mod:`.wrist`);
2. the contacts in the hand's base-link frame, then vector retargeting of the finger joints
   (:mod:`.solver`), batched over all contact sets given at once;
3. the base-link pose in the object frame: ``T_obj_base = T_obj_wrist inv(T_base_wrist(q_open))``.
   The wrist link may differ from the base (Shadow: base = forearm, wrist = palm, with WRJ1/WRJ0
   between them); joints of no finger stay at the open pose, so that transform is fixed.

Equations and readings: ``docs/synthesis/retargeting.md``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
import torch
from pydantic import Field

from ges_core.config import ConfigModel
from ges_core.contact import FINGER_SLOTS, ContactSet
from ges_core.errors import SynthesisError
from ges_core.hand import HandModel
from ges_core.kinematics import HandKinematics
from ges_core.synthesis.physics.pregrasp import THUMB_KEEP, open_joint_mask
from ges_core.synthesis.physics.table_clearance import finger_points
from ges_core.synthesis.retarget.search import (
    ObjectCloud,
    WristSearchConfig,
    candidate_offsets,
    candidate_wrists,
    distinct_ranking,
    object_penalty,
    table_penalty,
)
from ges_core.synthesis.retarget.solver import VectorRetargetConfig, VectorRetargeter
from ges_core.synthesis.retarget.wrist import (
    HandFrame,
    TopologyDescriptors,
    contact_problems,
    hand_frame,
    topology_descriptors,
    wrist_poses,
)
from ges_core.synthesis.types import Grasp
from ges_core.transforms import matrix_to_pose

__all__ = [
    "GraspRetargeter",
    "RetargetConfig",
    "raise_contacts",
    "retarget_contacts",
]


class RetargetConfig(ConfigModel):
    """Settings of grasp retargeting."""

    roll_deg: float = Field(10.0, description="pronation about the grasp axis, degrees (paper: 10)")
    pitch_deg: float = Field(20.0, description="fingers tilted toward the object about the lateral axis, degrees (20)")
    palm_distance: float = Field(
        0.75, ge=0, description="O_palm = O_center - palm_distance * l_p * n_palm (paper: 3/4), in units of l_p"
    )
    y_d: float = Field(
        0.0, description="metres along the hand's finger direction from the placed knuckle centre (paper's y_d)"
    )
    # Table clearance. Contacts come from slices at 10-35 mm on the demo objects; a fingertip whose pad sits
    # that low presses the table with its lower side (Allegro: 12 mm tip hemisphere). Measured on the 20
    # demo objects (SAPIEN; docs/synthesis/retargeting.md) for 0 / 20 / 25 / 30 mm: refinement ok Allegro
    # 7 / 11 / 11 / 9 of 19, Shadow 10 / 15 / 16 / - of 19; validated Allegro 5 / 6 / 8 / 5. 25 mm is the best
    # of those for both hands; 0 turns it off.
    min_contact_height: float = Field(
        0.025, ge=0, description="metres: a contact lower than this above the table (z = 0) is raised to it first"
    )
    low_raise_height: float = Field(
        0.015,
        ge=0,
        description="metres: min_contact_height of the Stage 1 pipeline's low_raise pass (SynthesisConfig.low_raise); "
        "where it is not below min_contact_height the pass has nothing to try",
    )
    init_closure: float = Field(
        0.0, ge=0, le=1, description="start of the joint solve: this fraction of the way open -> closed_pose()"
    )
    max_residual: float = Field(
        0.01,
        gt=0,
        description="metres: mean fingertip-to-aim distance (a contact, or the mean of the contacts one finger "
        "serves) up to which meta['reached'] is True",
    )
    solver: VectorRetargetConfig = Field(default_factory=VectorRetargetConfig)
    wrist_search: WristSearchConfig = Field(default_factory=WristSearchConfig)


class GraspRetargeter:
    """Retargets contact sets to grasps of one hand; build once, call many times.

    hand: the hand; config: settings; kinematics: an already built HandKinematics of ``hand``;
    thumb_keep: the opened hand's kept thumb joints (``SynthesisConfig.thumb_keep``), whose table clearance the
    wrist search checks too.
    """

    def __init__(
        self,
        hand: HandModel,
        config: RetargetConfig | None = None,
        *,
        kinematics: HandKinematics | None = None,
        thumb_keep: int = THUMB_KEEP,
    ) -> None:
        self.hand, self.config = hand, config or RetargetConfig()
        self.kinematics = kinematics or HandKinematics.from_hand(hand)
        self.solver = VectorRetargeter(hand, self.config.solver, kinematics=self.kinematics)
        d = hand.description
        self.q_init = d.closed_pose(self.config.init_closure)
        """(K,) start of the joint solve; its non-finger joints (Shadow's wrist) define T_base_wrist."""
        q_open = torch.as_tensor(self.q_init)[None]
        self.base_to_wrist = self.kinematics.link_poses(q_open, [d.wrist.link])[0, 0].numpy()
        """(4, 4) wrist-link pose in the base-link frame at ``q_init``."""
        self.frame: HandFrame = hand_frame(d, self._wrist_points(q_open))
        self.search_offsets = candidate_offsets(self.config.wrist_search)
        """(M, 6) wrist placements tried per grasp (row 0: the paper's), see :mod:`.search`."""
        # The opened hand (pre-grasp, start of refinement) is checked too: the Allegro's opened thumb reached
        # 2 cm lower than at the grasp and pressed the table at 80-200 N on flat objects (jenga, random_urdfs/000).
        self._opened = torch.as_tensor(open_joint_mask(d, thumb_keep))
        """(K,) joints the pre-grasp and refinement open (their table clearance is checked too)."""
        # the collision points refinement's start and the pre-grasp keep off the table too (engine_urdf: what the
        # simulators load: absolute mesh paths, converted meshes, prepared parts)
        self.hull = finger_points(hand)
        """The collision points (per link, link frames) the wrist search keeps off the table."""
        tips = {f.tip_link for f in d.fingers}
        self._body_point = np.array([link not in tips for link in self.hull.links])[self.hull.link_of]
        """(N,) True for collision points of links other than fingertips (kept out of the object)."""

    def retarget(self, contacts: ContactSet) -> Grasp:
        """One grasp; raises SynthesisError(reason="degenerate_contacts") for contacts spanning no plane."""
        result = self.retarget_many([contacts])[0]
        if isinstance(result, SynthesisError):
            raise result
        return result

    def retarget_many(
        self, contacts: Sequence[ContactSet], clouds: Sequence[ObjectCloud | None] | None = None
    ) -> list[Grasp | SynthesisError]:
        """One grasp per contact set, solved as one batch; degenerate sets come back as SynthesisError.

        clouds: per contact set, the object's surface samples (object frame) or None; given, the wrist
        search also keeps the hand's links other than the fingertips out of the object."""
        return [r if isinstance(r, SynthesisError) else r[0] for r in self.retarget_ranked(contacts, clouds)]

    def retarget_ranked(
        self, contacts: Sequence[ContactSet], clouds: Sequence[ObjectCloud | None] | None = None, keep: int = 1
    ) -> list[list[Grasp] | SynthesisError]:
        """Per contact set, up to ``keep`` grasps at distinct wrist placements, best first (one batch).

        The first grasp is :meth:`retarget_many`'s. The others are the next-best placements of the
        wrist search that differ from every one kept before by at least ``wrist_search.distinct_deg``
        of rotation or ``wrist_search.distinct_distance`` of position and that reach their contacts
        (``meta["reached"]``): the pipeline's later attempts (``SynthesisConfig.attempts``). Degenerate
        contact sets come back as SynthesisError.
        """
        if keep < 1:
            raise ValueError(f"retarget_ranked: keep must be at least 1, got {keep}")
        start = time.perf_counter()
        pos = self._positions(contacts)
        problems = contact_problems(pos)
        good = [i for i, p in enumerate(problems) if p is None]
        out: list = [None if p is None else _degenerate(i, p) for i, p in enumerate(problems)]
        if good:
            topo = topology_descriptors(pos[good], self.frame.chirality)
            normals = np.stack([contacts[i].normals for i in good])
            kept = [clouds[i] if clouds is not None else None for i in good]
            ranked = self._solve(topo, normals, kept, keep)
            seconds = (time.perf_counter() - start) / len(contacts)
            for j, i in enumerate(good):
                out[i] = [self._grasp(*solution, topo, j, seconds) for solution in ranked[j]]
        return out

    def wrist_link_poses(self, topo: TopologyDescriptors) -> np.ndarray:
        """(B, 4, 4) wrist-link poses in the object frame for ``topo``."""
        c = self.config
        return wrist_poses(
            topo, self.frame, roll_deg=c.roll_deg, pitch_deg=c.pitch_deg, palm_distance=c.palm_distance, y_d=c.y_d
        )

    # -- internals ------------------------------------------------------------------------
    def _solve(
        self, topo: TopologyDescriptors, normals: np.ndarray, clouds: Sequence[ObjectCloud | None] = (), keep: int = 1
    ) -> list[list[tuple[np.ndarray, np.ndarray, float, np.ndarray]]]:
        """Per grasp, up to ``keep`` solutions (base pose (4, 4), joints (K,), residual, per-slot errors (5,)).

        normals: (B, 5, 3) outward contact normals, object frame (the solver's pad term). Every
        candidate wrist placement (:mod:`.search`) of every grasp is solved in one batch; each
        grasp's solutions are its candidates in order of objective (the paper's placement first on
        ties), each at a placement distinct from the ones before (:func:`distinct_ranking`)."""
        c = self.config
        wrists = candidate_wrists(
            topo,
            self.frame,
            self.search_offsets,
            roll_deg=c.roll_deg,
            pitch_deg=c.pitch_deg,
            palm_distance=c.palm_distance,
            y_d=c.y_d,
        )
        b, m = wrists.shape[:2]
        base = wrists.reshape(b * m, 4, 4) @ np.linalg.inv(self.base_to_wrist)
        rot, trans = base[:, :3, :3], base[:, :3, 3]
        contacts, normals = np.repeat(topo.contacts, m, axis=0), np.repeat(normals, m, axis=0)
        targets = torch.as_tensor(np.einsum("bji,bsj->bsi", rot, contacts - trans[:, None]))  # R^T (p - t)
        normals_base = torch.as_tensor(np.einsum("bji,bsj->bsi", rot, normals))
        q0 = torch.as_tensor(self.q_init).expand(b * m, -1)
        q, residual = self.solver.solve(targets, q0, normals=normals_base)
        # the open-pose hand: refinement's start with refine.start=open_pose (the default, retract, backs each finger
        # off its grasp instead; checking that hand here measured no better, docs/synthesis/refine_validate.md)
        q_open = torch.where(self._opened, self.solver.open_pose, q)
        at_grasp = self._hand_points(q, base)
        fit = self.solver.finger_objective(q, targets, normals_base)
        fit[:, self.solver.thumb_finger] *= c.wrist_search.thumb_weight
        cost = (
            fit.sum(-1).numpy()
            + table_penalty(at_grasp[..., 2], c.wrist_search)
            + table_penalty(self._hand_points(q_open, base)[..., 2], c.wrist_search)
            + self._object_penalty(at_grasp, clouds, m)
        ).reshape(b, m)
        reached = (residual <= c.max_residual).numpy().reshape(b, m)
        picks = [
            [g * m + k for k in distinct_ranking(cost[g], wrists[g], reached[g], keep, c.wrist_search)]
            for g in range(b)
        ]
        rows = torch.as_tensor([r for p in picks for r in p])
        tip_err = (self.solver.fingertips(q[rows]) - targets[rows]).norm(dim=-1).numpy()
        err_of = dict(zip(rows.tolist(), tip_err, strict=True))
        q_np, residual_np = q.numpy(), residual.numpy()
        return [[(base[r], q_np[r], float(residual_np[r]), err_of[r]) for r in p] for p in picks]

    def _hand_points(self, q: torch.Tensor, base: np.ndarray) -> np.ndarray:
        """(B, N, 3) the hand's collision points (:mod:`ges_core.collision_points`), object frame, for q (B, K)."""
        points = self.hull.local(self.kinematics, q)  # (B, N, 3), base frame
        return np.einsum("bij,bnj->bni", base[:, :3, :3], points) + base[:, None, :3, 3]

    def _object_penalty(self, points: np.ndarray, clouds: Sequence[ObjectCloud | None], m: int) -> np.ndarray:
        """(B * m,) penalty of non-fingertip hand points inside the object, candidates of grasp b at rows b*m..."""
        out = np.zeros(len(points))
        c = self.config.wrist_search
        for b, cloud in enumerate(clouds):
            if cloud is not None and c.object_weight > 0:
                rows = slice(b * m, (b + 1) * m)
                out[rows] = object_penalty(points[rows][:, self._body_point], cloud, c)
        return out

    def _grasp(
        self,
        base: np.ndarray,
        q: np.ndarray,
        residual: float,
        tip_err: np.ndarray,
        topo: TopologyDescriptors,
        j: int,
        seconds: float,
    ) -> Grasp:
        meta = {
            "residual": float(residual),
            "tip_errors": dict(zip(FINGER_SLOTS, map(float, tip_err), strict=True)),
            "reached": bool(residual <= self.config.max_residual),
            "aimed_contacts": topo.contacts[j].tolist(),  # (5, 3) after raise_contacts
            "palm_normal": topo.palm_normal[j].tolist(),
            "grasp_axis": topo.grasp_axis[j].tolist(),
            "lateral_axis": topo.lateral_axis[j].tolist(),
            "seconds": seconds,
        }
        return Grasp(hand=self.hand.name, wrist_pose=matrix_to_pose(base), q=q, meta=meta)

    def _positions(self, contacts: Sequence[ContactSet]) -> np.ndarray:
        if isinstance(contacts, ContactSet) or not all(isinstance(c, ContactSet) for c in contacts):
            raise TypeError("retarget_many takes a sequence of ContactSet objects (object frame, five slots)")
        if len(contacts) == 0:
            raise ValueError("retarget_many got no contact sets")
        return raise_contacts(np.stack([c.positions for c in contacts]), self.config.min_contact_height)

    def _wrist_points(self, q: torch.Tensor) -> dict[str, np.ndarray]:
        """Open-pose knuckles and middle/little-slot fingertips in the wrist-link frame."""
        d = self.hand.description
        inv = np.linalg.inv(self.base_to_wrist)
        tips = self.solver.fingertips(q)[0].numpy() @ inv[:3, :3].T + inv[:3, 3]
        knuckles = []
        for finger in {d.finger_for_slot(s).name: d.finger_for_slot(s) for s in FINGER_SLOTS[1:]}.values():
            if finger.keypoint_links:
                knuckles.append(self.kinematics.points(q, [finger.keypoint_links[0]])[0, 0].numpy())
            else:  # no declared keypoints: one finger length back from the tip
                tip = self.kinematics.points(q, [finger.tip_link], torch.tensor([finger.tip_offset]))[0, 0].numpy()
                knuckles.append(tip - self.base_to_wrist[:3, :3] @ (d.middle_finger_length * self._finger_dir()))
        knuckles = np.asarray(knuckles) @ inv[:3, :3].T + inv[:3, 3]
        middle, little = FINGER_SLOTS.index("middle"), FINGER_SLOTS.index("little")
        return {"knuckles": knuckles, "middle_tip": tips[middle], "little_tip": tips[little]}

    def _finger_dir(self) -> np.ndarray:
        f = np.asarray(self.hand.description.wrist.finger_direction, dtype=np.float64)
        return f / np.linalg.norm(f)


def retarget_contacts(hand: HandModel, contacts: ContactSet, config: RetargetConfig | None = None) -> Grasp:
    """One-off convenience: build a :class:`GraspRetargeter` and retarget one contact set."""
    return GraspRetargeter(hand, config).retarget(contacts)


def raise_contacts(positions: np.ndarray, min_height: float) -> np.ndarray:
    """(B, 5, 3) copy of ``positions`` (object frame, table at z = 0) with every z below ``min_height`` set to it.

    A contact on a side wall moves up the wall, so a fingertip aimed at it keeps its pad off the table.
    """
    out = np.array(positions, dtype=np.float64, copy=True)
    out[..., 2] = np.maximum(out[..., 2], min_height)
    return out


def _degenerate(index: int, problem: str) -> SynthesisError:
    return SynthesisError(
        f"grasp retargeting: contact set {index}: {problem}; the contact generator must give five contacts "
        "spanning a plane",
        reason="degenerate_contacts",
    )
