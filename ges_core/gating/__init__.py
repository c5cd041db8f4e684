"""Expert selection: what a gate learns from, how it is trained and stored (see ``docs/gating.md``).

>>> rates = SuccessRates(object_ids, experts, rates_array)            # (n_objects, n_experts) in [0, 1]
>>> data = GateData(rates, library_clouds(library, object_ids, 1024))  # clouds (n, 1024, 3), object frame, m
>>> gate = registry.spec("gate", "curvenet").load()()                   # or pointnet2, centroid
>>> result = gate.fit(data, TrainConfig(epochs=60), log_dir="runs/gate/tb")
>>> gate.save("runs/gate/gate.pt"); load_gate("runs/gate/gate.pt", experts=experts).predict(clouds)

The gate plugins live in ``plugins/gates``; :class:`ges_core.policy.Gate` is their interface and
:class:`~ges_core.gating.torch_gate.TorchGate` the base of the two networks.
"""

from __future__ import annotations

from ges_core.gating.checkpoint import load_gate, read_checkpoint
from ges_core.gating.clouds import AugmentConfig, ResampledCloudWarning, augment, fit_cloud, library_clouds
from ges_core.gating.data import SuccessRates, best_experts, split_indices, targets
from ges_core.gating.inputs import gate_input
from ges_core.gating.loss import gate_accuracy, kl_loss
from ges_core.gating.train import GateData, TrainConfig, TrainResult

__all__ = [
    "AugmentConfig",
    "GateData",
    "ResampledCloudWarning",
    "SuccessRates",
    "TrainConfig",
    "TrainResult",
    "augment",
    "best_experts",
    "fit_cloud",
    "gate_accuracy",
    "gate_input",
    "kl_loss",
    "library_clouds",
    "load_gate",
    "read_checkpoint",
    "split_indices",
    "targets",
]
