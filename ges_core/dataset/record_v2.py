"""Reader of version-2 records (and, through :mod:`.record_v1`, version-1 ones) as version 3.

Version 3 added robust validation. A version-2 record has no ``robust`` step and no perturbation trials:

=====================================  ==========================================================
version 2                              version 3
=====================================  ==========================================================
``steps`` (4 steps)                    ``steps.robust``: ``{ok: false, reason: "not_run"}``
``validations.<sim>``                  ``trials``: [], ``robustness``: null
``attempts[i]``                        ``robust``: "not_run", ``robustness``: null
=====================================  ==========================================================

Works on the raw JSON scalars, as :mod:`.record_v1` does, so ``ges dataset validate`` checks an old file through
the same function as the reader.
"""

from __future__ import annotations

from ges_core.dataset.record_v1 import upgraded as upgraded_v1

__all__ = ["upgraded"]

_NOT_RUN = {"ok": False, "reason": "not_run"}
"""The robust step of a record made before robust validation existed (``record.NOT_RUN``)."""


def upgraded(meta: dict) -> dict:
    """The scalars of a record as version 3 (a version-1 record through version 2 first); others unchanged.

    Never raises whatever the scalars hold: malformed parts are left for the checks to report.
    """
    meta = upgraded_v1(meta)
    if meta.get("version") != 2:
        return meta
    out = {**meta, "version": 3}
    if isinstance(meta.get("steps"), dict):
        out["steps"] = {**meta["steps"], "robust": dict(_NOT_RUN)}
    if isinstance(meta.get("validations"), dict):
        out["validations"] = {sim: _verdict(v) for sim, v in meta["validations"].items()}
    if isinstance(meta.get("attempts"), list):
        out["attempts"] = [_attempt(a) for a in meta["attempts"]]
    return out


def _verdict(verdict: object) -> object:
    return {**verdict, "trials": [], "robustness": None} if isinstance(verdict, dict) else verdict


def _attempt(attempt: object) -> object:
    return {**attempt, "robust": "not_run", "robustness": None} if isinstance(attempt, dict) else attempt
