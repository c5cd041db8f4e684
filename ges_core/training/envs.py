"""What a training run trains on: the dataset's training grasps as a pool, the curriculum, the vectorized env."""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from pathlib import Path

from ges_core.dataset.hands import warn_if_hand_changed
from ges_core.env.evaluate.runner import dataset_scene
from ges_core.env.grasp_env import EnvConfig, GraspEnv
from ges_core.env.grasp_pool import GraspPool
from ges_core.env.grasp_source import GraspSelection, dataset_hand, library_for, open_grasp_dataset, select_records
from ges_core.env.reward import reward_preset
from ges_core.env.vec_env import GraspVecEnv
from ges_core.env.workers import SubprocVecEnv
from ges_core.errors import AssetError, ConfigError
from ges_core.hand_prep.prepare import built_prepared
from ges_core.hand_settings import hand_train_config
from ges_core.sim import SceneConfig
from ges_core.training.config import TrainConfig
from ges_core.training.curriculum import Curriculum

__all__ = ["TrainingSetup", "build_setup", "env_config", "training_grasps", "worker_env"]


@dataclass
class TrainingSetup:
    """The pieces of one run: names, the pool, the curriculum and the (possibly residual) vectorized env."""

    hand: str
    sim: str
    pool: GraspPool
    curriculum: Curriculum
    venv: object
    """A GraspVecEnv (``workers: 1``) or a SubprocVecEnv, or a ResidualVecEnv around one (``action_mode:
    residual``)."""
    grasps: GraspSelection
    """The training records the pool was built from (one per object) and the objects left out, with why."""
    config: TrainConfig
    """The run's config as the env was built from it: the given one with the hand's ``settings.train`` filling
    what it did not set (:func:`ges_core.hand_settings.hand_train_config`)."""
    hand_model: object
    """The run's HandModel (prepared as Stage 1's; what the in-run evaluation builds its envs with)."""
    dataset: object
    """The opened Stage 1 dataset (:func:`~ges_core.env.grasp_source.open_grasp_dataset`)."""
    library: object
    """Its ObjectLibrary (:func:`~ges_core.env.grasp_source.library_for`), the pool's objects' source."""
    scene: SceneConfig
    """The run's physics with ``num_envs = config.num_envs``: ``config.scene``, else the dataset's Stage 1 scene (what
    ``ges eval-experts`` scores the expert in). The envs, the env workers' and the in-run evaluation's."""

    @property
    def rejected(self) -> dict[str, str]:
        """Training objects left out by the grasp selection: object id -> why."""
        return dict(self.grasps.rejected)

    @property
    def env(self):
        """The GraspEnv, or with env workers its :class:`~ges_core.env.workers.EnvView` (no simulator here)."""
        return self.venv.env


def env_config(cfg: TrainConfig) -> EnvConfig:
    """The run's EnvConfig: ``cfg.env`` with the reward preset's weights and the run's seed for the randomization."""
    update = {"randomization": cfg.env.randomization.model_copy(update={"seed": cfg.seed})}
    if cfg.reward_preset != "custom":
        update["reward"] = reward_preset(cfg.reward_preset)
    return cfg.env.model_copy(update=update)


def training_grasps(dataset, hand_name: str, cfg: TrainConfig) -> GraspSelection:
    """The opened ``dataset``'s (:func:`~ges_core.env.grasp_source.open_grasp_dataset`) training records of
    ``hand_name`` that pass ``cfg.selection`` (the first ``max_objects`` by id), and the rejected ones."""
    chosen = select_records(dataset, hand_name, split="train", selection=cfg.selection)
    if cfg.max_objects is not None:
        keep = sorted(r.object_id for r in chosen.records)[: cfg.max_objects]
        chosen = type(chosen)(chosen.hand, chosen.selection, tuple(r for r in chosen.records if r.object_id in keep),
                              chosen.rejected, chosen.splits)  # fmt: skip
    return chosen


