"""Per-hand settings: a hand's YAML ``settings:`` section (Stage 1, ``ges sim check``, Stage 2 training) and a
run's ``hand_settings``.

A hand carries the Stage 1 settings that depend on the hand (how hard its fingertips must squeeze, which
object widths its thumb and fingers span, how many fingertips must touch, ...) as *partial* sections of the
run's :class:`~ges_core.synthesis.SynthesisConfig`::

    settings:                       # in the hand's YAML (docs/hands/format.md)
      validate: {squeeze_force: 3.0, min_squeeze: 0.25, min_tips: 2}
      contacts: {max_width: 0.09}
      thumb_keep: 1

Precedence, lowest first (each layer replaces only the keys it names; nested sections merge key by key):

1. the run config (``SynthesisConfig``: its defaults or what the run's YAML / ``-o`` gave);
2. the hand's YAML ``settings:`` (what the hand's author knows about the hand);
3. the run config's ``hand_settings: {HAND: {...}}`` (what this run wants for that hand).

:meth:`ges_core.synthesis.SynthesisConfig.for_hand` applies the three; the Stage 1 worker builds every step's
config of a hand from its result, and the Stage 2 scripted expert reads the hand's squeeze the same way
(:func:`hand_validate_config`). A hand that sets nothing runs with the run config unchanged.

Two sections are not Stage 1's and never reach its config: ``sim_check`` (how ``ges sim check`` closes the hand,
:func:`hand_sim_check_config`) and ``train`` (Stage 2 training values that depend on the hand, :data:`TRAIN_FIELDS`,
:func:`hand_train_config`), e.g. the residual expert's action scale of a hand with stiff drives::

    settings:
      train: {residual_scale: 0.02}

Both fill only what the run did not set itself (a preset, ``--config`` or ``-o`` value wins).

Each section is checked against the real config model (unknown keys, wrong types and out-of-range values
rejected, with the dotted path). The models are imported only when a hand has settings: they pull in torch.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from ges_core.errors import ConfigError

if TYPE_CHECKING:
    from ges_core.hand import HandDescription
    from ges_core.synthesis.physics.validate import ValidateConfig

__all__ = [
    "SCALARS",
    "SECTIONS",
    "SIM_CHECK",
    "SIM_CHECK_FIELDS",
    "TRAIN",
    "TRAIN_FIELDS",
    "check_settings",
    "hand_sim_check_config",
    "hand_train_config",
    "hand_validate_config",
    "merge_settings",
    "stage1_settings",
]

SECTIONS = ("contacts", "retarget", "refine", "pregrasp", "validate", "robust")
"""Sections of :class:`~ges_core.synthesis.SynthesisConfig` a hand may set (keys as spelled in YAML)."""
SCALARS = ("thumb_keep",)
"""Top-level :class:`~ges_core.synthesis.SynthesisConfig` values a hand may set."""
SIM_CHECK = "sim_check"
"""The one section that is not Stage 1's: how ``ges sim check`` closes this hand (:data:`SIM_CHECK_FIELDS`)."""
SIM_CHECK_FIELDS = ("closure", "settle_steps", "close_steps", "lift_steps", "lift_height")
""":class:`~ges_core.sim_check.SimCheckConfig` fields a hand may set (how far and how its fingers close)."""
TRAIN = "train"
"""The Stage 2 section: :class:`~ges_core.training.TrainConfig` values of this hand (:data:`TRAIN_FIELDS`)."""
TRAIN_FIELDS = ("residual_scale",)
""":class:`~ges_core.training.TrainConfig` fields a hand may set: ``residual_scale``, the factor on the residual
expert's policy output (normalized action units) added to its base expert's action; a hand with stiff drives needs
a small one (docs/training.md, 'What is trained')."""
NOT_STAGE1 = (SIM_CHECK, TRAIN)
"""Sections of a hand's settings that do not layer over the Stage 1 run config."""


def _models() -> dict[str, type]:
    """Section name -> its config model (imported here: they pull in torch)."""
    from ges_core.synthesis.contacts.generate import ContactConfig
    from ges_core.synthesis.physics.pregrasp import PregraspConfig
    from ges_core.synthesis.physics.refine import RefineConfig
    from ges_core.synthesis.physics.robust import RobustConfig
    from ges_core.synthesis.physics.validate import ValidateConfig
    from ges_core.synthesis.retarget.retargeter import RetargetConfig

    return {
        "contacts": ContactConfig,
        "retarget": RetargetConfig,
        "refine": RefineConfig,
        "pregrasp": PregraspConfig,
        "validate": ValidateConfig,
        "robust": RobustConfig,
    }


