"""One ``ges train-expert`` run: config -> setup -> GraspRunner -> checkpoints, logs and a summary.

    cfg = load_train_config("tiny", overrides=["iterations=50"])
    summary = train_expert("runs/tiny/dataset", cfg, "runs/tiny/experts/expert0", registry=load_registry())
    print(summary.table())

The run folder: ``config.yaml`` (the resolved TrainConfig), ``logs/`` (TensorBoard), ``checkpoints/``
(``last.pt`` + numbered), ``history.jsonl`` (one line per iteration), ``curriculum.log`` (promotions),
``summary.json``. ``resume=True`` continues from the newest loadable checkpoint; without it a folder that already
holds checkpoints is refused (so a run is never overwritten by accident).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import torch
import yaml

from ges_core.config import fill_absent
from ges_core.errors import ConfigError
from ges_core.paths import atomic_write_text
from ges_core.training.checkpoint import find_checkpoints, latest_loadable
from ges_core.training.config import EvaluationConfig, TrainConfig, load_train_config
from ges_core.training.envs import TrainingSetup, build_setup
from ges_core.training.runner import BEST, GraspRunner

__all__ = ["TrainSummary", "rsl_config", "train_expert", "train_from_args", "warm_start_active"]


@dataclass
class TrainSummary:
    """What a run did (also ``summary.json`` in the run folder)."""

    run_dir: str
    hand: str
    sim: str
    action_mode: str
    iterations: int
    env_steps: int
    seconds: float
    stopped: str
    """'done' (all iterations), 'time_limit', or 'interrupted' (Ctrl-C: the last checkpoint stands)."""
    stage: int
    promotions: list[str] = field(default_factory=list)
    episodes: int = 0
    success_paper: float = math.nan
    """Success rate (paper protocol) over every episode of the run."""
    success_peers: float = math.nan
    last_success_paper: float = math.nan
    """Over the episodes of the last iteration."""
    nan_actions: int = 0
    bad_updates: int = 0
    checkpoint: str = ""
    resumed_from: str | None = None
    warm_start: dict | None = None
    """The behaviour-cloning warm start's record (``warm_start.json``); None when it did not run in this call."""
    residual_scale: float | None = None
    """Residual mode: the scale the policy's output was trained at (the run's, else the hand's); None otherwise."""
    evaluation: dict | None = None
    """In-run evaluations (``evaluation.interval`` > 0): ``last`` and ``best`` paper success, ``best_iteration``,
    ``best_checkpoint`` (None: not kept), ``objects`` and ``episodes`` per object; None when off."""

    def table(self) -> str:
        """A few lines for the terminal."""
        rate = "-" if self.seconds <= 0 else f"{self.env_steps / self.seconds:,.0f}"
        lines = [
            f"expert run {self.run_dir} ({self.hand}, {self.sim}, action {self.action_mode}"
            + (f" x {self.residual_scale:g})" if self.residual_scale is not None else ")"),
            f"  iterations {self.iterations}, env steps {self.env_steps:,}, {self.seconds:.0f} s ({rate} steps/s), "
            f"stopped: {self.stopped}",
            f"  curriculum stage {self.stage}; promotions: {len(self.promotions)}",
            *[f"    {p}" for p in self.promotions],
            f"  episodes {self.episodes}: success {_pct(self.success_paper)} (paper), {_pct(self.success_peers)} "
            f"(peers); last iteration {_pct(self.last_success_paper)} (paper)",
            *([_warm_line(self.warm_start)] if self.warm_start else []),
            *([_evaluation_line(self.evaluation)] if self.evaluation else []),
            f"  NaN actions {self.nan_actions} (episodes ended unstable), undone updates {self.bad_updates}",
            f"  checkpoint {self.checkpoint}" + (f" (resumed from {self.resumed_from})" if self.resumed_from else ""),
        ]
        return "\n".join(lines)


def _warm_line(w: dict) -> str:
    loss = w["imitation_loss"]
    return (f"  warm start: {w['demo_env_steps']:,} demonstration steps ({w['demo_successes']}/{w['demo_episodes']} "
            f"episodes succeeded), imitation loss {loss[0]:.4f} -> {loss[-1]:.4f}")  # fmt: skip


def _evaluation_line(e: dict) -> str:
    where = f" -> {e['best_checkpoint']}" if e.get("best_checkpoint") else ""
    at = f" at iteration {e['best_iteration']}{where}" if e.get("best_iteration") is not None else ""
    return (f"  evaluation (noise-free, {e['objects']} object(s) x {e['episodes']} episode(s)): last "
            f"{_pct(e['last'])}, best {_pct(e['best'])}{at}")  # fmt: skip


def _pct(x: float) -> str:
    return "-" if x is None or math.isnan(x) else f"{100 * x:.1f} %"


