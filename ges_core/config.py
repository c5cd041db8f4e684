"""Configuration: pydantic models loaded from YAML, with ``key.sub=value`` overrides.

Every model forbids unknown keys; :func:`load_config` reports every problem at once with its
dotted path and raises one :class:`~ges_core.errors.ConfigError`.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from ges_core.errors import ConfigError

__all__ = [
    "STORED_WHEN_SET",
    "ConfigModel",
    "Defaults",
    "RegistryConfig",
    "absent_means",
    "absent_paths",
    "apply_overrides",
    "dotted_leaves",
    "fill_absent",
    "load_config",
    "parse_model",
    "parse_overridden",
    "read_yaml",
    "stored_dump",
]

M = TypeVar("M", bound=BaseModel)


class ConfigModel(BaseModel):
    """Base of our settings models: unknown keys rejected, immutable, no NaN or infinite numbers."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


STORED_WHEN_SET = {"stored_when_set": True}
"""``json_schema_extra`` of a field added after configs were already stored (a dataset's ``run_config`` and its hash
in every record): :func:`stored_dump` leaves it out while it holds its default, so a run that does not set it
stores what it stored before the field existed, and such a stored config still matches."""


def absent_means(value: object) -> dict:
    """``json_schema_extra`` of a field added after configs were stored whose *default changes what runs*: a stored
    config leaves it out while it holds ``value``, what the code did before the field existed. So a config stored
    before matches a run that asks for ``value`` (and resumes it), a run at the new default is refused on resume
    rather than mixed, and :func:`fill_absent` reads an old stored config as ``value``, not as the new default.
    (:data:`STORED_WHEN_SET` is the case where the default is the old behaviour.)"""
    return {"absent_means": value}


def fill_absent(cls: type[BaseModel], data: dict) -> dict:
    """A copy of stored config ``data`` (for ``cls``) with every :func:`absent_means` field it lacks, nested ones
    included (:func:`absent_paths`), set to what its absence means; parse it then (:func:`parse_model`)."""
    out = copy.deepcopy(data)
    for path, value in absent_paths(cls).items():
        *sections, key = path.split(".")
        node = out
        for name in sections:
            node = node.setdefault(name, {})
            if not isinstance(node, dict):  # a section stored as something else: parsing will say so
                break
        else:
            node.setdefault(key, value)
    return out


def absent_paths(cls: type[BaseModel], prefix: str = "") -> dict[str, object]:
    """``{dotted key: value}`` of every :func:`absent_means` field of ``cls``, nested ones included (by alias): what
    a stored config that lacks the key ran with (the dataset writer names them when it refuses a resume)."""
    out: dict[str, object] = {}
    for name, info in cls.model_fields.items():
        key, sub, extra = prefix + (info.alias or name), info.annotation, _extra(info)
        if isinstance(sub, type) and issubclass(sub, BaseModel):
            out.update(absent_paths(sub, key + "."))
        elif "absent_means" in extra:
            out[key] = extra["absent_means"]
    return out


def dotted_leaves(data: object, prefix: str = "") -> dict[str, object]:
    """Dotted key -> value of every leaf of nested mappings, keys in sorted order at each level (a list is a leaf;
    ``prefix`` starts every key)."""
    if isinstance(data, dict):
        return {
            k: v
            for key, value in sorted(data.items())
            for k, v in dotted_leaves(value, f"{prefix}.{key}" if prefix else str(key)).items()
        }
    return {prefix: data}


def stored_dump(model: ConfigModel) -> dict:
    """JSON-ready ``model`` (keys by alias) for storing, without the :data:`STORED_WHEN_SET` fields, nested ones
    included, that hold their defaults, nor the :func:`absent_means` fields that hold what their absence means."""
    data = model.model_dump(mode="json", by_alias=True)
    _drop_unset_late_fields(model, data)
    return data


def _drop_unset_late_fields(model: BaseModel, data: dict) -> None:
    for name, info in type(model).model_fields.items():
        key, value = info.alias or name, getattr(model, name)
        if key not in data:
            continue
        if isinstance(value, BaseModel):
            _drop_unset_late_fields(value, data[key])
        elif _left_out(info, value):
            del data[key]
        elif isinstance(value, dict):  # models keyed by name (LibraryConfig.object_properties)
            for item, sub in value.items():
                if isinstance(sub, BaseModel) and isinstance(data[key].get(item), dict):
                    _drop_unset_late_fields(sub, data[key][item])


