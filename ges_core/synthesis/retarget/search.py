"""Local wrist search of grasp retargeting: try wrist poses around the paper's and keep the best fit.

The paper places the wrist once, from the contacts' descriptors and constants (roll 10 deg, pitch 20
deg, ``O_palm`` 3/4 ``l_p`` behind the contacts). For a hand whose thumb cannot oppose from that one
pose (the Shadow thumb reached the thumb contact of a 79 mm box 17 mm off, with its side), the
fingers then push the object sideways and no grasp holds. This module makes the wrist placement a
small search: candidate placements vary the paper's roll, pitch, palm distance and ``y_d`` and add a
yaw about the palm normal through the contacts' centre and a slide along the lateral axis; every
candidate's joints are solved (one batch), and the candidate with the lowest retargeting objective
(fingertip + pad terms, the thumb's weighted ``thumb_weight`` times, plus the table and object penalties) wins.
The paper's own placement is candidate 0 and wins ties. ``enabled=False`` gives the paper's placement.

The candidate set is a fixed, seeded sample of the grid, the same for every grasp, so a grasp's
result never depends on its batch mates.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import torch
from pydantic import Field

from ges_core.config import STORED_WHEN_SET, ConfigModel
from ges_core.synthesis.retarget.wrist import HandFrame, TopologyDescriptors, wrist_poses

__all__ = [
    "ObjectCloud",
    "WristSearchConfig",
    "candidate_offsets",
    "candidate_wrists",
    "distinct_ranking",
    "object_penalty",
    "table_penalty",
]


BOX_MARGIN = 0.01
"""m: the cloud's samples may lie up to about their spacing (a few mm at 512 points on a 5-10 cm object)
inside the true surface's bounding box; hand points further out than this are not measured."""


class WristSearchConfig(ConfigModel):
    """Which wrist placements retargeting tries (offsets from the paper's placement)."""

    enabled: bool = Field(True, description="search around the paper's wrist placement (False: the paper's only)")
    # The grid: on the Shadow hand and the 79 x 98 mm demo box, a thumb pose with its pad facing the
    # contact normal (cosine > 0.99) within 6 mm of the contact exists only at yaw -40 deg and pitch 40-60
    # deg (measured by sampling 100 000 thumb configurations per placement).
    yaw_deg: tuple[float, ...] = Field((-40.0, -20.0, 0.0, 20.0, 40.0), description="turns about n_palm, degrees")
    roll_deg: tuple[float, ...] = Field((-20.0, 0.0, 20.0, 40.0), description="added to the paper's roll, degrees")
    pitch_deg: tuple[float, ...] = Field((-20.0, 0.0, 20.0, 40.0), description="added to the paper's pitch, degrees")
    palm_distance: tuple[float, ...] = Field((-0.3, -0.15, 0.0), description="added to palm_distance, in l_p")
    y_d: tuple[float, ...] = Field((-0.04, -0.02, 0.0), description="added to y_d, metres")
    # Lateral: the hand slid along u_palm (index -> little); negative toward the index side. In a side grasp
    # u_palm points down, and the Allegro (four fingers, ~10 cm palm) reaching contacts 2.5-8.4 cm up a 10 cm
    # can pressed the table with its palm and ring finger in every placement that fitted (13-53 N); slid 1-2
    # cm toward the index side, 2-3 of the 3 best placements of both cans refined without touching it.
    lateral: tuple[float, ...] = Field((-0.02, -0.01), description="slides along u_palm (index -> little), metres")
    lateral_candidates: int = Field(32, ge=0, description="placements tried with a lateral slide, added to candidates")
    candidates: int = Field(
        96, ge=1, description="placements tried per grasp without lateral slide: the paper's plus a seeded sample"
    )
    seed: int = Field(0, description="seed of the grid sample")
    # thumb_weight: the fingers' joints are solved apart (VectorRetargeter), so this only ranks the placements. The
    # thumb opposes all the others, and the Shadow's placements then not lifted had it aimed furthest off its contact.
    # The Shadow sets 8 (placements tried -10 to -13 %, robust unchanged); the Allegro at 8 lost a robust real scan,
    # so the default is 1 (docs/synthesis/retargeting.md, "The thumb's weight").
    thumb_weight: float = Field(
        1.0,
        ge=0,
        description="weight of the thumb's fit term against each other finger's when ranking placements",
        json_schema_extra=STORED_WHEN_SET,  # added after datasets were written: stored only when set
    )
    # Table: points on every link's collision geometry (ges_core.collision_points) should stay 5 mm above
    # the table (closing fingers move a few mm). Without it the search traded table contact for fingertip
    # fit (Allegro refinement table_contact 2 -> 5 of 19 demo objects).
    table_clearance: float = Field(
        0.005, ge=0, description="metres the hand's collision points should stay above z = 0"
    )
    table_weight: float = Field(10.0, ge=0, description="weight of the squared clearance shortfall, per m^2 of fit")
    # Object: the fingertips must touch the object, the other links should not go into it. On
    # procedural/box/001 the Shadow fingers' middle phalanges lay on the box's top edge (0.5-2.2 N each)
    # while no distal touched, so refinement failed (few_contacts). Signed distance to the nearest cloud
    # sample along its normal. Validated grasps on the 20 demo objects (SAPIEN), Allegro / Shadow: off
    # 14 / 6; clearance 0 (penetration only) 14 / 7; 3 mm 12 / 7 (the Allegro's thick distal links sit
    # within 3 mm of the surface next to their tips, so good placements lost to worse fits).
    object_clearance: float = Field(0.0, ge=0, description="metres non-fingertip links should stay out of the object")
    object_weight: float = Field(10.0, ge=0, description="weight of the squared object shortfall, per m^2 of fit")
    cloud_points: int = Field(512, ge=1, description="object surface samples used (first N of the cloud)")
    # Alternatives (GraspRetargeter.retarget_ranked: the pipeline's next attempts when a placement fails
    # refinement or validation, SynthesisConfig.attempts): neighbours
    # on the grid (20 deg apart in yaw/roll/pitch) fail alike, so an alternative must differ from every
    # placement ranked before it by a whole grid step in angle or by 2 cm in position.
    distinct_deg: float = Field(15.0, ge=0, description="rotation between ranked placements, degrees (or distance)")
    distinct_distance: float = Field(0.02, ge=0, description="wrist-origin distance between ranked placements, m")


