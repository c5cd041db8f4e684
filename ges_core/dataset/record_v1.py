"""Reader of version-1 records: their free-form ``extra`` becomes the typed fields of version 2.

Version 1 (GES-UniGrasp before the typed records) kept the Stage 1 pipeline's notes in ``extra``:

=====================================================  ==============================================
version 1 (``extra[...]``)                             version 2
=====================================================  ==============================================
``symmetric``                                          ``symmetric``
``contacts_from``                                      ``contacts_from``
``attempt``, ``attempts`` (list of {refinement,        ``attempt``, ``attempts`` (AttemptVerdict)
validation})
``frozen``, ``touching_fingers``, ``object_shift``,    ``refinement`` (RefinementInfo)
``object_turn_deg``
``validations`` ({sim: {success, reason, seconds,      ``validations`` (SimVerdict per simulator)
flags}})
``errors`` ({step: message})                           ``errors``
``setup_seconds`` ({sim: seconds})                     the timing file (``setup_seconds``)
``picture``                                            ``picture``
any other key                                          ``extra``
``steps.<step>.seconds``, ``validations.<sim>.seconds``  the timing file (:mod:`ges_core.dataset.timing`)
(none)                                                 ``run_config_hash``: null (unknown)
=====================================================  ==============================================

Version 1 kept the wall-clock times inside the record; :func:`timing_v1` reads them (version 2 keeps them
beside the record, so that its file is the same for the same run).

Works on the raw JSON scalars (no types imported), so the checks of ``ges dataset validate`` read a
version-1 file through the same function as the record reader.
"""

from __future__ import annotations

__all__ = ["REFINEMENT_KEYS", "timing_v1", "upgraded"]

REFINEMENT_KEYS = ("frozen", "touching_fingers", "object_shift", "object_turn_deg")
"""Version-1 ``extra`` keys that make up version 2's ``refinement``."""
_MOVED = ("symmetric", "contacts_from", "attempt", "picture")
"""Version-1 ``extra`` keys that keep their name as version-2 fields (absent: null)."""
_COLLECTIONS = {"attempts": list, "validations": dict, "errors": dict}
"""Version-1 ``extra`` keys that keep their name, absent meaning empty."""


def upgraded(meta: dict) -> dict:
    """The scalars of a record as version 2: a version-1 record's ``extra`` moved into the typed keys.

    Any other version is returned unchanged. Never raises on a dict ``extra`` whatever it holds (the
    version-2 checks then report what is wrong); a non-dict ``extra`` is left for the checks to report.
    """
    extra = meta.get("extra")
    if meta.get("version") != 1 or not isinstance(extra, dict):
        return meta
    rest = dict(extra)
    rest.pop("setup_seconds", None)  # a time: see timing_v1
    notes = {key: rest.pop(key, None) for key in _MOVED}
    notes |= {key: rest.pop(key, empty()) for key, empty in _COLLECTIONS.items()}
    refinement = {key: rest.pop(key) for key in REFINEMENT_KEYS if key in rest}
    notes["refinement"] = refinement or None
    notes["validations"] = _without_seconds(notes["validations"])
    steps = _without_seconds(meta.get("steps"))
    return {**meta, "version": 2, "steps": steps, "run_config_hash": None, **notes, "extra": rest}


def timing_v1(meta: dict) -> dict:
    """The wall-clock times a version-1 record holds, as a timing file holds them (:mod:`.timing`); {} for any
    other version. Values are taken as they are (the checks of the timing file judge them)."""
    extra = meta.get("extra")
    if meta.get("version") != 1 or not isinstance(extra, dict):
        return {}
    return {
        "steps": _seconds_of(meta.get("steps")),
        "validations": _seconds_of(extra.get("validations")),
        "setup_seconds": extra.get("setup_seconds", {}),
    }


def _seconds_of(items: object) -> dict:
    """{name: item["seconds"]} of a dict of dicts (anything else: {})."""
    if not isinstance(items, dict):
        return {}
    return {k: v.get("seconds") for k, v in items.items() if isinstance(v, dict)}


def _without_seconds(items: object) -> object:
    """A dict of dicts without their "seconds" keys (anything else unchanged)."""
    if not isinstance(items, dict):
        return items
    return {k: {f: x for f, x in v.items() if f != "seconds"} if isinstance(v, dict) else v for k, v in items.items()}
