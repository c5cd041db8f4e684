"""The three-stage curriculum: stage objects from a (hand-written) clusters file, the promotion rule, resume."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ges_core.clustering import ClusterMember, Clusters, load_clusters, save_clusters
from ges_core.errors import AssetError, ConfigError
from ges_core.training.config import CurriculumConfig
from ges_core.training.curriculum import Curriculum

CLUSTER0 = {f"a/{i}": 0.1 * (i + 1) for i in range(6)}
"""Cluster 0's training objects and their distances to its centre (a/0 nearest)."""
CLUSTER1 = {"b/0": 0.3, "b/1": 0.2}


def _member(oid: str, cluster: int, distance: float, split: str = "train") -> ClusterMember:
    features = np.array([distance, 1.0 - distance])  # the hard-case set's centre is computed from these
    return ClusterMember(
        object_id=oid, category=oid.split("/")[0], split=split, cluster=cluster, assigned_by="category",
        features=features, distance=distance, nearest_cluster=cluster,
    )  # fmt: skip


def _clusters(tmp_path) -> Clusters:
    """Written and read back through the clusters file format, as ges cluster leaves it beside a dataset."""
    objects = {o: _member(o, 0, d) for o, d in CLUSTER0.items()}
    objects |= {o: _member(o, 1, d) for o, d in CLUSTER1.items()}
    objects["a/new"] = _member("a/new", 0, 0.05, split="unseen_object")  # nearest, but not a training object
    clusters = Clusters(
        k=2, seed=0, feature_names=("f0", "f1"), mean=np.zeros(2), std=np.ones(2), centres=np.zeros((2, 2)),
        kmeans_centres=np.zeros((2, 2)), objects=dict(sorted(objects.items())), categories={"a": 0, "b": 1},
    )  # fmt: skip
    save_clusters(clusters, tmp_path / "clusters.json")
    return load_clusters(tmp_path / "clusters.json")


ALL = sorted([*CLUSTER0, *CLUSTER1])


def test_stages_are_centre_cluster_everything(tmp_path) -> None:
    cur = Curriculum.for_cluster(CurriculumConfig(centre_fraction=0.3), _clusters(tmp_path), 0, ALL)
    assert cur.stage_objects == {1: ["a/0", "a/1"], 2: [f"a/{i}" for i in range(6)], 3: ALL}  # ceil(0.3 x 6) = 2
    assert cur.stage == 1 and cur.weights() == {"a/0": 1.0, "a/1": 1.0}


def test_only_objects_with_a_usable_grasp_take_part(tmp_path) -> None:
    usable = ["a/3", "a/5", "b/0"]
    cur = Curriculum.for_cluster(CurriculumConfig(centre_fraction=0.3), _clusters(tmp_path), 0, usable)
    assert cur.stage_objects == {1: ["a/3"], 2: ["a/3", "a/5"], 3: usable}
    with pytest.raises(AssetError, match=r"cluster 1 \(2 training objects\) holds no training object with a usable"):
        Curriculum.for_cluster(CurriculumConfig(), _clusters(tmp_path), 1, ["a/0"])
    with pytest.raises(ConfigError, match="k = 2"):
        Curriculum.for_cluster(CurriculumConfig(), _clusters(tmp_path), 2, ALL)


def test_a_cluster_of_one_object_trains_on_it_in_stages_one_and_two(tmp_path) -> None:
    cur = Curriculum.for_cluster(CurriculumConfig(), _clusters(tmp_path), 1, ["b/1", "a/0"])
    assert cur.stage_objects[1] == cur.stage_objects[2] == ["b/1"]


def test_promotion_on_success_rate_over_the_window(tmp_path) -> None:
    cfg = CurriculumConfig(window=4, promote_success=0.5, max_iterations=100)
    cur = Curriculum.for_cluster(cfg, _clusters(tmp_path), 0, ALL)
    cur.record([True, True, True])
    assert cur.end_iteration(1) is None  # 3 of 4 episodes: the window is not full yet
    cur.record([False])
    promotion = cur.end_iteration(2)  # 3 / 4 >= 0.5
    assert promotion is not None and (promotion.from_stage, promotion.to_stage, promotion.reason) == (1, 2, "success")
    assert promotion.success_rate == 0.75
    assert "stage 1 -> 2 (whole cluster), success: success 0.75" in promotion.describe()
    assert cur.stage == 2 and set(cur.weights()) == set(CLUSTER0) and math.isnan(cur.success_rate())
    cur.record([False, False, True, False])  # 1 / 4 < 0.5: stays
    assert cur.end_iteration(3) is None and cur.stage == 2