def _extra(info) -> dict:
    """A field's ``json_schema_extra`` when it is a dict (where :data:`STORED_WHEN_SET` and :func:`absent_means`
    live), else empty."""
    return info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}


def _left_out(info, value) -> bool:
    """Whether a field's ``value`` is left out of a stored config (:data:`STORED_WHEN_SET`, :func:`absent_means`)."""
    extra = _extra(info)
    if extra.get("stored_when_set"):
        return value == info.get_default(call_default_factory=True)
    return "absent_means" in extra and value == extra["absent_means"]


class Defaults(ConfigModel):
    """Which plugin of each kind is used when none is named."""

    hand: str = Field("shadow", description="default hand plugin")
    sim: str = Field("sapien", description="default simulator plugin")
    gate: str | None = Field(None, description="default gate plugin (none until gating exists)")


class RegistryConfig(ConfigModel):
    """The contents of ``registry.yaml``."""

    defaults: Defaults = Field(default_factory=Defaults)
    plugins: list[str] = Field(
        default_factory=list,
        description="local plugins: a dotted module ('pkg.mod') or a .py file path (relative to registry.yaml)",
    )
    settings: dict[str, dict[str, dict[str, Any]]] = Field(
        default_factory=dict,
        description="per-plugin factory keyword arguments: settings[kind][name] = {...}",
    )


def read_yaml(path: str | Path) -> dict:
    """A YAML mapping from ``path`` (empty file -> {}); clear errors for missing or malformed files."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ConfigError(f"cannot read config file {path}: {exc.strerror}") from exc
    except yaml.YAMLError as exc:
        raise ConfigError(f"config file {path} is not valid YAML: {exc}") from exc
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"config file {path} must hold a mapping at the top level, not {type(data).__name__}")
    return data


def apply_overrides(data: dict, overrides: Iterable[str]) -> dict:
    """Copy of ``data`` with each ``"a.b.c=value"`` applied (value parsed as YAML)."""
    out = _deep_copy(data)
    for item in overrides:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"override '{item}' must look like key.sub=value")
        node = out
        parts = key.strip().split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(f"override '{item}': '{part}' is not a mapping")
        node[parts[-1]] = yaml.safe_load(raw) if raw.strip() else None
    return out


def parse_model(
    model: type[M], data: dict, *, where: str = "config", overrides: Iterable[str] = (), flag: str = "-o"
) -> M:
    """Validate ``data`` into ``model``; one ConfigError listing every problem by dotted path.

    overrides: the ``key=value`` items :func:`apply_overrides` applied to ``data`` (given on the command line as
    ``flag KEY=VALUE``); a problem at or under (or above) an override's key names it, so a bad override is not read
    as a problem of the file ``where`` names.
    """
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        keys = {item.partition("=")[0].strip(): item for item in overrides}
        problems = []
        for err in exc.errors():
            loc = ".".join(str(p) for p in err["loc"]) or "<root>"
            origin = next((item for key, item in keys.items() if _related(key, loc)), None)
            problems.append(f"{loc}: {err['msg']}" + (f" (set by {flag} {origin})" if origin else ""))
        raise ConfigError(f"invalid {where}: " + "; ".join(problems), problems=problems) from None


def _related(key: str, loc: str) -> bool:
    """The dotted ``key`` and ``loc`` are the same path or one lies under the other."""
    return key == loc or loc.startswith(key + ".") or key.startswith(loc + ".")


def parse_overridden(
    model: type[M], data: dict, overrides: Iterable[str], *, where: str = "config", flag: str = "-o"
) -> M:
    """:func:`apply_overrides` then :func:`parse_model`; a problem an override made names it (``flag KEY=VALUE``)."""
    overrides = list(overrides)  # read twice: an iterator would name nothing the second time
    return parse_model(model, apply_overrides(data, overrides), where=where, overrides=overrides, flag=flag)


def load_config(model: type[M], path: str | Path | None = None, overrides: Iterable[str] = ()) -> M:
    """Read ``path`` (or start empty), apply overrides, validate into ``model``."""
    data = read_yaml(path) if path is not None else {}
    return parse_overridden(model, data, overrides, where=str(path or model.__name__))


def _deep_copy(data: Any) -> Any:
    if isinstance(data, dict):
        return {k: _deep_copy(v) for k, v in data.items()}
    if isinstance(data, list):
        return [_deep_copy(v) for v in data]
    return data