def rsl_config(cfg: TrainConfig, residual: bool) -> dict:
    """The rsl-rl 5.5.1 runner config (separate actor/critic MLPModels, Gaussian actions, PPO)."""
    p = cfg.ppo
    groups = ["policy", "base_action"] if residual else ["policy"]
    std = p.init_noise_std if not residual else min(p.init_noise_std, 0.1)  # see ges_core.training.residual
    if warm_start_active(cfg):
        std = cfg.warm_start.init_std  # a cloned actor keeps its behaviour only under small noise (warm_start.py)
    model = {"class_name": "MLPModel", "activation": p.activation, "obs_normalization": p.obs_normalization}
    return {
        "num_steps_per_env": p.num_steps_per_env,
        "save_interval": cfg.checkpoint_interval,
        "obs_groups": {"actor": groups, "critic": groups},
        "actor": {**model, "hidden_dims": list(p.actor_hidden),
                  "distribution_cfg": {"class_name": "GaussianDistribution", "init_std": std}},
        "critic": {**model, "hidden_dims": list(p.critic_hidden)},
        "algorithm": {
            "class_name": "PPO", "learning_rate": p.learning_rate, "schedule": p.schedule, "desired_kl": p.desired_kl,
            "num_learning_epochs": p.num_learning_epochs, "num_mini_batches": p.num_mini_batches,
            "clip_param": p.clip_param, "gamma": p.gamma, "lam": p.lam, "entropy_coef": p.entropy_coef,
            "value_loss_coef": p.value_loss_coef, "max_grad_norm": p.max_grad_norm,
            "use_clipped_value_loss": p.clipped_value_loss,
        },
        "check_for_nan": True,
        "logger": "tensorboard",
    }  # fmt: skip


def warm_start_active(cfg: TrainConfig) -> bool:
    """The behaviour-cloning warm start runs: switched on and the absolute action mode."""
    return cfg.warm_start.enabled and cfg.action_mode == "absolute"


def _demonstrator(setup: TrainingSetup, cfg: TrainConfig, registry):
    """The Expert the warm start imitates (None when it does not run). It reads the observation with the goal
    blocks even where the policy's has none (NoGoal, ``env.goal_prior=false``): a teacher that knows the goal
    (:func:`ges_core.training.warm_start.collect_demonstrations` puts it in)."""
    if not warm_start_active(cfg):
        return None
    from ges_core.policy import ExpertContext

    context = ExpertContext.of_env(setup.env, sim=setup.sim, registry=registry)
    context = replace(context, obs_layout=context.obs_layout.with_goal())
    return registry.build_expert(cfg.warm_start.expert, context, **cfg.warm_start.expert_settings)


def _meta(setup: TrainingSetup, cfg: TrainConfig, train_cfg: dict, runner: GraspRunner) -> dict:
    """The checkpoint's fixed ``ges`` fields: what the expert was made for and what rebuilds it."""
    from ges_core.policy import ExpertContext, ExpertScope

    env = setup.env
    obs = setup.venv.get_observations()
    groups = train_cfg["obs_groups"]["actor"]
    return {
        "made_for": ExpertScope.of(ExpertContext.of_env(env)).to_dict(),
        "model": {
            "obs_groups": groups, "group_sizes": {g: int(obs[g].shape[1]) for g in groups},
            "actor": train_cfg["actor"], "num_actions": setup.venv.num_actions,
        },
        "action_mode": cfg.action_mode, "residual_scale": cfg.residual_scale, "base_expert": cfg.base_expert,
        "base_expert_settings": cfg.base_expert_settings,
        "hand": setup.hand, "sim": setup.sim, "train_config": cfg.model_dump(mode="json"),
        "objects": list(setup.pool.keys),
    }  # fmt: skip


def _zero_output_layer(runner: GraspRunner) -> None:
    """Residual mode: the actor's mean starts at 0, so the first actions are the base expert's."""
    last = [m for m in runner.alg.actor.mlp.modules() if isinstance(m, torch.nn.Linear)][-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()


def train_expert(
    dataset: str | Path,
    cfg: TrainConfig,
    out: str | Path,
    *,
    registry,
    clusters=None,
    resume: bool = False,
    progress: bool = True,
) -> TrainSummary:
    """Train one expert (module docs); ``clusters``: a Clusters (None: curriculum off or no clusters needed)."""
    out = Path(out)
    previous = latest_loadable(out / "checkpoints") if resume else None
    if not resume and (find_checkpoints(out / "checkpoints") or (out / "checkpoints" / "last.pt").exists()):
        raise ConfigError(f"{out} already holds checkpoints of a run; pass --resume to continue it, or another --out")
    if resume and previous is not None:
        update = {"iterations": cfg.iterations, "time_limit": cfg.time_limit}
        if cfg.evaluation != EvaluationConfig():  # evaluations leave the training alone: a resume may set them
            update["evaluation"] = cfg.evaluation.model_dump()
        stored = fill_absent(TrainConfig, previous[1]["ges"]["train_config"])  # a later setting: what it ran with
        cfg = TrainConfig.model_validate(stored | update)
    torch.manual_seed(cfg.seed)
    setup = build_setup(dataset, cfg, registry, clusters)
    cfg = setup.config  # with the hand's settings.train (what the run left unset)
    try:
        train_cfg = rsl_config(cfg, cfg.action_mode == "residual")
        runner = GraspRunner(setup.venv, train_cfg, out, curriculum=setup.curriculum, meta={}, settings=cfg,
                             demonstrator=_demonstrator(setup, cfg, registry))  # fmt: skip
        runner.meta = _meta(setup, cfg, train_cfg, runner)
        if cfg.action_mode == "residual":
            _zero_output_layer(runner)
        if cfg.evaluation.interval:
            from ges_core.training.evaluation import InRunEvaluator

            runner.evaluator = InRunEvaluator.for_run(cfg, setup, registry)
        if previous is not None:
            runner.resume_from(previous[1])
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(out / "config.yaml", yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False))
        stopped = _learn(runner, cfg, progress)
        summary = _summary(out, setup, cfg, runner, stopped, previous)
        atomic_write_text(out / "summary.json", __import__("json").dumps(asdict(summary), indent=1) + "\n")
        return summary
    finally:
        setup.venv.close()


