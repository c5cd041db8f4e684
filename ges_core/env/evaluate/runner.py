"""Evaluate an expert on Stage 1 grasps: per object one :class:`GraspEnv`, one episode per env.

>>> config = BaselineConfig(hand="allegro", sim="sapien", envs=2, selection="refined")
>>> report = evaluate_baseline("runs/demo/dataset", config, "runs/demo/baseline")
>>> print(report.table())

Per selected record (:mod:`ges_core.env.grasp_source`): the object's rest pose in ``sim``, a fresh
``sim`` with ``envs`` scenes (objects never share a scene: a reused scene carries the previous object's
history, see ``ges_core/synthesis/run_worker.py``), ``GraspEnv`` + ``GraspVecEnv`` (full reset: stage
one reaching to the pre-grasp), then the expert acts until every env has ended one episode. Recorded
per object: each env's end reason, whether the paper's protocol (0.2 m up, held 200 simulation steps)
and the peers' protocol (within 5 cm of the lift target at some step) succeeded, the highest rise.

Results: ``<out>/baseline-<hand>-<sim>.json``, rewritten atomically after every object. A rerun with the
same settings reuses every stored object whose grasp is unchanged (a killed run resumes where it
stopped); other settings raise ConfigError. Without randomization every env of one object runs the
same physics, so ``envs > 1`` only repeats the episode (a determinism check), see ``docs/env_baseline.md``.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from pydantic import Field, field_validator

from ges_core.config import ConfigModel, parse_model
from ges_core.dataset import GraspRecord
from ges_core.dataset.layout import config_differences, utc_now
from ges_core.env.baseline import ScriptedExpert
from ges_core.env.grasp_env import EnvConfig, GraspEnv
from ges_core.env.grasp_source import (
    SELECTIONS,
    GraspSelection,
    grasp_targets,
    library_for,
    object_rest_pose,
    open_grasp_dataset,
    select_records,
)
from ges_core.env.success import EndReason
from ges_core.env.vec_env import GraspVecEnv
from ges_core.errors import AssetError, ConfigError, GesError, SimulationError
from ges_core.objects.splits import SPLITS
from ges_core.paths import atomic_write_text
from ges_core.policy import Expert
from ges_core.sim import SceneConfig

__all__ = [
    "RESULTS_FORMAT",
    "BaselineConfig",
    "BaselineReport",
    "ScriptedSettings",
    "SplitRow",
    "evaluate_baseline",
    "format_table",
    "results_path",
    "run_episodes",
    "summarize",
]

RESULTS_FORMAT = "ges.baseline_results"
RESULTS_VERSION = 1
REASONS: tuple[str, ...] = tuple(r.name.lower() for r in EndReason if r is not EndReason.RUNNING) + ("error",)
"""End-reason columns of the table: the env's EndReason names, then 'error' (the object could not be set up)."""


class ScriptedSettings(ConfigModel):
    """Overrides of :class:`~ges_core.env.baseline.ScriptedExpert`'s parameters; None keeps the expert's default."""

    approach_steps: int | None = Field(None, ge=0, description="control steps moving the wrist to the grasp first")
    close_steps: int | None = Field(None, ge=1, description="control steps ramping the fingers to the goal")
    pause_steps: int | None = Field(None, ge=0, description="control steps held between closing and lifting")
    overshoot: float | None = Field(None, ge=0, description="fraction of (goal - start) pushed past the goal joints")
    lift: float | None = Field(None, gt=0, description="metres to lift (see ScriptedExpert)")
    carry_margin: float | None = Field(None, ge=0, description="m the wrist may rise past lift for a slipping object")
    carry_gain: float | None = Field(None, ge=0, le=1, description="share of the object's sideways drift corrected")
    squeeze_force: float | None = Field(None, ge=0, description="N each fingertip is driven to press with")

    def kwargs(self) -> dict:
        """The given overrides as ScriptedExpert keyword arguments."""
        return {k: v for k, v in self.model_dump().items() if v is not None}


def scripted_defaults() -> dict:
    """ScriptedExpert's current default parameters (stored with results: a changed default invalidates them)."""
    sig = inspect.signature(ScriptedExpert.__init__)
    return {k: p.default for k, p in sig.parameters.items() if p.default is not inspect.Parameter.empty}


