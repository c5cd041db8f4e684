"""Batched vector retargeting: joint angles that put each fingertip on its target point.

Solves, for every grasp b of a batch at once,

    min_q  sum_s ||alpha v_s - f_s(q)||^2 + beta ||q - q_prev||^2     s.t.  q_l <= q <= q_u

where ``v_s`` is the target of finger slot ``s`` (base-link frame, metres) and ``f_s(q)`` the
fingertip point (``tip_link`` + ``tip_offset``) of the physical finger serving that slot. A finger
serving two slots (Allegro's ring serves ring and little) gets both terms, which is the same as
aiming it at the mean of the two targets with weight 2.

Method: projected Levenberg-Marquardt with an active set of joints, one independent problem per finger.
With the wrist held fixed every fingertip depends only on its own finger's joints, so the problem
separates into F small ones (4-5 unknowns each) solved side by side: each finger of each grasp has
its own damping, accepts or rejects its own steps and stops improving on its own. Coupled joints
(Shadow's J0 follows J1) are not unknowns: only leaders are, followers are set by
``HandDescription.apply_couplings`` semantics and their Jacobian columns are folded into the
leader's (chain rule). Joints of no finger (Shadow's wrist WRJ1/WRJ0) stay at ``q_init``.

Start: ``q_init`` (default the open pose) unless, per finger, a sample of a fixed table of
``seeds`` random configurations has a lower objective; the table (FK of seeded random joint values)
is built once per retargeter. ``seeds=0`` starts from ``q_init`` only.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch
from pydantic import Field

from ges_core.arrays import checked_array
from ges_core.config import ConfigModel
from ges_core.contact import FINGER_SLOTS
from ges_core.errors import ArrayError, AssetError
from ges_core.hand import HandDescription, HandModel
from ges_core.kinematics import HandKinematics

__all__ = ["VectorRetargetConfig", "VectorRetargeter"]

_DAMPING_FLOOR = 1e-2
"""m^2 added to diag(J^T J) under the damping: about a fingertip Jacobian column's squared length
(0.1 m lever); it damps the first steps from straight (singular) fingers. Cold starts, Allegro, 1024
reachable targets, 10 iterations: mean error 0.024 mm; with 1e-6 instead 0.29 mm (4.7 mm when the
initial damping was also 0.01)."""
_BOUND_EPS = 1e-9
"""Radians: a joint this close to a limit counts as on it (active set)."""


class VectorRetargetConfig(ConfigModel):
    """Settings of :class:`VectorRetargeter`."""

    alpha: float = Field(
        1.0,
        gt=0,
        description="scale applied to the targets (alpha of the paper). 1.0 for contacts on a real object: they "
        "are already in metres where the fingertips must go; the paper's alpha scales human keypoints to a robot",
    )
    beta: float = Field(
        1e-8,
        ge=0,
        description="smoothness weight, m^2/rad^2: 1e-8 weighs 1 rad of joint motion like 0.1 mm of fingertip "
        "error; it picks, among a redundant finger's solutions, the one nearest q_prev (1e-6 left up to 1 mm "
        "of error on reachable targets)",
    )
    iterations: int = Field(6, ge=0, description="Levenberg-Marquardt iterations (one batched FK + Jacobian each)")
    tolerance: float = Field(
        1e-6, ge=0, description="metres: a finger this close to its target stops moving; the solve ends when all do"
    )
    damping: float = Field(
        0.1, gt=0, description="initial Levenberg-Marquardt damping lambda (A = J^T J + lambda (diag(J^T J) + floor))"
    )
    seeds: int = Field(512, ge=0, description="random configurations in the start table (0: start from q_init only)")
    # Pad term: with contact normals given, a second point per finger, pad_depth behind the pad along its
    # pad_normal, is aimed pad_depth outside the contact along the surface normal, so the pad faces the
    # surface. Without it the Shadow thumb reached its contacts with its side and pushed the box sideways
    # (thumb force ~90 degrees off the contact normal, 0 of 19 demo grasps held; docs/synthesis/retargeting.md).
    pad_weight: float = Field(
        0.5, ge=0, description="weight of the pad-orientation point against the fingertip point (0: tips only)"
    )
    pad_depth: float = Field(
        0.015, gt=0, description="metres between the fingertip point and the pad-orientation point"
    )
    seed: int = Field(0, description="random seed of the start table")


@dataclass(frozen=True)
class _FingerLayout:
    """Index tensors describing which joints each used finger moves (hand joint order)."""

    tip_links: tuple[str, ...]
    """(F,) tip link of each used finger."""
    offsets: torch.Tensor
    """(F, 3) fingertip point in each tip link's frame, metres."""
    pads: torch.Tensor
    """(F, 3) unit pad normal in each tip link's frame (zero: none declared)."""
    slot_finger: torch.Tensor
    """(S,) index of the used finger serving each slot."""
    weights: torch.Tensor
    """(F,) number of slots each finger serves."""
    cols: torch.Tensor
    """(F, n) leader-joint indices of each finger, padded."""
    mask: torch.Tensor
    """(F, n) True where ``cols`` is a real joint."""
    joint_finger: torch.Tensor
    """(K,) used finger of each joint, F for joints of no used finger."""


