"""Which expert to run, as the command line names it: ``[LABEL=]NAME[:key=value,...]``.

>>> parse_expert("scripted")
ExpertChoice(label='scripted', name='scripted', settings={})
>>> parse_expert("slow=scripted:close_steps=60,lift=0.25").settings
{'close_steps': 60, 'lift': 0.25}

``NAME`` is a registry name (``ges list`` shows the experts); each ``key=value`` is one of the expert's settings
(``ges info expert NAME``), the value read as YAML (``60`` an int, ``0.25`` a float, ``null`` None, text a string).
``LABEL`` names the expert's column in a success matrix; without it the label is the text after any ``LABEL=``
(``scripted:close_steps=60``), so two settings of one expert are two columns.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import yaml

from ges_core.errors import ConfigError

__all__ = ["ExpertChoice", "parse_expert"]

_LABEL = re.compile(r"^[A-Za-z0-9_.+-]+$")
"""What a label may hold: it is a JSON key and a table cell, and must not hold ':', '=' or ','."""


@dataclass(frozen=True)
class ExpertChoice:
    """One expert to build: its column label, registry name and settings (over the registry's)."""

    label: str
    name: str
    settings: dict[str, Any] = field(default_factory=dict, hash=False)

    def text(self) -> str:
        """The ``NAME[:key=value,...]`` form (without the label)."""
        if not self.settings:
            return self.name
        return f"{self.name}:" + ",".join(f"{k}={_dump(v)}" for k, v in self.settings.items())


def parse_expert(text: str) -> ExpertChoice:
    """``[LABEL=]NAME[:key=value,...]`` -> :class:`ExpertChoice`; ConfigError saying the form when it is not one."""
    how = "use NAME, NAME:key=value,key=value or LABEL=NAME:key=value (e.g. slow=scripted:close_steps=60)"
    text = text.strip()
    label = None
    if "=" in text.partition(":")[0]:  # an '=' before any ':' ends a label
        label, _, text = text.partition("=")
        if not _LABEL.match(label):
            raise ConfigError(f"expert '{label}={text}': the label '{label}' may hold letters, digits and _.+- only")
    name, _, rest = text.partition(":")
    if not name or not _LABEL.match(name):
        raise ConfigError(f"expert '{text}': '{name}' is not an expert name; {how}")
    settings: dict[str, Any] = {}
    for item in filter(None, (part.strip() for part in rest.split(","))):
        key, eq, raw = item.partition("=")
        if not eq or not key.strip():
            raise ConfigError(f"expert '{text}': setting '{item}' must look like key=value; {how}")
        if key.strip() in settings:
            raise ConfigError(f"expert '{text}': setting '{key.strip()}' is given twice")
        settings[key.strip()] = yaml.safe_load(raw) if raw.strip() else None
    return ExpertChoice(label or ExpertChoice("", name, settings).text(), name, settings)


def _dump(value: Any) -> str:
    """A setting value as it is written on the command line (YAML flow style, one line)."""
    return yaml.safe_dump(value, default_flow_style=True, width=1_000_000).strip().removesuffix("\n...").strip()