def candidate_offsets(config: WristSearchConfig) -> np.ndarray:
    """(M, 6) offsets (yaw deg, roll deg, pitch deg, palm distance l_p, y_d m, lateral m); row 0 is all zeros
    (the paper's). Rows 1 .. ``candidates - 1``: a seeded sample of the grid without lateral slide; then
    ``lateral_candidates`` rows sampled from the grid with each nonzero ``lateral`` (another seed), so the
    slid placements add to the others and never displace them."""
    if not config.enabled:
        return np.zeros((1, 6))
    angles = (config.yaw_deg, config.roll_deg, config.pitch_deg, config.palm_distance, config.y_d)
    plain = _sample(np.array(list(itertools.product(*angles, (0.0,)))), config.candidates - 1, config.seed)
    slides = tuple(v for v in config.lateral if v != 0.0)
    slid = _sample(np.array(list(itertools.product(*angles, slides))), config.lateral_candidates, config.seed + 1)
    return np.concatenate([np.zeros((1, 6)), plain, slid])


def _sample(grid: np.ndarray, take: int, seed: int) -> np.ndarray:
    """Up to ``take`` rows of ``grid`` (K, 6) other than all zeros, seeded, in grid order."""
    grid = grid.reshape(-1, 6)  # an empty product comes as (0,)
    grid = grid[np.any(grid != 0.0, axis=1)]
    take = min(take, len(grid))
    return grid[np.sort(np.random.default_rng(seed).choice(len(grid), size=take, replace=False))]


def candidate_wrists(
    topo: TopologyDescriptors,
    hand: HandFrame,
    offsets: np.ndarray,
    *,
    roll_deg: float,
    pitch_deg: float,
    palm_distance: float,
    y_d: float,
) -> np.ndarray:
    """(B, M, 4, 4) wrist-link poses, object frame: the paper's placement moved by each of ``offsets`` (M, 6)."""
    out = np.empty((len(topo.center), len(offsets), 4, 4))
    for m, (yaw, roll, pitch, dist, yd, lateral) in enumerate(offsets):
        poses = wrist_poses(
            topo,
            hand,
            roll_deg=roll_deg + roll,
            pitch_deg=pitch_deg + pitch,
            palm_distance=palm_distance + dist,
            y_d=y_d + yd,
        )
        out[:, m] = _turn_about_normal(poses, topo, np.radians(yaw))
        out[:, m, :3, 3] += lateral * topo.lateral_axis
    return out


