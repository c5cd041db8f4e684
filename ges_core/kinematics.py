"""Batched forward kinematics and fingertip Jacobians of a hand, relative to its base link.

This is the one module of GES-UniGrasp that calls ``pytorch_kinematics`` (pinned to 0.7.6 by
``mani-skill``); keep every ``pk`` call here so the version can move later.

Frames and units: every pose and point is in the frame of the hand's base (URDF root) link,
metres; joint vectors ``q`` are ``(B, K)`` in ``HandDescription.joint_names`` order, radians
(metres for prismatic joints). The chain's own joint order (depth-first through the URDF tree) is
mapped to the hand's order once, by name.

Jacobians are geometric, from one FK pass: column ``k`` of a point ``p`` on link ``l`` is
``a_k x (p - o_k)`` for a revolute ancestor joint ``k`` (``a_k`` its axis and ``o_k`` its origin,
base frame), ``a_k`` for a prismatic one and zero for joints that do not move ``l``. Measured on
Allegro, 4 fingertip points, float64, one CPU thread, pk 0.7.6, best of 3 runs on the shared 2-core
machine (loaded; single runs varied up to 2x):

==================================  ========  =========
per call                             B = 1     B = 1024
==================================  ========  =========
Jacobians, geometric (kept)          2.6 ms    22 ms
Jacobians, pk.SerialChain per link   7.9 ms    35 ms
Jacobians, autograd, 12 backwards   18.5 ms   229 ms
Jacobians, autograd, vmapped         4.9 ms   457 ms
FK, 4 tip links                      1.2 ms    16 ms
FK, all 23 links                     2.3 ms    18 ms
==================================  ========  =========

``pytorch_kinematics`` 0.7.6 parses URDF origins in float32, so whatever the dtype the frames carry
float32 rounding: against PyBullet (float64) on Allegro, link positions agree within 1e-8 m and
rotation entries within 4e-7. Composition runs in the chosen dtype (float64 by default).

Coupled joints (``HandDescription.couplings``, URDF ``<mimic>`` tags) are ordinary joints of ``q``
here: FK places a follower's links at the value ``q`` gives it (set followers first with
``HandDescription.apply_couplings``). ``<mimic>`` tags are removed before the chain is built, so whatever a
later pytorch-kinematics does with them, the chain's joints stay the URDF's movable joints.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Sequence
from functools import lru_cache
from typing import TYPE_CHECKING

import torch

from ges_core.errors import AssetError, UnknownNameError

if TYPE_CHECKING:
    from ges_core.hand import HandModel

__all__ = ["HandKinematics", "cached_kinematics", "palm_offset", "shared_kinematics"]

_REVOLUTE = 1
"""Index of ``"revolute"`` in ``pytorch_kinematics.frame.Joint.TYPES`` (0 fixed, 2 prismatic)."""


def _build_chain(urdf_text: str):
    """A ``pk.Chain`` from URDF text (the parser's chatter on stdout/stderr is swallowed)."""
    import pytorch_kinematics as pk

    from ges_core.hand_prep.mimic import strip_mimic

    data = strip_mimic(urdf_text).encode("utf-8")  # bytes: lxml rejects a str that carries an XML declaration
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            return pk.build_chain_from_urdf(data)
    except Exception as exc:  # noqa: BLE001 - the parser raises many kinds; we name the input
        raise AssetError(
            f"pytorch_kinematics cannot build a chain from this URDF: {type(exc).__name__}: {exc}"
        ) from exc


class HandKinematics:
    """FK, points and positional Jacobians of one hand, batched over configurations.

    urdf_text: the hand's URDF (fixed base: no floating wrist joints).
    joint_names: the hand's canonical joint order (K names); must be exactly the URDF's movable joints.
    dtype, device: of every tensor this object returns (like ``torch.Tensor.to``).
    """

    def __init__(
        self,
        urdf_text: str,
        joint_names: Sequence[str],
        *,
        dtype: torch.dtype = torch.float64,
        device: torch.device | str = "cpu",
    ) -> None:
        self.urdf_text = urdf_text
        self.joint_names = tuple(joint_names)
        self.dtype, self.device = dtype, torch.device(device)
        self._chain = _build_chain(urdf_text).to(dtype=dtype, device=self.device)
        chain_joints = list(self._chain.get_joint_parameter_names())
        self._check_joint_names(chain_joints)
        hand_index = {n: i for i, n in enumerate(self.joint_names)}
        self.idx_hand_to_chain = torch.tensor([hand_index[n] for n in chain_joints], device=self.device)
        """(K,) hand-order vector -> chain order: ``q_chain = q_hand[:, idx_hand_to_chain]``."""
        self.idx_chain_to_hand = torch.tensor([chain_joints.index(n) for n in self.joint_names], device=self.device)
        """(K,) chain-order vector -> hand order: ``q_hand = q_chain[:, idx_chain_to_hand]``."""
        self.link_names: tuple[str, ...] = tuple(self._chain.get_frame_names(exclude_fixed=False))
        """Every link of the URDF, base link first (depth-first order)."""
        self._pairs_cache: dict[tuple[int, ...], tuple[torch.Tensor, ...]] = {}

    @classmethod
    def from_hand(
        cls, hand: HandModel, *, dtype: torch.dtype = torch.float64, device: torch.device | str = "cpu"
    ) -> HandKinematics:
        """Kinematics of ``hand``'s URDF in its description's joint order."""
        return cls(hand.urdf_text(), hand.description.joint_names, dtype=dtype, device=device)

    def to(self, dtype: torch.dtype | None = None, device: torch.device | str | None = None) -> HandKinematics:
        """A copy with another dtype and/or device (this object is unchanged)."""
        return HandKinematics(self.urdf_text, self.joint_names, dtype=dtype or self.dtype, device=device or self.device)

    @property
    def base_link(self) -> str:
        """The URDF root link: the frame of every pose and point returned."""
        return self.link_names[0]

    @property
    def num_joints(self) -> int:
        """K."""
        return len(self.joint_names)

    # -- public API -----------------------------------------------------------------------
    def link_poses(self, q: torch.Tensor, links: Sequence[str]) -> torch.Tensor:
        """(B, L, 4, 4) homogeneous poses of ``links`` in the base frame for ``q`` (B, K)."""
        idx = self._frame_indices(links)
        fk = self._fk(self._q_chain(q), sorted(set(idx)))
        return torch.stack([fk[i] for i in idx], dim=1)

    def points(self, q: torch.Tensor, links: Sequence[str], offsets: torch.Tensor | None = None) -> torch.Tensor:
        """(B, L, 3) base-frame positions of points fixed to ``links``.

        offsets: (L, 3) or (B, L, 3) point in each link's frame, metres; None = link origins.
        """
        poses = self.link_poses(q, links)
        return self._apply_offsets(poses, self._offsets(offsets, len(links), poses.shape[0]))

    def jacobians(self, q: torch.Tensor, links: Sequence[str], offsets: torch.Tensor | None = None) -> torch.Tensor:
        """(B, L, 3, K) positional Jacobians ``d points / d q`` in the hand's joint order, base frame.

        offsets: as in :meth:`points`.
        """
        return self.points_and_jacobians(q, links, offsets)[1]

    def points_and_jacobians(
        self, q: torch.Tensor, links: Sequence[str], offsets: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, L, 3) points and (B, L, 3, K) Jacobians from one forward-kinematics pass (see :meth:`jacobians`)."""
        idx = self._frame_indices(links)
        key = tuple(idx)
        if key not in self._pairs_cache:
            self._pairs_cache[key] = self._jacobian_pairs(idx)
        pairs = self._pairs_cache[key]
        q_chain = self._q_chain(q)
        needed = sorted(set(idx) | set(pairs[1].tolist()))
        fk = self._fk(q_chain, needed)
        poses = torch.stack([fk[i] for i in idx], dim=1)
        points = self._apply_offsets(poses, self._offsets(offsets, len(idx), q_chain.shape[0]))
        return points, self._scatter_columns(points, fk, pairs)

    # -- internals ------------------------------------------------------------------------
    def _check_joint_names(self, chain_joints: list[str]) -> None:
        missing = [n for n in chain_joints if n not in self.joint_names]
        unknown = [n for n in self.joint_names if n not in chain_joints]
        twice = sorted({n for n in self.joint_names if self.joint_names.count(n) > 1})
        if missing or unknown or twice:
            raise AssetError(
                f"joint_names must list each movable URDF joint once: not in the URDF {unknown}, "
                f"missing {missing}, repeated {twice} (URDF joints: {', '.join(chain_joints)})"
            )

    def _q_chain(self, q: torch.Tensor) -> torch.Tensor:
        q = torch.as_tensor(q)
        if q.ndim != 2 or q.shape[1] != self.num_joints:
            raise ValueError(
                f"q must have shape (B, {self.num_joints}) in the order {', '.join(self.joint_names)}; "
                f"got {tuple(q.shape)}"
            )
        return q.to(dtype=self.dtype, device=self.device)[:, self.idx_hand_to_chain]

    def _frame_indices(self, links: Sequence[str]) -> list[int]:
        if isinstance(links, str):
            raise TypeError(f"links must be a sequence of link names, got the string '{links}'")
        if len(links) == 0:
            raise ValueError("links is empty; name at least one link")
        lookup = self._chain.frame_to_idx
        for name in links:
            if name not in lookup:
                raise UnknownNameError("link", name, self.link_names)
        return [lookup[name] for name in links]

    def _fk(self, q_chain: torch.Tensor, frame_indices: list[int]) -> dict[int, torch.Tensor]:
        """Frame index -> (B, 4, 4) pose, for ``frame_indices`` (sorted, so ancestors come first)."""
        names = self._chain.forward_kinematics(q_chain, torch.tensor(frame_indices, device=self.device))
        return {i: names[self._chain.idx_to_frame[i]].get_matrix() for i in frame_indices}

    def _offsets(self, offsets: torch.Tensor | None, n_links: int, batch: int) -> torch.Tensor:
        if offsets is None:
            return torch.zeros(batch, n_links, 3, dtype=self.dtype, device=self.device)
        off = torch.as_tensor(offsets).to(dtype=self.dtype, device=self.device)
        if off.shape == (n_links, 3):
            return off.expand(batch, n_links, 3)
        if off.shape != (batch, n_links, 3):
            raise ValueError(
                f"offsets must have shape ({n_links}, 3) or ({batch}, {n_links}, 3); got {tuple(off.shape)}"
            )
        return off

    @staticmethod
    def _apply_offsets(poses: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
        return (poses[..., :3, :3] @ offsets.unsqueeze(-1)).squeeze(-1) + poses[..., :3, 3]

    def _jacobian_pairs(self, frame_indices: list[int]) -> tuple[torch.Tensor, ...]:
        """(row, joint frame, hand column, is revolute) for every (link, ancestor joint) pair."""
        rows, frames, cols, revolute = [], [], [], []
        for row, idx in enumerate(frame_indices):
            for anc in self._chain.parents_indices[idx].tolist():
                jnt = int(self._chain.joint_indices[anc])
                if jnt < 0:
                    continue
                rows.append(row)
                frames.append(anc)
                cols.append(int(self.idx_hand_to_chain[jnt]))  # hand column of chain joint jnt
                revolute.append(int(self._chain.joint_type_indices[anc]) == _REVOLUTE)
        as_long = {"dtype": torch.long, "device": self.device}
        return (
            torch.tensor(rows, **as_long),
            torch.tensor(frames, **as_long),
            torch.tensor(cols, **as_long),
            torch.tensor(revolute, dtype=torch.bool, device=self.device),
        )

    def _scatter_columns(
        self, points: torch.Tensor, fk: dict[int, torch.Tensor], pairs: tuple[torch.Tensor, ...]
    ) -> torch.Tensor:
        """(B, L, 3, K) Jacobians from joint frames: ``a x (p - o)`` (revolute) or ``a`` (prismatic)."""
        rows, frames, cols, revolute = pairs
        batch, n_links = points.shape[:2]
        jac = torch.zeros(batch, n_links, 3, self.num_joints, dtype=self.dtype, device=self.device)
        if len(rows) == 0:
            return jac
        joint_poses = torch.stack([fk[i] for i in frames.tolist()], dim=1)  # (B, P, 4, 4)
        chain_joint = self._chain.joint_indices[frames]
        axes = (joint_poses[..., :3, :3] @ self._chain.axes[chain_joint].unsqueeze(-1)).squeeze(-1)  # (B, P, 3)
        lever = points[:, rows] - joint_poses[..., :3, 3]
        cols_vals = torch.where(revolute[:, None], torch.cross(axes, lever, dim=-1), axes)
        jac[:, rows, :, cols] = cols_vals.transpose(0, 1)
        return jac


def shared_kinematics(hand: HandModel) -> HandKinematics:
    """A float64 CPU :class:`HandKinematics` of ``hand``, built once per (URDF, joint order) and then reused.

    For code that needs the hand's kinematics now and then (a squeeze, a start pose) rather than keeping its
    own: parsing the URDF takes 20 ms to 0.7 s. Callers must not change the object (it is shared)."""
    d = hand.description
    return cached_kinematics(hand.urdf_text(), tuple(d.joint_names))


@lru_cache(maxsize=8)
def cached_kinematics(urdf_text: str, joint_names: tuple[str, ...]) -> HandKinematics:
    """:func:`shared_kinematics` by its key (for caches keyed by the URDF text rather than a hand object)."""
    return HandKinematics(urdf_text, joint_names)


def palm_offset(hand: HandModel, q: torch.Tensor, palm: float = 0.0, finger: float = 0.0) -> torch.Tensor:
    """(B, 3) float64 base-frame vector: ``palm`` m along the hand's palm normal plus ``finger`` m along its finger
    direction (``HandDescription.wrist``, given in the wrist link's frame), with the hand at joints ``q`` (B, K).

    The wrist link may sit behind wrist joints (the Shadow's palm is two joints past its base), so the wrist-frame
    vector is turned by the base-to-wrist-link rotation at ``q`` (set coupled joints first). Turn the result by the
    base link's orientation for a world (or object-frame) offset of the base: moving the base by it moves the palm
    the same way, since the hand is rigid at fixed joints.
    """
    w = hand.description.wrist
    local = palm * torch.tensor(w.palm_normal, dtype=torch.float64) + finger * torch.tensor(
        w.finger_direction, dtype=torch.float64
    )
    turn = shared_kinematics(hand).link_poses(q, [w.link])[:, 0, :3, :3].to(torch.float64)
    return turn @ local
