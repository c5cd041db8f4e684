"""The episode runner: per selected record one fresh simulator, ``GraspEnv`` + ``GraspVecEnv`` and the expert.

:func:`evaluate_baseline` selects the records, skips those the results store already holds
(:mod:`~ges_core.env.evaluate.store`), runs the rest object by object (:func:`evaluate_object`,
:func:`run_episodes`) and returns a :class:`BaselineReport` whose table comes from
:mod:`~ges_core.env.evaluate.table`.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import torch

from ges_core.config import parse_model
from ges_core.dataset import GraspRecord
from ges_core.env.evaluate.config import BaselineConfig
from ges_core.env.evaluate.store import grasp_key, read_results, results_header, results_path, write_results
from ges_core.env.evaluate.table import SplitRow, format_table, summarize
from ges_core.env.grasp_env import GraspEnv
from ges_core.env.grasp_source import (
    SELECTIONS,
    GraspSelection,
    grasp_targets,
    object_rest_pose,
    open_grasp_dataset,
    record_asset,
    select_records,
)
from ges_core.env.metrics import METRIC_NAMES
from ges_core.env.success import EndReason
from ges_core.env.vec_env import GraspVecEnv
from ges_core.errors import GesError, SimulationError
from ges_core.policy import Expert, ExpertContext
from ges_core.sim import SceneConfig

__all__ = [
    "BaselineReport",
    "EpisodeOutcome",
    "build_expert_for",
    "config_records",
    "dataset_scene",
    "evaluate_baseline",
    "evaluate_object",
    "expert_defaults",
    "run_episodes",
]


def build_expert_for(registry, config: BaselineConfig, env: GraspEnv) -> Expert:
    """``config.expert`` with ``config.expert_settings`` over its registered settings, built for ``env``
    (:meth:`~ges_core.registry.Registry.build_expert`: an expert made for another hand or layout is refused)."""
    context = ExpertContext.of_env(env, sim=config.sim, registry=registry)
    return registry.build_expert(config.expert, context, **config.expert_settings)


def expert_defaults(registry, config: BaselineConfig) -> dict:
    """The settings ``config.expert`` is built with before ``config.expert_settings``: its plugin's, then
    registry.yaml's (stored with results: a changed default invalidates them). UnknownNameError for an unknown
    expert."""
    return dict(registry.settings("expert", config.expert))


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
    metrics: dict[str, list[float]] = field(default_factory=dict)
    """Table 3 metric name (:data:`~ges_core.env.metrics.METRIC_NAMES`) -> per env its episode's value (sums over
    the episode, :mod:`~ges_core.env.metrics`); NaN for an env that never acted (an error before the episode)."""


def run_episodes(venv: GraspVecEnv, expert: Expert) -> EpisodeOutcome:
    """Act until every env has ended its first episode (envs that end early are reset and ignored)."""
    n = venv.num_envs
    reason = torch.zeros(n, dtype=torch.long)
    peers, rise = torch.zeros(n, dtype=torch.bool), torch.zeros(n, dtype=torch.float64)
    steps, finished = torch.zeros(n, dtype=torch.long), torch.zeros(n, dtype=torch.bool)
    metrics = {name: torch.full((n,), float("nan"), dtype=torch.float64) for name in METRIC_NAMES}
    expert.reset()
    obs = venv.get_observations()["policy"]
    for t in range(1, venv.max_episode_length + 1):
        obs_td, _, done, extras = venv.step(expert.act(obs))
        obs, done = obs_td["policy"], done.bool()
        new = done & ~finished
        reason[new], peers[new] = extras["end_reason"][new], extras["peer_success"][new]
        rise[new], steps[new] = extras["max_rise"][new], t
        if new.any():
            for name, values in metrics.items():
                values[new] = extras["episode_metrics"][name][new]
        finished |= new
        if finished.all():
            break
        if done.any():
            expert.reset(done.nonzero().flatten())
    return EpisodeOutcome(
        [EndReason(int(r)).name.lower() for r in reason], peers.tolist(), rise.tolist(), steps.tolist(),
        {name: values.tolist() for name, values in metrics.items()},
    )  # fmt: skip


def evaluate_object(registry, hand, record: GraspRecord, library, config: BaselineConfig, scene: SceneConfig) -> dict:
    """JSON-ready result of one object: ``config.envs`` episodes of ``config.expert`` in a fresh simulator (closed
    afterwards).

    A GesError while setting the object up (no collision model, bad grasp, backend failure) or while its episodes
    run gives every env the reason ``error`` and the message under ``"error"``; the run goes on. An expert that
    cannot be built (unknown setting, made for another hand) is the caller's error and propagates.
    """
    start = time.perf_counter()
    result = {"object_id": record.object_id, "category": record.category, "split": record.split}
    result["grasp_key"] = grasp_key(record)
    n, sim = config.envs, None
    try:
        asset = record_asset(library, record)
        pose = object_rest_pose(registry, config.sim, asset, scene)
        targets = grasp_targets(record, hand.description, n, pose)
        sim = registry.build_sim(config.sim, scene)
        env = GraspEnv(sim, hand, asset, targets, config.env)
    except GesError as error:
        if sim is not None:
            sim.close()
        return _result(result, _failed(n, "error"), start, error)
    try:
        expert = build_expert_for(registry, config, env)
        outcome, error = _episodes(env, expert, config)
    finally:
        sim.close()
    return _result(result, outcome, start, error)


def _failed(n: int, reason: str) -> EpisodeOutcome:
    """Every env ended with ``reason`` before the expert acted."""
    return EpisodeOutcome([reason] * n, [False] * n, [0.0] * n, [0] * n, {m: [float("nan")] * n for m in METRIC_NAMES})


def _episodes(env: GraspEnv, expert: Expert, config: BaselineConfig) -> tuple[EpisodeOutcome, GesError | None]:
    try:
        venv = GraspVecEnv(env, seed=config.seed)  # full reset: stage one reaching, every env together
    except SimulationError:  # blew up before the expert acted: no episode to run
        return _failed(config.envs, "unstable"), None
    try:
        return run_episodes(venv, expert), None
    except GesError as error:
        return _failed(config.envs, "error"), error


def _result(result: dict, outcome: EpisodeOutcome, start: float, error: GesError | None) -> dict:
    """The JSON-ready row of one object (``result``: its id, category, split and grasp key)."""
    if error is not None:
        result["error"] = f"{type(error).__name__}: {error}"
    return {
        **result,
        "envs": len(outcome.reasons),
        "end_reasons": outcome.reasons,
        "paper_success": sum(r == "success" for r in outcome.reasons),
        "peers_success": int(sum(outcome.peers)),
        "peers": outcome.peers,
        "max_rise": [round(float(x), 5) for x in outcome.max_rise],
        "steps": outcome.steps,
        "metrics": {name: [_rounded(v) for v in values] for name, values in outcome.metrics.items()},
        "seconds": round(time.perf_counter() - start, 3),
    }


def _rounded(value: float) -> float | None:
    """A metric for JSON: 6 significant digits; None for NaN (no episode)."""
    return None if value != value else float(f"{value:.6g}")


def config_records(data, config: BaselineConfig, selection: GraspSelection | None = None) -> list[GraspRecord]:
    """The records a run evaluates: those of ``config.hand`` passing ``config.selection`` (``selection``, when
    already made) in ``config.splits``, in dataset order."""
    selection = selection or select_records(data, config.hand, selection=config.selection)
    return [r for r in selection.records if r.split in config.splits]


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

    def rows(self) -> list[SplitRow]:
        """The summary rows (per split in the config, then all)."""
        considered = Counter(s for s in self.selection.splits.values())
        return summarize(self.results, dict(considered), self.config.splits)

    def header(self) -> str:
        """One line: expert, hand, simulator, selection rule, envs."""
        c = self.config
        sims = sorted({r.simulator for r in self.selection.records}) or ["-"]
        return (
            f"{c.expert} expert{_settings_note(c)} | hand {c.hand} | sim {c.sim} | grasps: selection '{c.selection}' "
            f"({SELECTIONS[c.selection]}), refined in {', '.join(sims)} | {c.envs} env(s) per object | "
            f"objects = evaluated / the hand's records in the split"
        )

    def table(self) -> str:
        """Header and markdown table."""
        return format_table(self.rows(), self.header())


def _settings_note(config: BaselineConfig) -> str:
    """`` (close_steps=20)`` for an expert run with settings of its own, else ''."""
    given = ", ".join(f"{k}={v}" for k, v in config.expert_settings.items())
    return f" ({given})" if given else ""


def evaluate_baseline(
    dataset: str | Path,
    config: BaselineConfig,
    out: str | Path,
    *,
    registry=None,
    progress: bool = False,
    fanout=None,
) -> BaselineReport:
    """Evaluate ``config.expert`` on the records of ``config.hand`` that pass ``config.selection``.

    registry: a :class:`~ges_core.registry.Registry` (default: ``load_registry()``). Results are
    written to :func:`results_path` after every object; stored results are reused (resume).
    fanout: where the objects run (:class:`~ges_core.env.evaluate.fanout.Fanout`; default: here, in order).
    """
    from ges_core.env.evaluate.fanout import Cell, Fanout, evaluate_cells

    start = time.perf_counter()
    data = open_grasp_dataset(dataset)
    if registry is None:
        from ges_core.registry import load_registry

        registry = load_registry()
    path, header = results_path(out, config), results_header(config, expert_defaults(registry, config))
    selection = select_records(data, config.hand, selection=config.selection)
    records = config_records(data, config, selection)
    store = read_results(path, header, registry)  # every stored object (those outside this selection stay in the file)
    report = BaselineReport(path, config, selection, [])
    todo = [r for r in records if store.get(r.object_id, {}).get("grasp_key") != grasp_key(r)]
    fresh = {r.object_id for r in todo}
    report.reused = [r.object_id for r in records if r.object_id not in fresh]
    if todo:
        from tqdm import tqdm

        cells = [Cell(r.object_id, config) for r in todo]
        bar = tqdm(total=len(cells), disable=not progress, unit="object", desc=f"{config.hand}/{config.sim}",
                   dynamic_ncols=True)  # fmt: skip
        rows = evaluate_cells(data, cells, {r.object_id: r for r in todo}, registry, fanout or Fanout())
        for i, row in rows:
            store[cells[i].object_id] = row
            report.evaluated.append(cells[i].object_id)
            write_results(path, header, data.root.resolve(), store)
            bar.update(1)
            bar.set_postfix(success=sum(store[oid]["paper_success"] for oid in report.evaluated))
        bar.close()
    report.results = [store[r.object_id] for r in records]
    report.seconds = time.perf_counter() - start
    return report


def dataset_scene(data, envs: int, scene: SceneConfig | None = None) -> SceneConfig:
    """The run's physics: ``scene``, else the dataset's Stage 1 scene; ``num_envs = envs``."""
    if scene is None:
        stored = data.run_config.get("scene") if isinstance(data.run_config, dict) else None
        scene = parse_model(SceneConfig, stored, where=f"{data.root} run_config.scene") if stored else SceneConfig()
    return scene.model_copy(update={"num_envs": envs})