@dataclass(frozen=True)
class _Problem:
    """What the solver aims for a batch: P points per finger (P = 1 fingertip; 2 with the pad term)."""

    targets: torch.Tensor
    """(B, F, P, 3) target of each aimed point, base-link frame, metres."""
    weights: torch.Tensor
    """(F, P) weight of each aimed point (fingertip 1)."""
    offsets: torch.Tensor
    """(F, P, 3) each aimed point in its finger's tip-link frame."""


@dataclass
class _LmState:
    """The Levenberg-Marquardt iterate of a batch (or of some of its rows)."""

    q: torch.Tensor
    """(B, K) joints."""
    live: torch.Tensor
    """(B, C) True where a coupled follower is not clipped."""
    points: torch.Tensor
    """(B, F, P, 3) aimed points at ``q``."""
    jac: torch.Tensor
    """(B, F, P, 3, K) their Jacobians."""
    cost: torch.Tensor
    """(B, F) each finger's share of the objective."""
    lam: torch.Tensor
    """(B, F) damping."""
    done: torch.Tensor
    """(B, F) settled fingers."""

    def take(self, rows: torch.Tensor) -> _LmState:
        """The state of ``rows`` only (copies)."""
        return _LmState(*(getattr(self, f.name)[rows] for f in fields(self)))

    def put(self, rows: torch.Tensor, part: _LmState) -> None:
        """Write ``part`` (the state of ``rows``) back."""
        for f in fields(self):
            getattr(self, f.name)[rows] = getattr(part, f.name)