def distinct_ranking(
    cost: np.ndarray, wrists: np.ndarray, eligible: np.ndarray, keep: int, config: WristSearchConfig
) -> list[int]:
    """Up to ``keep`` candidate indices, best first: the lowest ``cost`` (M,), then the cheapest
    ``eligible`` (M,) candidates whose wrist pose (of ``wrists`` (M, 4, 4)) differs from every one picked
    before by at least ``config.distinct_deg`` of rotation or ``config.distinct_distance`` of position.
    Ties go to the lower index (the paper's placement is index 0)."""
    order = np.argsort(cost, kind="stable")
    picked = [int(order[0])]
    min_cos = np.cos(np.radians(config.distinct_deg))
    for k in order[1:]:
        if len(picked) >= keep:
            break
        if not eligible[k]:
            continue
        rot = wrists[picked, :3, :3]
        cos = (np.einsum("pij,ij->p", rot, wrists[k, :3, :3]) - 1.0) / 2.0  # cos of the relative rotation angle
        far = np.linalg.norm(wrists[picked, :3, 3] - wrists[k, :3, 3], axis=1) >= config.distinct_distance
        if np.all((cos <= min_cos) | far):
            picked.append(int(k))
    return picked


def _turn_about_normal(poses: np.ndarray, topo: TopologyDescriptors, angle: float) -> np.ndarray:
    """(B, 4, 4) ``poses`` turned by ``angle`` rad about each grasp's palm normal through its contact centre."""
    if angle == 0.0:
        return poses
    n = topo.palm_normal
    k = np.zeros((len(n), 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -n[:, 2], n[:, 1], -n[:, 0]
    k = k - k.transpose(0, 2, 1)
    turn = np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)  # Rodrigues
    out = poses.copy()
    out[:, :3, :3] = turn @ poses[:, :3, :3]
    out[:, :3, 3] = np.einsum("bij,bj->bi", turn, poses[:, :3, 3] - topo.center) + topo.center
    return out


@dataclass(frozen=True)
class ObjectCloud:
    """An object's surface samples, object frame: what the wrist search keeps the hand's body out of."""

    points: np.ndarray
    """(C, 3) points on the surface, metres."""
    normals: np.ndarray
    """(C, 3) unit outward normals at them."""


def object_penalty(points: np.ndarray, cloud: ObjectCloud, config: WristSearchConfig) -> np.ndarray:
    """(M,) ``object_weight * sum(max(0, clearance - d)^2)`` over hand points ``points`` (M, N, 3), object frame.

    d: signed distance of each point from the surface, approximated through its nearest cloud sample c
    with outward normal n as ``(p - c) . n`` (negative inside). Good near the surface, which is where
    the links that should not touch are; a point deeper than half the object's thickness may read as outside.
    Only points within the cloud's bounding box grown by ``clearance + BOX_MARGIN`` are measured (the
    others are outside the object by more than the clearance, so add nothing); most of the hand is.
    """
    pts = cloud.points[: config.cloud_points]
    nrm = cloud.normals[: config.cloud_points]
    flat = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    grow = config.object_clearance + BOX_MARGIN
    near = np.flatnonzero(np.all((flat > pts.min(axis=0) - grow) & (flat < pts.max(axis=0) + grow), axis=1))
    out = np.zeros(points.shape[:2])
    if len(near):
        hand = torch.as_tensor(flat[near])
        nearest = torch.cdist(hand, torch.as_tensor(pts)).argmin(dim=1).numpy()
        d = np.einsum("ij,ij->i", flat[near] - pts[nearest], nrm[nearest])
        out.reshape(-1)[near] = np.clip(config.object_clearance - d, 0.0, None) ** 2
    return config.object_weight * out.sum(axis=1)


def table_penalty(link_z: np.ndarray, config: WristSearchConfig) -> np.ndarray:
    """(B,) ``table_weight * sum(max(0, clearance - z)^2)`` over hand points' heights ``link_z`` (B, N), m."""
    short = np.clip(config.table_clearance - link_z, 0.0, None)
    return config.table_weight * (short**2).sum(axis=1)
