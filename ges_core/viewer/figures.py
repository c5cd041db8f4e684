"""A record's figures as Markdown for the viewer's side panel: outcome, steps, quality, verdicts per simulator."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ges_core.dataset.record import NOT_RUN, SKIPPED, STEPS

if TYPE_CHECKING:
    from ges_core.dataset.record import GraspRecord, SimVerdict

__all__ = ["record_markdown"]


def record_markdown(record: GraspRecord) -> str:
    """Markdown of ``record``: outcome and failure reason, per-step results and times, quality, the verdict of each
    validating simulator (nominal trial, flags, perturbation trials and robustness), refinement notes and errors."""
    parts = [_headline(record), _steps_table(record), _quality(record), *_verdicts(record)]
    parts += [_provenance(record), *_errors(record)]
    return "\n\n".join(p for p in parts if p)


def _headline(record: GraspRecord) -> str:
    if record.success:
        outcome = "**success**" + (" (robust)" if record.robust else "")
    else:
        step = record.failed_step
        outcome = f"**failed** at {step}: `{record.steps[step].reason}`" if step else "**failed**"
    return (
        f"**{record.object_id}** · hand **{record.hand}** · {record.category} · split `{record.split}`  \n"
        f"{outcome} · strategy {record.strategy or '-'} · simulator {record.simulator}"
    )


def _steps_table(record: GraspRecord) -> str:
    rows = ["| step | result | time |", "|---|---|---|"]
    for name in STEPS:
        step = record.steps.get(name)
        if step is None:
            continue
        rows.append(f"| {name} | {_result(step.ok, step.reason)} | {_seconds(step.seconds)} |")
    return "\n".join(rows)


def _result(ok: bool, reason: str) -> str:
    if ok:
        return "ok"
    return reason if reason in (SKIPPED, NOT_RUN) else f"✗ {reason}"


def _quality(record: GraspRecord) -> str:
    q = record.quality
    items = [
        f"force closure ε {_num(q.force_closure, '.3f')}",
        f"retarget residual {_mm(q.retarget_residual)}",
        f"max penetration {_mm(q.max_penetration)}",
        f"table contact {'-' if q.table_contact is None else ('yes' if q.table_contact else 'no')}",
    ]
    if record.refinement is not None:
        r = record.refinement
        items.append(f"object moved {_mm(r.object_shift)}, turned {r.object_turn_deg:.1f}° while closing")
        items.append(f"touching: {', '.join(r.touching_fingers) or 'none'}")
    return "**quality** · " + " · ".join(items)


def _verdicts(record: GraspRecord) -> list[str]:
    return [_verdict(sim, v, sim == record.simulator) for sim, v in sorted(record.validations.items())]


def _verdict(sim: str, verdict: SimVerdict, primary: bool) -> str:
    held = "held" if verdict.success else f"✗ `{verdict.reason}`"
    flags = ", ".join(f"{k} {'✓' if v else '✗'}" for k, v in sorted(verdict.flags.items()))
    text = f"**{sim}**{' (primary)' if primary else ''}: nominal trial {held} · {flags}"
    if verdict.trials:
        held_n = sum(t.success for t in verdict.trials)
        text += f"  \nrobust trials {held_n}/{len(verdict.trials)} held (robustness {verdict.robustness:.2f})"
        failed = [f"{t.name} `{t.reason}`" for t in verdict.trials if not t.success]
        if failed:
            text += ": failed " + ", ".join(failed)
    return text


def _provenance(record: GraspRecord) -> str:
    bits = [f"seed {record.seed}", f"grasp from {record.grasp_stage or '-'}"]
    if record.attempts:
        chosen = "none passed" if record.attempt is None else f"#{record.attempt + 1}"
        bits.append(f"wrist placement {chosen} of {len(record.attempts)} tried")
    if record.contacts_from:
        bits.append(f"contacts retargeted from {record.contacts_from}")
    return " · ".join(bits)


def _errors(record: GraspRecord) -> list[str]:
    return [f"error ({step}): {message}" for step, message in sorted(record.errors.items())]


def _seconds(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f} s"


def _mm(value: float | None) -> str:
    return "-" if value is None else f"{1000 * value:.1f} mm"


def _num(value: float | None, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)