class VectorRetargeter:
    """Batched bounded least-squares fingertip retargeting for one hand.

    hand: the hand; its URDF is parsed once (or pass ``kinematics`` built from it).
    config: solver settings.
    """

    def __init__(
        self,
        hand: HandModel,
        config: VectorRetargetConfig | None = None,
        *,
        kinematics: HandKinematics | None = None,
    ) -> None:
        self.hand, self.config = hand, config or VectorRetargetConfig()
        self.description = d = hand.description
        self.kinematics = kinematics or HandKinematics.from_hand(hand)
        self.dtype = self.kinematics.dtype
        self.layout = _finger_layout(d, self.dtype)
        self.limits = torch.as_tensor(d.limits_array, dtype=self.dtype)
        self.open_pose = torch.as_tensor(np.asarray(d.open_pose, dtype=np.float64), dtype=self.dtype)
        self._couplings = _coupling_tensors(d, self.dtype)
        self._seed_q, self._seed_points = self._seed_table()

    # -- public API -----------------------------------------------------------------------
    @property
    def num_fingers(self) -> int:
        """F, the physical fingers that serve at least one slot."""
        return len(self.layout.tip_links)

    def fingertips(self, q: torch.Tensor) -> torch.Tensor:
        """(B, S, 3) fingertip point serving each slot, base-link frame, metres, for ``q`` (B, K)."""
        tips = self.kinematics.points(q, self.layout.tip_links, self.layout.offsets)
        return tips[:, self.layout.slot_finger]

    def solve(
        self,
        targets: torch.Tensor | np.ndarray,
        q_init: torch.Tensor | np.ndarray | None = None,
        q_prev: torch.Tensor | np.ndarray | None = None,
        normals: torch.Tensor | np.ndarray | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Joint angles whose fingertips reach ``targets``.

        targets: (B, S, 3) one point per slot in :data:`FINGER_SLOTS` order, base-link frame, metres
            (multiplied by ``config.alpha``).
        q_init: (B, K) start, hand joint order; joints of no finger keep these values. Default: open pose.
        q_prev: (B, K) the ``beta`` term's anchor. Default: ``q_init``.
        normals: (B, S, 3) outward surface normals at the targets, base-link frame, or None. Given (and
            ``config.pad_weight`` > 0), fingers with a declared ``pad_normal`` also turn their pad to
            face the surface (the pad term, see :class:`VectorRetargetConfig`).
        Returns ``q`` (B, K) within limits, couplings applied, and the residual (B,): the mean over
            slots of the distance from the serving fingertip to the point that finger aims at, metres: the
            slot's target, or for a finger serving several slots (Allegro's ring) the mean of their targets,
            the best it can do (measured to each target, two contacts d apart would add at least 2 d / 5
            to the mean whatever the hand does).
        """
        tgt = self._check_targets(targets) * self.config.alpha
        batch = tgt.shape[0]
        q0 = self._check_q(q_init, batch, "q_init")
        prev = q0 if q_prev is None else self._check_q(q_prev, batch, "q_prev")
        problem = self._problem(tgt, normals)
        q = self._start(self._couple(q0)[0], problem, prev)
        q, points = self._levenberg_marquardt(q, problem, prev)
        aims = problem.targets[:, self.layout.slot_finger, 0]  # (B, S, 3): a slot's target, or its finger's mean
        residual = (points[:, self.layout.slot_finger, 0] - aims).norm(dim=-1).mean(dim=1)
        return q, residual

    @property
    def thumb_finger(self) -> int:
        """Index among the F used fingers (:meth:`finger_objective`'s columns) of the finger serving the thumb slot."""
        return int(self.layout.slot_finger[FINGER_SLOTS.index("thumb")])

    def objective(
        self,
        q: torch.Tensor,
        targets: torch.Tensor | np.ndarray,
        normals: torch.Tensor | np.ndarray | None = None,
    ) -> torch.Tensor:
        """(B,) the fit part of the objective at ``q`` (B, K): weighted squared distances of the aimed points, m^2.

        targets, normals: as for :meth:`solve`. Lets a caller compare solutions of different problems
        (e.g. wrist placements) on one scale. The sum over fingers of :meth:`finger_objective`."""
        return self.finger_objective(q, targets, normals).sum(-1)

    def finger_objective(
        self,
        q: torch.Tensor,
        targets: torch.Tensor | np.ndarray,
        normals: torch.Tensor | np.ndarray | None = None,
    ) -> torch.Tensor:
        """(B, F) each used finger's share of :meth:`objective` (its slot count times its points' weighted squared
        distances), m^2, fingers in :attr:`num_fingers` order (the thumb's column: :attr:`thumb_finger`)."""
        problem = self._problem(self._check_targets(targets) * self.config.alpha, normals)
        return self._fit(self._points(torch.as_tensor(q).to(self.dtype), problem.offsets), problem)

    # -- input checks -----------------------------------------------------------------------
    def _check_targets(self, targets: torch.Tensor | np.ndarray, what: str = "targets") -> torch.Tensor:
        layout = f"one per slot ({', '.join(FINGER_SLOTS)}), base-link frame; check the contact generator"
        t = checked_array(targets, (None, len(FINGER_SLOTS), 3), f"retargeting: {what}", layout=layout)
        if len(t) == 0:
            raise ArrayError(f"retargeting: {what} is empty; give at least one grasp (B >= 1)")
        return torch.from_numpy(t).to(self.dtype)

    def _check_q(self, q: torch.Tensor | np.ndarray | None, batch: int, what: str) -> torch.Tensor:
        k = self.description.num_joints
        if q is None:
            return self.open_pose.expand(batch, k).clone()
        layout = f"one row per grasp, '{self.description.name}' joint order"
        q = torch.from_numpy(checked_array(q, (batch, k), f"retargeting: {what}", layout=layout)).to(self.dtype)
        return q.clamp(self.limits[:, 0], self.limits[:, 1])

    # -- problem pieces ---------------------------------------------------------------------
    def _problem(self, tgt: torch.Tensor, normals: torch.Tensor | np.ndarray | None) -> _Problem:
        """Per-finger points to aim: the fingertip, plus the pad-orientation point when normals are given."""
        lay, cfg = self.layout, self.config
        finger_tgt = self._finger_targets(tgt)
        has_pad = lay.pads.norm(dim=-1) > 0
        if normals is None or cfg.pad_weight == 0 or not bool(has_pad.any()):
            ones = torch.ones(self.num_fingers, 1, dtype=self.dtype)
            return _Problem(finger_tgt[:, :, None], ones, lay.offsets[:, None])
        n = self._check_targets(normals, "normals")
        n = self._finger_targets(n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12))
        n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        points = torch.stack([finger_tgt, finger_tgt + cfg.pad_depth * n], dim=2)
        weights = torch.stack([torch.ones_like(has_pad, dtype=self.dtype), cfg.pad_weight * has_pad.to(self.dtype)], 1)
        return _Problem(points, weights, self._pad_offsets())

    def _pad_offsets(self) -> torch.Tensor:
        """(F, 2, 3) fingertip point and pad-orientation point (pad_depth behind the pad) in each tip link's frame."""
        lay = self.layout
        return torch.stack([lay.offsets, lay.offsets - self.config.pad_depth * lay.pads], dim=1)

    def _finger_targets(self, targets: torch.Tensor) -> torch.Tensor:
        """(B, F, 3) mean target of each used finger's slots."""
        lay = self.layout
        summed = torch.zeros(targets.shape[0], self.num_fingers, 3, dtype=self.dtype)
        summed.index_add_(1, lay.slot_finger, targets)
        return summed / lay.weights[None, :, None]

    def _couple(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """q with followers set from leaders (clipped), and (B, C) True where a follower is not clipped."""
        fol, lead, ratio, offset = self._couplings
        if len(fol) == 0:
            return q, torch.ones(q.shape[0], 0, dtype=torch.bool)
        value = ratio * q[:, lead] + offset
        lo, hi = self.limits[fol, 0], self.limits[fol, 1]
        q = q.clone()
        q[:, fol] = torch.maximum(torch.minimum(value, hi), lo)
        return q, (value >= lo) & (value <= hi)

    def _fit(self, points: torch.Tensor, problem: _Problem) -> torch.Tensor:
        """(B, F) each finger's fit term: its slot count times its aimed points' weighted squared distances, m^2;
        points (B, F, P, 3) as ``problem`` aims them."""
        return self.layout.weights * (problem.weights * ((points - problem.targets) ** 2).sum(-1)).sum(-1)

    def _cost(self, points: torch.Tensor, q: torch.Tensor, problem: _Problem, prev: torch.Tensor) -> torch.Tensor:
        """(B, F) each finger's share of the objective (fit plus the beta term); points (B, F, P, 3) as ``problem``
        aims them."""
        dq2 = torch.zeros(q.shape[0], self.num_fingers + 1, dtype=self.dtype)
        dq2.index_add_(1, self.layout.joint_finger, (q - prev) ** 2)
        return self._fit(points, problem) + self.config.beta * dq2[:, :-1]

    def _seed_table(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(M, K) random joint values (other joints open, couplings applied) and (M, F, 2, 3) their aimed points."""
        m = self.config.seeds
        if m == 0:
            return torch.zeros(0, self.description.num_joints, dtype=self.dtype), torch.zeros(0, self.num_fingers, 2, 3)
        lim = self.limits.numpy()
        rng = np.random.default_rng(self.config.seed)
        q = torch.as_tensor(rng.uniform(lim[:, 0], lim[:, 1], size=(m, len(lim))), dtype=self.dtype)
        moved = self.layout.joint_finger < self.num_fingers
        q = self._couple(torch.where(moved, q, self.open_pose))[0]
        return q, self._points(q, self._pad_offsets())

    def _start(self, q0: torch.Tensor, problem: _Problem, prev: torch.Tensor) -> torch.Tensor:
        """Per finger, ``q0`` or the table sample with the lower objective (aimed points + beta term)."""
        if self.config.seeds == 0:
            return q0
        lay, seeds = self.layout, self._seed_q
        rows, row_of = torch.unique(q0, dim=0, return_inverse=True)  # usually one start for all: one FK
        cost0 = self._cost(self._points(rows, problem.offsets)[row_of], q0, problem, prev)
        fit = 0.0
        for p in range(problem.targets.shape[2]):
            dist = torch.cdist(problem.targets[:, :, p].transpose(0, 1), self._seed_points[:, :, p].transpose(0, 1))
            fit = fit + (lay.weights * problem.weights[:, p])[:, None, None] * dist**2  # (F, B, M)
        best_cost, best = (fit + self.config.beta * self._seed_joint_cost(prev)).min(dim=-1)  # (F, B)
        finger = lay.joint_finger.clamp(max=self.num_fingers - 1)  # joints of no finger: masked below
        use = (best_cost.transpose(0, 1) < cost0)[:, finger] & (lay.joint_finger < self.num_fingers)
        # (B, K): every joint taken from the sample its own finger picked
        picked = seeds[best.transpose(0, 1)[:, finger], torch.arange(len(finger))]
        return torch.where(use, picked, q0)

    def _seed_joint_cost(self, prev: torch.Tensor) -> torch.Tensor:
        """(F, B, M) squared joint distance from ``prev`` to every table sample, per finger's joints."""
        lay = self.layout
        rows = []
        for f in range(self.num_fingers):
            joints = torch.nonzero(lay.joint_finger == f)[:, 0]
            rows.append(torch.cdist(prev[:, joints], self._seed_q[:, joints]) ** 2)
        return torch.stack(rows)

    # -- Levenberg-Marquardt ----------------------------------------------------------------
    def _levenberg_marquardt(
        self, q: torch.Tensor, problem: _Problem, prev: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, K) joints after ``config.iterations`` steps from ``q``, and their (B, F, P, 3) aimed points.

        Every finger keeps its best iterate; a finger within ``config.tolerance`` of a tips-only target stops
        moving. Only the rows (grasps) with a finger still moving are iterated: a settled row costs no more
        kinematics, and the result is the same as iterating every row (its fingers are frozen either way).
        """
        cfg = self.config
        q, live = self._couple(q)
        points, jac = self._points_and_jacobians(q, problem.offsets)
        cost = self._cost(points, q, problem, prev)
        lam = torch.full(cost.shape, cfg.damping, dtype=self.dtype)
        done = self._settled(points, torch.zeros(cost.shape, dtype=torch.bool), problem)  # settled: change no more
        state = _LmState(q, live, points, jac, cost, lam, done)
        for _ in range(cfg.iterations):
            rows = torch.nonzero(~state.done.all(dim=1))[:, 0]
            if len(rows) == 0:
                break
            whole = len(rows) == len(q)
            sub = _Problem(problem.targets if whole else problem.targets[rows], problem.weights, problem.offsets)
            part = state if whole else state.take(rows)
            self._lm_iteration(part, sub, prev if whole else prev[rows])
            if not whole:
                state.put(rows, part)
        return state.q, state.points

    def _lm_iteration(self, s: _LmState, problem: _Problem, prev: torch.Tensor) -> None:
        """One Levenberg-Marquardt iteration of the rows in ``s`` (updated in place)."""
        lay = self.layout
        step = self._step(s.q, s.points - problem.targets, self._fold_couplings(s.jac, s.live), prev, s.lam, problem)
        trial, trial_live = self._couple(torch.maximum(torch.minimum(s.q + step, self.limits[:, 1]), self.limits[:, 0]))
        trial_points, trial_jac = self._points_and_jacobians(trial, problem.offsets)
        trial_cost = self._cost(trial_points, trial, problem, prev)
        ok = (trial_cost < s.cost) & ~s.done  # (B, F)
        ok_pad = torch.cat([ok, torch.zeros_like(ok[:, :1])], dim=1)
        s.q = torch.where(ok_pad[:, lay.joint_finger], trial, s.q)
        s.live = torch.where(ok_pad[:, lay.joint_finger[self._couplings[0]]], trial_live, s.live)
        s.points = torch.where(ok[..., None, None], trial_points, s.points)
        s.jac = torch.where(ok[..., None, None, None], trial_jac, s.jac)
        s.cost = torch.where(ok, trial_cost, s.cost)
        s.lam = torch.where(ok, s.lam / 3.0, s.lam * 4.0).clamp(1e-9, 1e9)  # usual LM schedule: shrink on success
        s.done = self._settled(s.points, s.done, problem)

    def _settled(self, points: torch.Tensor, done: torch.Tensor, problem: _Problem) -> torch.Tensor:
        """(B, F) fingers that have settled: ``done`` ones, and those whose tip (of ``points`` (B, F, P, 3)) is within
        ``tolerance`` of a tips-only target (with the pad term there is no exact solution: they iterate to the end)."""
        if problem.targets.shape[2] != 1:
            return done
        return done | ((points[:, :, 0] - problem.targets[:, :, 0]).norm(dim=-1) <= self.config.tolerance)

    def _step(
        self,
        q: torch.Tensor,
        residual: torch.Tensor,
        jac: torch.Tensor,
        prev: torch.Tensor,
        lam: torch.Tensor,
        problem: _Problem,
    ) -> torch.Tensor:
        """(B, K) damped Gauss-Newton step of the leader joints; joints on a limit pushing outward drop out.

        residual: (B, F, P, 3) aimed points minus targets; jac: (B, F, P, 3, K).
        """
        lay = self.layout
        fingers = torch.arange(self.num_fingers)[:, None]
        jg = jac.permute(0, 1, 4, 2, 3)[:, fingers, lay.cols]  # (B, F, n, P, 3)
        qf, pf = q[:, lay.cols], prev[:, lay.cols]
        lo, hi = self.limits[lay.cols, 0], self.limits[lay.cols, 1]
        free = lay.mask.expand(qf.shape)
        for _ in range(2):  # second pass without the joints the first one pushed past a limit
            dx = self._damped_solve(jg, residual, qf - pf, free, lam, problem.weights)
            blocked = ((qf <= lo + _BOUND_EPS) & (dx < 0)) | ((qf >= hi - _BOUND_EPS) & (dx > 0))
            if not blocked.any():
                break
            free = free & ~blocked
        step = torch.zeros_like(q)
        step[:, lay.cols[lay.mask]] = dx[:, lay.mask]
        return step

    def _damped_solve(
        self,
        jg: torch.Tensor,
        residual: torch.Tensor,
        dq: torch.Tensor,
        free: torch.Tensor,
        lam: torch.Tensor,
        point_weights: torch.Tensor,
    ) -> torch.Tensor:
        """(B, F, n) solution of (J^T W J + beta I + lam D) dx = -(J^T W r + beta dq) over the free joints.

        jg: (B, F, n, P, 3); residual: (B, F, P, 3); point_weights: (F, P); W = slot count x point weight.
        """
        w, beta = self.layout.weights[:, None] * point_weights, self.config.beta  # (F, P)
        jm = (jg * free[..., None, None]).flatten(-2)  # (B, F, n, P*3)
        wm = w[:, :, None].expand(*w.shape, 3).flatten(-2)  # (F, P*3)
        hess = (jm * wm[None, :, None]) @ jm.transpose(-1, -2)
        grad = (jm @ (wm * residual.flatten(-2)).unsqueeze(-1)).squeeze(-1) + beta * dq * free
        diag = (
            lam[..., None] * (torch.diagonal(hess, dim1=-2, dim2=-1) + _DAMPING_FLOOR) + beta + (~free).to(self.dtype)
        )
        return -torch.linalg.solve(hess + torch.diag_embed(diag), grad.unsqueeze(-1)).squeeze(-1) * free

    def _fold_couplings(self, jac: torch.Tensor, live: torch.Tensor) -> torch.Tensor:
        """(B, F, P, 3, K) Jacobian with each follower's column added to its leader's (times ratio, if not clipped)."""
        fol, lead, ratio, _ = self._couplings
        if len(fol) == 0:
            return jac
        scale = (ratio * live).reshape(live.shape[0], *([1] * (jac.dim() - 2)), -1)
        return jac.index_add(-1, lead, jac[..., fol] * scale)

    def _points(self, q: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
        """(B, F, P, 3) the aimed points (``offsets`` (F, P, 3) in each tip link's frame) for ``q`` (B, K)."""
        f, p = offsets.shape[:2]
        links = list(self.layout.tip_links) * p
        flat = self.kinematics.points(q, links, offsets.transpose(0, 1).reshape(f * p, 3))
        return flat.reshape(q.shape[0], p, f, 3).transpose(1, 2)

    def _points_and_jacobians(self, q: torch.Tensor, offsets: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, F, P, 3) aimed points and (B, F, P, 3, K) their Jacobians from one FK pass."""
        f, p = offsets.shape[:2]
        links = list(self.layout.tip_links) * p
        pts, jac = self.kinematics.points_and_jacobians(q, links, offsets.transpose(0, 1).reshape(f * p, 3))
        b, k = q.shape[0], jac.shape[-1]
        return pts.reshape(b, p, f, 3).transpose(1, 2), jac.reshape(b, p, f, 3, k).transpose(1, 2)


def _finger_layout(d: HandDescription, dtype: torch.dtype) -> _FingerLayout:
    """Which fingers serve the slots, their joints (leaders only) and fingertip points."""
    followers = {c.follower for c in d.couplings}
    used = []
    for slot in FINGER_SLOTS:
        finger = d.finger_for_slot(slot)
        if finger not in used:
            used.append(finger)
    slot_finger = [used.index(d.finger_for_slot(s)) for s in FINGER_SLOTS]
    joint_finger = np.full(d.num_joints, len(used), dtype=np.int64)
    for f, finger in enumerate(used):
        idx = d.joint_index(finger.joints)
        if np.any(joint_finger[idx] != len(used)):
            raise AssetError(
                f"hand '{d.name}': finger '{finger.name}' shares joints with another finger; "
                "vector retargeting needs each joint in one finger (fix the hand's fingers list)"
            )
        joint_finger[idx] = f
    leaders = [d.joint_index([j for j in f.joints if j not in followers]) for f in used]
    n = max(len(ix) for ix in leaders)
    cols, mask = np.zeros((len(used), n), dtype=np.int64), np.zeros((len(used), n), dtype=bool)
    for f, ix in enumerate(leaders):
        cols[f, : len(ix)], mask[f, : len(ix)] = ix, True
    return _FingerLayout(
        tip_links=tuple(f.tip_link for f in used),
        offsets=torch.tensor([f.tip_offset for f in used], dtype=dtype),
        pads=torch.tensor([f.pad_normal or (0.0, 0.0, 0.0) for f in used], dtype=dtype),
        slot_finger=torch.tensor(slot_finger),
        weights=torch.bincount(torch.tensor(slot_finger), minlength=len(used)).to(dtype),
        cols=torch.as_tensor(cols),
        mask=torch.as_tensor(mask),
        joint_finger=torch.as_tensor(joint_finger),
    )


def _coupling_tensors(
    d: HandDescription, dtype: torch.dtype
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """(C,) follower indices, (C,) leader indices, (C,) ratios, (C,) offsets (radians): ``q_f = r q_l + o``."""
    fol = torch.as_tensor(d.joint_index([c.follower for c in d.couplings]), dtype=torch.long)
    lead = torch.as_tensor(d.joint_index([c.leader for c in d.couplings]), dtype=torch.long)
    ratio = torch.tensor([c.ratio for c in d.couplings], dtype=dtype)
    return fol, lead, ratio, torch.tensor([c.offset for c in d.couplings], dtype=dtype)