def check_settings(data: object, where: str) -> dict[str, Any]:
    """``data`` checked as partial per-hand settings; returns a deep copy (plain YAML/JSON data).

    where: what the settings are, for messages (e.g. ``"hand 'shadow' (shadow.yaml) settings"``); every problem
    is named by its dotted path under it. ConfigError listing every problem.
    """
    if data is None:
        return {}
    allowed = SECTIONS + SCALARS + NOT_STAGE1
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: must be a mapping of sections ({', '.join(allowed)}), got {data!r}")
    problems = [f"{where}.{key}: unknown section (known: {', '.join(allowed)})" for key in data if key not in allowed]
    models = _models() if any(k in SECTIONS for k in data) else {}
    for key, value in data.items():
        if key in SECTIONS:
            problems += _section_problems(models[key], value, f"{where}.{key}")
    if SIM_CHECK in data:
        problems += _sim_check_problems(data[SIM_CHECK], f"{where}.{SIM_CHECK}")
    if TRAIN in data:
        problems += _train_problems(data[TRAIN], f"{where}.{TRAIN}")
    if "thumb_keep" in data:
        keep = data["thumb_keep"]
        if isinstance(keep, bool) or not isinstance(keep, int) or keep < 0:
            problems.append(f"{where}.thumb_keep: must be an integer >= 0 (proximal thumb joints kept), got {keep!r}")
    if problems:
        raise ConfigError("invalid per-hand settings: " + "; ".join(problems), problems=problems)
    return copy.deepcopy(dict(data))


def _section_problems(model: type, value: object, where: str) -> list[str]:
    """Problems of one partial section against its model (its defaults fill what it leaves out)."""
    if not isinstance(value, Mapping):
        return [f"{where}: must be a mapping of {model.__name__} fields, got {value!r}"]
    try:
        model.model_validate(dict(value))
    except ValidationError as exc:
        return [f"{where}{''.join('.' + str(p) for p in e['loc'])}: {e['msg']}" for e in exc.errors()]
    return []


def _limited_problems(model: type, fields: tuple[str, ...], value: object, where: str) -> list[str]:
    """Problems of a section that may set only ``fields`` of ``model`` (``sim_check``, ``train``)."""
    known = ", ".join(fields)
    if not isinstance(value, Mapping):
        return [f"{where}: must be a mapping of {known}, got {value!r}"]
    problems = [f"{where}.{k}: not a per-hand field (known: {known})" for k in value if k not in fields]
    return problems or _section_problems(model, value, where)


def _sim_check_problems(value: object, where: str) -> list[str]:
    """Problems of a hand's ``sim_check`` section: only :data:`SIM_CHECK_FIELDS`, each valid for SimCheckConfig."""
    from ges_core.sim_check import SimCheckConfig

    return _limited_problems(SimCheckConfig, SIM_CHECK_FIELDS, value, where)


def _train_problems(value: object, where: str) -> list[str]:
    """Problems of a hand's ``train`` section: only :data:`TRAIN_FIELDS`, each valid for TrainConfig."""
    from ges_core.training.config import TrainConfig

    return _limited_problems(TrainConfig, TRAIN_FIELDS, value, where)


def stage1_settings(settings: Mapping | None) -> dict:
    """A hand's settings without the ``sim_check`` and ``train`` sections: what layers over the Stage 1 run config."""
    return {k: v for k, v in (settings or {}).items() if k not in NOT_STAGE1}


def hand_sim_check_config(description: HandDescription, config):
    """``config`` (a :class:`~ges_core.sim_check.SimCheckConfig`) with the hand's ``settings.sim_check`` taking
    every field the user did not set (``-o closure=...`` or the config file wins over the hand's YAML)."""
    return _fill_unset(description, SIM_CHECK, config)


def hand_train_config(description: HandDescription, config):
    """``config`` (a :class:`~ges_core.training.TrainConfig`) with the hand's ``settings.train`` taking every
    field the run did not set (a preset, ``--config`` or ``-o`` value wins; a resumed run's stored config sets
    every field, so it keeps its own). Returns ``config`` itself when the hand sets nothing new."""
    return _fill_unset(description, TRAIN, config)


def _fill_unset(description: HandDescription, section_name: str, config):
    """``config`` with the hand's ``settings.<section_name>`` in every field not in ``config.model_fields_set``
    (the same object when there is none)."""
    section = description.settings.get(section_name) or {}
    update = {k: v for k, v in section.items() if k not in config.model_fields_set}
    if not update:
        return config
    from ges_core.config import parse_model

    data = merge_settings(config.model_dump(mode="json", exclude_unset=True), update)
    return parse_model(type(config), data, where=f"hand '{description.name}' settings.{section_name}")


def merge_settings(base: Mapping, *layers: Mapping | None) -> dict:
    """Deep copy of ``base`` with each layer's keys put over it in turn (mappings merge key by key; any other
    value, lists included, replaces)."""
    out = copy.deepcopy(dict(base))
    for layer in layers:
        for key, value in (layer or {}).items():
            if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
                out[key] = merge_settings(out[key], value)
            else:
                out[key] = copy.deepcopy(value)
    return out


def hand_validate_config(description: HandDescription, base: ValidateConfig | None = None) -> ValidateConfig:
    """``base`` (default: :class:`ValidateConfig`'s defaults) with the hand's ``settings.validate`` over it: the
    squeeze and pass marks that Stage 1 validation of this hand uses when the run sets nothing else."""
    from ges_core.config import parse_model
    from ges_core.synthesis.physics.validate import ValidateConfig

    base = base or ValidateConfig()
    section = description.settings.get("validate")
    if not section:
        return base
    data = merge_settings(base.model_dump(mode="json"), section)
    return parse_model(ValidateConfig, data, where=f"hand '{description.name}' settings.validate")