def _learn(runner: GraspRunner, cfg: TrainConfig, progress: bool) -> str:
    """Run the remaining iterations under a progress bar; 'interrupted' on Ctrl-C (the last checkpoint stands)."""
    from tqdm import tqdm

    todo = cfg.iterations - runner.current_learning_iteration
    if todo <= 0:
        return "done"
    bar = tqdm(total=cfg.iterations, initial=runner.current_learning_iteration, desc="ppo", unit="it",
               disable=not progress)  # fmt: skip

    def tick(done: int, row: dict) -> None:
        bar.update(1)
        bar.set_postfix(stage=row["stage"], success=row["success_paper"], steps=row["env_steps"], refresh=False)

    runner.on_iteration = tick
    runner.on_promotion = bar.write
    runner.on_evaluation = bar.write
    if runner.evaluator is not None:
        runner.evaluator.on_object = lambda done, total: bar.set_postfix_str(f"evaluating {done}/{total} objects")
    try:
        return runner.learn(todo)
    except KeyboardInterrupt:
        return "interrupted"
    finally:
        bar.close()


def _summary(out: Path, setup, cfg: TrainConfig, runner: GraspRunner, stopped: str, previous) -> TrainSummary:
    t = runner.totals
    last = runner.last_counts
    ckpt = out / "checkpoints" / "last.pt"
    return TrainSummary(
        run_dir=str(out), hand=setup.hand, sim=setup.sim, action_mode=cfg.action_mode,
        iterations=runner.current_learning_iteration, env_steps=t["env_steps"], seconds=round(runner.seconds, 1),
        stopped=stopped, stage=runner.curriculum.stage,
        promotions=[p.describe() for p in runner.curriculum.history], episodes=t["episodes"],
        success_paper=t["paper"] / t["episodes"] if t["episodes"] else math.nan,
        success_peers=t["peers"] / t["episodes"] if t["episodes"] else math.nan,
        last_success_paper=last.rate("paper"), nan_actions=t["nan_actions"], bad_updates=t["bad_updates"],
        checkpoint=str(ckpt) if ckpt.exists() else "", resumed_from=str(previous[0]) if previous else None,
        warm_start=getattr(runner, "warm_start_record", None),
        residual_scale=cfg.residual_scale if cfg.action_mode == "residual" else None,
        evaluation=_evaluation_summary(out, cfg, runner),
    )  # fmt: skip


def _evaluation_summary(out: Path, cfg: TrainConfig, runner: GraspRunner) -> dict | None:
    if runner.evaluator is None:
        return None
    best = out / "checkpoints" / BEST
    kept = {k: runner.evaluation[k] for k in ("last", "best", "best_iteration")}  # per-object rows: evaluations.jsonl
    return {**kept, "best_checkpoint": str(best) if best.exists() else None,
            "objects": len(runner.evaluator.objects), "episodes": cfg.evaluation.episodes}  # fmt: skip


def train_from_args(args, registry) -> TrainSummary:
    """``ges train-expert``'s arguments -> :func:`train_expert`."""
    overrides = list(args.overrides)
    for key, value in (("hand", args.hand), ("sim", args.sim), ("num_envs", args.envs),
                       ("iterations", args.iterations), ("seed", args.seed), ("cluster", args.cluster)):  # fmt: skip
        if value is not None:
            overrides.append(f"{key}={value}")
    cfg = load_train_config(args.preset, args.config, overrides)
    clusters = _clusters(args, cfg)
    name = args.name or (f"expert{cfg.cluster}" if cfg.objects is None else "expert_hard")
    out = args.out or Path(args.dataset).parent / "experts" / name
    started = time.perf_counter()
    summary = train_expert(args.dataset, cfg, out, registry=registry, clusters=clusters, resume=args.resume,
                           progress=not args.no_progress)  # fmt: skip
    summary.seconds = summary.seconds or round(time.perf_counter() - started, 1)
    return summary


def _clusters(args, cfg: TrainConfig):
    """The clustering the curriculum needs (None when it is off and no object set is given)."""
    if not cfg.curriculum.enabled and cfg.objects is None and args.clusters is None:
        return None
    from ges_core.clustering import load_clusters

    return load_clusters(args.clusters or args.dataset)