class BaselineConfig(ConfigModel):
    """Settings of one expert evaluation (stored in the results file; a resume needs the same)."""

    hand: str = Field(..., description="registry name of the hand")
    sim: str = Field(..., description="registry name of the simulator the episodes run in")
    envs: int = Field(1, ge=1, description="envs (episodes) per object, all from the same grasp")
    selection: str = Field("validated", description=f"which records give grasps: {', '.join(SELECTIONS)}")
    splits: tuple[str, ...] = Field(SPLITS, min_length=1, description="splits to evaluate")
    seed: int = Field(0, description="torch seed given to GraspVecEnv")
    env: EnvConfig = Field(default_factory=EnvConfig)
    expert: ScriptedSettings = Field(default_factory=ScriptedSettings)
    scene: SceneConfig | None = Field(
        None, description="physics settings; None: the dataset's Stage 1 scene (num_envs set to envs)"
    )

    @field_validator("selection")
    @classmethod
    def _known_selection(cls, value: str) -> str:
        if value not in SELECTIONS:
            raise ValueError(f"unknown selection '{value}'; choose one of {', '.join(SELECTIONS)}")
        return value

    @field_validator("splits")
    @classmethod
    def _known_splits(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        unknown = [s for s in value if s not in SPLITS]
        if unknown:
            raise ValueError(f"unknown splits {unknown}; choose from {', '.join(SPLITS)}")
        return value


ExpertFactory = Callable[[GraspEnv, BaselineConfig], Expert]
"""Builds the expert for one object's env (its layouts) and the run's settings."""


def scripted_expert(env: GraspEnv, config: BaselineConfig) -> Expert:
    """The scripted baseline expert with ``config.expert`` settings, closing with the hand's squeeze."""
    return ScriptedExpert(env.obs_layout, env.act_layout, hand=env.hand, **config.expert.kwargs())


# -- one object ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class EpisodeOutcome:
    """One episode per env: lists of n entries."""

    reasons: list[str]
    """EndReason name (lower case) per env; 'running' if the env never ended."""
    peers: list[bool]
    """The peers' protocol succeeded in the episode."""
    max_rise: list[float]
    """Highest rise of the object above its start, m."""
    steps: list[int]
    """Control steps the episode lasted."""


def run_episodes(venv: GraspVecEnv, expert: Expert) -> EpisodeOutcome:
    """Act until every env has ended its first episode (envs that end early are reset and ignored)."""
    n = venv.num_envs
    reason = torch.zeros(n, dtype=torch.long)
    peers, rise = torch.zeros(n, dtype=torch.bool), torch.zeros(n, dtype=torch.float64)
    steps, finished = torch.zeros(n, dtype=torch.long), torch.zeros(n, dtype=torch.bool)
    expert.reset()
    obs = venv.get_observations()["policy"]
    for t in range(1, venv.max_episode_length + 1):
        obs_td, _, done, extras = venv.step(expert.act(obs))
        obs, done = obs_td["policy"], done.bool()
        new = done & ~finished
        reason[new], peers[new] = extras["end_reason"][new], extras["peer_success"][new]
        rise[new], steps[new] = extras["max_rise"][new], t
        finished |= new
        if finished.all():
            break
        if done.any():
            expert.reset(done.nonzero().flatten())
    return EpisodeOutcome(
        [EndReason(int(r)).name.lower() for r in reason], peers.tolist(), rise.tolist(), steps.tolist()
    )


def evaluate_object(
    registry, hand, record: GraspRecord, library, config: BaselineConfig, scene: SceneConfig, factory: ExpertFactory
) -> dict:
    """JSON-ready result of one object: episodes in a fresh simulator (closed afterwards).

    A GesError while setting the object up (no collision model, bad grasp, backend failure) gives
    every env the reason ``error`` and the message under ``"error"``; the run goes on.
    """
    start = time.perf_counter()
    result = {"object_id": record.object_id, "category": record.category, "split": record.split}
    result["grasp_key"] = grasp_key(record)
    n = config.envs
    try:
        asset = library.get(record.object_id)
        pose = object_rest_pose(registry, config.sim, asset, scene)
        targets = grasp_targets(record, hand.description, n, pose)
        sim = registry.build_sim(config.sim, scene)
        try:
            outcome = _episodes(sim, hand, asset, targets, config, factory)
        finally:
            sim.close()
    except GesError as error:
        outcome = EpisodeOutcome(["error"] * n, [False] * n, [0.0] * n, [0] * n)
        result["error"] = f"{type(error).__name__}: {error}"
    return {
        **result,
        "envs": n,
        "end_reasons": outcome.reasons,
        "paper_success": sum(r == "success" for r in outcome.reasons),
        "peers_success": int(sum(outcome.peers)),
        "peers": outcome.peers,
        "max_rise": [round(float(x), 5) for x in outcome.max_rise],
        "steps": outcome.steps,
        "seconds": round(time.perf_counter() - start, 3),
    }


def _episodes(sim, hand, asset, targets, config: BaselineConfig, factory: ExpertFactory) -> EpisodeOutcome:
    env = GraspEnv(sim, hand, asset, targets, config.env)
    try:
        venv = GraspVecEnv(env, seed=config.seed)  # full reset: stage one reaching, every env together
    except SimulationError:  # blew up before the expert acted: no episode to run
        n = config.envs
        return EpisodeOutcome(["unstable"] * n, [False] * n, [0.0] * n, [0] * n)
    return run_episodes(venv, factory(env, config))


def grasp_key(record: GraspRecord) -> str:
    """16 hex digits identifying the record's grasp and pre-grasp (a changed record is evaluated again)."""
    h = hashlib.sha256()
    for pose in (record.grasp, record.pregrasp):
        if pose is not None:
            h.update(np.ascontiguousarray(pose.wrist_pose).tobytes() + np.ascontiguousarray(pose.q).tobytes())
    h.update(",".join(record.joint_names).encode())
    return h.hexdigest()[:16]


# -- the results file --------------------------------------------------------------------------
def results_path(out: str | Path, config: BaselineConfig) -> Path:
    """``<out>/baseline-<hand>-<sim>.json``."""
    return Path(out) / f"baseline-{config.hand}-{config.sim}.json"


def _header(config: BaselineConfig, expert: str, defaults: dict) -> dict:
    """What a stored result depends on: the expert, its defaults and every setting but the record choice."""
    settings = config.model_dump(mode="json", exclude={"selection", "splits"})
    return {"expert": expert, "expert_defaults": defaults, "config": settings}


def _read_results(path: Path, header: dict) -> dict[str, dict]:
    """Stored per-object results of a run with ``header``; {} if there is no file yet."""
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise AssetError(f"cannot read baseline results {path}: {exc}; delete the file to start over") from exc
    if not isinstance(data, dict) or data.get("format") != RESULTS_FORMAT:
        raise AssetError(f"{path} is not a baseline results file (format {RESULTS_FORMAT!r}); choose another --out")
    if data.get("version") != RESULTS_VERSION:
        raise AssetError(
            f"{path} holds baseline results of version {data.get('version')!r}, this code reads {RESULTS_VERSION}; "
            "choose another --out or delete the file to start over"
        )
    diffs = config_differences(data.get("run"), header)
    if diffs:
        raise ConfigError(
            f"baseline results {path} were written with other settings ({'; '.join(diffs)}); choose another "
            "--out, rerun with those settings, or delete the file to start over",
            problems=diffs,
        )
    return dict(data.get("objects", {}))


def _write_results(path: Path, header: dict, dataset: Path, objects: dict[str, dict]) -> None:
    data = {
        "format": RESULTS_FORMAT,
        "version": RESULTS_VERSION,
        "updated": utc_now(),
        "dataset": str(dataset),
        "run": header,
        "objects": objects,
    }
    atomic_write_text(path, json.dumps(data, indent=1) + "\n")


# -- the summary -----------------------------------------------------------------------------------
@dataclass
class SplitRow:
    """One line of the summary table."""

    split: str
    objects: int = 0
    """Objects evaluated."""
    considered: int = 0
    """Objects of the hand in the dataset (before the selection rule)."""
    episodes: int = 0
    paper: int = 0
    """Episodes that met the paper's protocol."""
    peers: int = 0
    """Episodes that met the peers' protocol."""
    reasons: Counter = field(default_factory=Counter)

    @property
    def paper_rate(self) -> float | None:
        """Paper-protocol success rate over episodes (None without episodes)."""
        return self.paper / self.episodes if self.episodes else None

    @property
    def peers_rate(self) -> float | None:
        """Peers-protocol success rate over episodes (None without episodes)."""
        return self.peers / self.episodes if self.episodes else None

    def to_dict(self) -> dict:
        """JSON-ready."""
        return {
            "split": self.split, "objects": self.objects, "considered": self.considered, "episodes": self.episodes,
            "paper_success": self.paper, "peers_success": self.peers, "paper_rate": self.paper_rate,
            "peers_rate": self.peers_rate, "end_reasons": {r: self.reasons.get(r, 0) for r in REASONS},
        }  # fmt: skip


def summarize(results: list[dict], considered: dict[str, int], splits: tuple[str, ...] = SPLITS) -> list[SplitRow]:
    """One row per split in ``splits`` and an ``all`` row; considered: split -> objects in the dataset."""
    rows = {s: SplitRow(s, considered=considered.get(s, 0)) for s in splits}
    total = SplitRow("all", considered=sum(considered.get(s, 0) for s in splits))
    for res in results:
        if res["split"] not in rows:
            continue
        for row in (rows[res["split"]], total):
            row.objects += 1
            row.episodes += res["envs"]
            row.paper += res["paper_success"]
            row.peers += res["peers_success"]
            row.reasons.update(res["end_reasons"])
    return [*rows.values(), total]


def format_table(rows: list[SplitRow], header: str = "") -> str:
    """Markdown table of ``rows`` under an optional header line."""
    reasons = [r for r in REASONS if any(row.reasons.get(r) for row in rows)] or ["success"]
    lines = [header, ""] if header else []
    lines.append("| split | objects | episodes | success (paper) | success (peers) | " + " | ".join(reasons) + " |")
    lines.append("|---" * (5 + len(reasons)) + "|")
    for row in rows:
        cells = [row.split, f"{row.objects}/{row.considered}", str(row.episodes)]
        cells += [_rate(row.paper, row.episodes), _rate(row.peers, row.episodes)]
        cells += [str(row.reasons.get(r, 0)) for r in reasons]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _rate(k: int, n: int) -> str:
    return f"{100 * k / n:.1f} % ({k}/{n})" if n else "-"


# -- the run -------------------------------------------------------------------------------------
@dataclass
class BaselineReport:
    """What :func:`evaluate_baseline` did and found."""

    path: Path
    """The results file."""
    config: BaselineConfig
    selection: GraspSelection
    results: list[dict]
    """Per evaluated object (this run's and reused), dataset order."""
    evaluated: list[str] = field(default_factory=list)
    """Objects evaluated by this run."""
    reused: list[str] = field(default_factory=list)
    """Objects whose stored result was reused (resume)."""
    seconds: float = 0.0
    expert_name: str = "scripted"

    def rows(self) -> list[SplitRow]:
        """The summary rows (per split in the config, then all)."""
        considered = Counter(s for s in self.selection.splits.values())
        return summarize(self.results, dict(considered), self.config.splits)

    def header(self) -> str:
        """One line: expert, hand, simulator, selection rule, envs."""
        c = self.config
        sims = sorted({r.simulator for r in self.selection.records}) or ["-"]
        return (
            f"{self.expert_name} expert | hand {c.hand} | sim {c.sim} | grasps: selection '{c.selection}' "
            f"({SELECTIONS[c.selection]}), refined in {', '.join(sims)} | {c.envs} env(s) per object | "
            f"objects = evaluated / the hand's records in the split"
        )

    def table(self) -> str:
        """Header and markdown table."""
        return format_table(self.rows(), self.header())


def evaluate_baseline(
    dataset: str | Path,
    config: BaselineConfig,
    out: str | Path,
    *,
    registry=None,
    progress: bool = False,
    expert: ExpertFactory = scripted_expert,
    expert_name: str = "scripted",
) -> BaselineReport:
    """Evaluate ``expert`` on the records of ``config.hand`` that pass ``config.selection``.

    registry: a :class:`~ges_core.registry.Registry` (default: ``load_registry()``). Results are
    written to :func:`results_path` after every object; stored results are reused (resume).
    """
    start = time.perf_counter()
    if expert is scripted_expert and not config.env.goal_prior:
        raise ConfigError(
            "the scripted expert reads the goal blocks (goal_pos, goal_q) of the observation; it cannot run "
            "with env.goal_prior=false (NoGoal). Evaluate a learned expert there, or keep goal_prior=true"
        )
    data = open_grasp_dataset(dataset)
    if registry is None:
        from ges_core.registry import load_registry

        registry = load_registry()
    selection = select_records(data, config.hand, selection=config.selection)
    records = [r for r in selection.records if r.split in config.splits]
    defaults = scripted_defaults() if expert is scripted_expert else {}
    path, header = results_path(out, config), _header(config, expert_name, defaults)
    store = _read_results(path, header)  # every stored object (those outside this selection stay in the file)
    report = BaselineReport(path, config, selection, [], expert_name=expert_name)
    todo = [r for r in records if store.get(r.object_id, {}).get("grasp_key") != grasp_key(r)]
    fresh = {r.object_id for r in todo}
    report.reused = [r.object_id for r in records if r.object_id not in fresh]
    if todo:
        from tqdm import tqdm

        hand, library, scene = registry.build_hand(config.hand), library_for(data), _scene(data, config)
        bar = tqdm(todo, disable=not progress, unit="object", desc=f"{config.hand}/{config.sim}", dynamic_ncols=True)
        for record in bar:
            store[record.object_id] = evaluate_object(registry, hand, record, library, config, scene, expert)
            report.evaluated.append(record.object_id)
            _write_results(path, header, data.root.resolve(), store)
            bar.set_postfix(success=sum(store[oid]["paper_success"] for oid in report.evaluated))
    report.results = [store[r.object_id] for r in records]
    report.seconds = time.perf_counter() - start
    return report


def _scene(data, config: BaselineConfig) -> SceneConfig:
    """The run's physics: ``config.scene``, else the dataset's Stage 1 scene; num_envs = envs."""
    scene = config.scene
    if scene is None:
        stored = data.run_config.get("scene") if isinstance(data.run_config, dict) else None
        scene = parse_model(SceneConfig, stored, where=f"{data.root} run_config.scene") if stored else SceneConfig()
    return scene.model_copy(update={"num_envs": config.envs})
