"""Settings an expert plugin gained after a result was stored: the one rule for reading old results.

Stored results name every setting their expert ran with (a matrix column, a GES results file, baseline results).
When a plugin gains a setting, older files lack it. A setting added to an expert must keep the expert's behaviour
at its default (docs/experts.md, "Adding a setting to an expert"), so a stored result that lacks it ran as the
plugin's default: :func:`with_gained_settings` fills it in before stored and new settings are compared. Without
this rule every stored result of the expert would be refused after the setting is added. (A code change that does
alter the episodes is what the matrix's code stamp reports; :func:`ges_core.experts.evaluate.cells_by_other_code`.)
"""

from __future__ import annotations

from typing import Any

from ges_core.errors import UnknownNameError

__all__ = ["with_gained_settings"]


def with_gained_settings(stored: dict[str, Any], name: str, registry) -> dict[str, Any]:
    """``stored`` (the settings a stored result of expert ``name`` names) plus every setting of the plugin's own
    defaults (its spec's, not registry.yaml's) that ``stored`` lacks, at that default. An expert the registry does
    not know: ``stored`` unchanged (a copy)."""
    try:
        defaults = registry.spec("expert", name).settings
    except UnknownNameError:
        return dict(stored)
    return {**stored, **{key: value for key, value in defaults.items() if key not in stored}}