def build_setup(dataset_path: str | Path, cfg: TrainConfig, registry, clusters=None) -> TrainingSetup:
    """Pool, curriculum (``clusters``: a :class:`~ges_core.clustering.Clusters`; None only with the curriculum off
    and no ``objects``) and the vectorized env of a run; the hand's ``settings.train`` fills what ``cfg`` leaves
    unset (``TrainingSetup.config``)."""
    hand_name, sim_name = dataset_hand(dataset_path, registry, cfg.hand), cfg.sim or registry.default("sim")
    hand = built_prepared(registry, hand_name)  # decomposed as ges synth does, so the hand is Stage 1's
    data = open_grasp_dataset(dataset_path)
    warn_if_hand_changed(data.manifest, data.root, hand_name, hand)
    cfg = hand_train_config(hand.description, cfg)
    grasps, library = training_grasps(data, hand_name, cfg), library_for(data)
    pool = GraspPool.from_selection(grasps, hand, library)  # AssetError when no record is usable
    curriculum = _curriculum(cfg, clusters, pool)
    pool.set_weights(curriculum.weights())
    scene = dataset_scene(data, cfg.num_envs, cfg.scene)
    venv = _vec_env(cfg, registry, hand, sim_name, pool, scene)
    if cfg.action_mode == "residual":
        from ges_core.policy import ExpertContext
        from ges_core.training.residual import ResidualVecEnv

        context = ExpertContext.of_env(venv.env, sim=sim_name, registry=registry)
        base = registry.build_expert(cfg.base_expert, context, **cfg.base_expert_settings)
        venv = ResidualVecEnv(venv, base, cfg.residual_scale)
    return TrainingSetup(hand_name, sim_name, pool, curriculum, venv, grasps, cfg, hand, data, library, scene)


def _vec_env(
    cfg: TrainConfig, registry, hand, sim_name: str, pool: GraspPool, scene: SceneConfig
) -> GraspVecEnv | SubprocVecEnv:
    """``cfg.workers == 1``: a GraspVecEnv in this process; more: a SubprocVecEnv whose workers each build their
    slice of the envs (the registry rebuilt there through ``registry.rebuild``; the pool, weights included,
    pickled). ``scene``: the run's physics (:attr:`TrainingSetup.scene`); each worker sets its own ``num_envs``."""
    if cfg.workers == 1:
        sim = registry.build_sim(sim_name, scene)
        return GraspVecEnv(GraspEnv.from_pool(sim, hand, pool, env_config(cfg)), seed=cfg.seed)
    if getattr(registry, "rebuild", None) is None:
        raise ConfigError(
            "env workers rebuild the registry in each worker process: build it with ges_core.registry.load_registry "
            "(it records how), or set workers=1"
        )
    make = partial(worker_env, registry.rebuild, hand.name, sim_name, pool, env_config(cfg), scene=scene)
    return SubprocVecEnv(make, cfg.num_envs, cfg.workers, hand=hand, pool=pool, seed=cfg.seed)


def worker_env(
    rebuild,
    hand_name: str,
    sim_name: str,
    pool: GraspPool,
    cfg: EnvConfig,
    env_ids,
    *,
    scene: SceneConfig,
) -> GraspEnv:
    """One env worker's GraspEnv (called in the worker): envs ``env_ids`` (global ids, seeding their streams);
    ``scene``: the run's physics (:attr:`TrainingSetup.scene`), ``num_envs`` set to ``len(env_ids)``."""
    registry = rebuild()
    sim = registry.build_sim(sim_name, scene.model_copy(update={"num_envs": len(env_ids)}))
    return GraspEnv.from_pool(sim, registry.build_hand(hand_name), pool, cfg, env_index=env_ids)


def _curriculum(cfg: TrainConfig, clusters, pool: GraspPool) -> Curriculum:
    available = sorted(set(pool.keys))
    if clusters is None:
        if cfg.curriculum.enabled or cfg.objects is not None:
            raise AssetError(
                "the curriculum needs the dataset's clusters: run 'ges cluster DATASET' (it writes "
                "DATASET/clusters.json) or pass --clusters FILE; -o curriculum.enabled=false trains on every "
                "training object without stages"
            )
        return Curriculum(cfg.curriculum, {s: available for s in cfg.curriculum.stages})
    return Curriculum.for_cluster(cfg.curriculum, clusters, cfg.cluster, available, objects=cfg.objects)
