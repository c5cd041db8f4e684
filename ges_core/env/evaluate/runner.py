"""The episode runner: per selected record one fresh simulator, ``GraspEnv`` + ``GraspVecEnv`` and the expert.

:func:`evaluate_baseline` selects the records, skips those the results store already holds
(:mod:`~ges_core.env.evaluate.store`), runs the rest object by object (:func:`evaluate_object`,
:func:`run_episodes`) and returns a :class:`BaselineReport` whose table comes from
:mod:`~ges_core.env.evaluate.table`.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import torch

from ges_core.config import parse_model
from ges_core.dataset import GraspRecord
from ges_core.env.baseline import ScriptedExpert
from ges_core.env.evaluate.config import BaselineConfig, scripted_defaults
from ges_core.env.evaluate.store import grasp_key, read_results, results_header, results_path, write_results
from ges_core.env.evaluate.table import SplitRow, format_table, summarize
from ges_core.env.grasp_env import GraspEnv
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
from ges_core.errors import ConfigError, GesError, SimulationError
from ges_core.policy import Expert
from ges_core.sim import SceneConfig

__all__ = [
    "BaselineReport",
    "EpisodeOutcome",
    "ExpertFactory",
    "evaluate_baseline",
    "evaluate_object",
    "run_episodes",
    "scripted_expert",
]


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
    path, header = results_path(out, config), results_header(config, expert_name, defaults)
    store = read_results(path, header)  # every stored object (those outside this selection stay in the file)
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
            write_results(path, header, data.root.resolve(), store)
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