def test_promotion_at_the_iteration_cap_and_the_last_stage_is_kept(tmp_path) -> None:
    cur = Curriculum.for_cluster(CurriculumConfig(window=4, max_iterations=2), _clusters(tmp_path), 0, ALL)
    assert cur.end_iteration(1) is None
    p = cur.end_iteration(2)
    assert p is not None and p.reason == "iteration_cap" and math.isnan(p.success_rate) and p.episodes == 0
    cur.end_iteration(3)
    assert cur.end_iteration(4).to_stage == 3
    for it in range(5, 20):
        cur.record([True] * 4)
        assert cur.end_iteration(it) is None
    assert cur.stage == 3 and [h.to_stage for h in cur.history] == [2, 3]


def test_hard_case_set_runs_stages_one_and_two_nearest_its_own_centre(tmp_path) -> None:
    cfg = CurriculumConfig(stages=[1, 2], centre_fraction=0.5, max_iterations=1)
    cur = Curriculum.for_cluster(cfg, _clusters(tmp_path), 0, ALL, objects=["a/0", "a/2", "a/5", "b/0"])
    # features (d, 1 - d): the set's mean d is 0.325; nearest a/2 and b/0 (both 0.3; ties by id)
    assert cur.stage_objects[1] == ["a/2", "b/0"] and sorted(cur.stage_objects[2]) == ["a/0", "a/2", "a/5", "b/0"]
    promotion = cur.end_iteration(1)
    assert promotion.to_stage == 2 and cur.end_iteration(2) is None
    assert "stage 1 -> 2 (whole set)" in promotion.describe()  # no cluster to name
    resumed = Curriculum.for_cluster(cfg, _clusters(tmp_path), 0, ALL, objects=["a/0", "a/2", "a/5", "b/0"])
    state = cur.state_dict()
    for p in state["history"]:
        p.pop("stage_name")  # a checkpoint written before the name was stored
    resumed.load_state_dict(state)
    assert "(whole cluster)" in resumed.history[0].describe()
    with pytest.raises(ConfigError, match="not in the clustering"):
        Curriculum.for_cluster(cfg, _clusters(tmp_path), 0, ALL, objects=["zzz"])


def test_state_round_trip_and_a_changed_run_is_refused(tmp_path) -> None:
    cfg = CurriculumConfig(window=4, max_iterations=2)
    cur = Curriculum.for_cluster(cfg, _clusters(tmp_path), 0, ALL)
    cur.end_iteration(1), cur.end_iteration(2)
    cur.record([True, False])
    again = Curriculum.for_cluster(cfg, _clusters(tmp_path), 0, ALL)
    again.load_state_dict(cur.state_dict())
    assert again.stage == 2 and list(again.window) == [True, False] and again.history == cur.history
    other = Curriculum.for_cluster(cfg, _clusters(tmp_path), 1, ALL)
    with pytest.raises(ConfigError, match="start a new run folder"):
        other.load_state_dict(cur.state_dict())


def test_disabled_curriculum_trains_on_the_last_stage_only(tmp_path) -> None:
    cur = Curriculum.for_cluster(CurriculumConfig(enabled=False), _clusters(tmp_path), 0, ALL)
    assert cur.stages == [3] and cur.objects() == ALL and cur.end_iteration(1) is None


def test_promotion_on_the_in_run_evaluation(tmp_path) -> None:
    """``promote_on: evaluation`` reads the latest evaluation of the stage, not the training window; the rate is
    forgotten at a promotion (the next stage waits for its own evaluation) and survives a resume."""
    cfg = CurriculumConfig(window=4, promote_success=0.5, max_iterations=100, promote_on="evaluation")
    cur = Curriculum.for_cluster(cfg, _clusters(tmp_path), 0, ALL)
    cur.record([True] * 8)  # the training episodes alone promote nothing
    assert cur.end_iteration(1) is None
    cur.record_evaluation(0.25, 8)
    assert cur.end_iteration(2) is None and cur.end_iteration(3) is None  # below the threshold, kept until the next
    cur.record_evaluation(0.5, 8)
    again = Curriculum.for_cluster(cfg, _clusters(tmp_path), 0, ALL)
    again.load_state_dict(cur.state_dict())
    for c in (cur, again):
        p = c.end_iteration(4)
        assert (p.from_stage, p.to_stage, p.reason, p.success_rate, p.episodes) == (1, 2, "evaluation", 0.5, 8)
        assert "evaluation: success 0.50 in the evaluation's 8 noise-free episode(s)" in p.describe()
        assert c.evaluation is None and c.end_iteration(5) is None  # stage 2 waits for an evaluation of its own
    assert cur.all_objects() == ALL


def test_evaluation_promotion_needs_the_in_run_evaluation() -> None:
    from ges_core.training.config import load_train_config

    with pytest.raises(ConfigError, match=r"evaluation.interval"):
        load_train_config("tiny", overrides=["curriculum.promote_on=evaluation"])
    cfg = load_train_config("tiny", overrides=["curriculum.promote_on=evaluation", "evaluation.interval=50"])
    assert cfg.evaluation.interval == 50 and cfg.evaluation.seed not in range(8)  # not ges eval-experts' seeds
