"""The scripted expert's parameters: the one place each is defined, with its default and where it comes from.

:class:`ScriptedConfig`'s defaults are the plugin's registered settings (``ges info expert scripted``); registry.yaml
``settings.expert.scripted`` and a caller's settings (``--expert scripted:close_steps=20``) override them key by key.
Light on purpose (pydantic only): the registration module imports it to list the defaults.
"""

from __future__ import annotations

from pydantic import Field

from ges_core.config import ConfigModel

__all__ = ["ScriptedConfig"]


class ScriptedConfig(ConfigModel):
    """Settings of :class:`~ges_plugins.experts.scripted.expert.ScriptedExpert` (control steps, metres, newtons)."""

    approach_steps: int = Field(15, ge=0, description="control steps moving the wrist from the start to the grasp")
    """15 = Stage 1 validation's 30 physics steps (2 cm at 1.3 mm per step). At the full 5 mm per step a Shadow thumb
    hit a plate with 14.5 N and the plate slid 6 mm and tilted 8 degrees before the fingers closed
    (procedural/plate/000, SAPIEN). 0: the fingers close from the first step while the wrist goes straight to
    the grasp."""
    close_steps: int = Field(30, ge=1, description="control steps ramping the fingers to their closing targets")
    """30 = Stage 1 validation's 60 physics steps at the env's 2 physics steps per control step."""
    pause_steps: int = Field(5, ge=0, description="control steps held between the close and the carry")
    """Lifting on the step the fingers reached their targets lost two-finger Allegro grasps in PyBullet (the grip
    was still building); 5 held them (benchmarks/scripted_baseline.py grasps, docs/env_baseline.md)."""
    overshoot: float = Field(0.3, ge=0, description="fraction of (goal - start) the fingers are driven past the goal")
    """Used without a hand only: PD targets exactly at a contact pose give no grip force."""
    lift: float = Field(0.225, gt=0, description="m above its start the object is carried to")
    """The 0.2 m bar + 2.5 cm for slip in the hand (1 cm let a slipping box dip to 0.195 m in PyBullet), still within
    the peers' 5 cm."""
    carry_margin: float = Field(0.05, ge=0, description="m the wrist target may rise past lift for a slipping object")
    """A dropped object does not send the hand away."""
    carry_gain: float = Field(0.2, ge=0, le=1, description="share of the lifted object's sideways drift taken back")
    """Per carry step, past DRIFT_TOLERANCE. Without it a squeezed test box dragged 8-9 cm sideways in a PyBullet
    Allegro hand stayed out of the peers' 5 cm; gain 1 on every drift (the first version) rocked the carried object
    and dropped Shadow grasps. 0.2: a time constant of 5 control steps, well above the wrist's PD lag of 1-2."""
    palm_shift: float = Field(
        0.0, ge=-0.05, le=0.05, description="m the grasp's wrist is moved along the palm normal (+: into the object)"
    )
    """0: the Stage 1 grasp. Needs the hand (its ``wrist.palm_normal``, taken through the wrist link's pose at the
    goal joints). The approach still stops where the wrist link touches the object, so a deeper grasp is not driven
    into it. A grasp that differs from the given one in a way that depends on the object's shape: a gate's choice
    (docs/evaluate.md, "Scripted experts that grasp elsewhere")."""
    finger_shift: float = Field(
        0.0, ge=-0.05, le=0.05, description="m the grasp's wrist is moved along the finger direction (+: fingers on)"
    )
    """0: the Stage 1 grasp. As ``palm_shift``, along the hand's ``wrist.finger_direction``."""
    squeeze_force: float | None = Field(
        None, ge=0, description="N each fingertip is driven to press with (None: the hand's validate squeeze)"
    )
    """With a hand the closing targets are Stage 1 validation's squeeze (the overshoot rule pushed the Shadow thumb
    across its contact: 0 of 21 objects lifted, benchmarks/scripted_baseline.py); None reads the force from the
    hand YAML's ``settings.validate`` over ValidateConfig's defaults, as Stage 1 does. On a hand with stiff drives
    it changes nothing: the Allegro's Kp = 400 N·m/rad turns 5 N into about 0.001 rad past the grasp, far under the
    squeeze's 0.05 rad floor, so 2.5 N and 10 N gave the same episodes as 5 N to the last digit (94 procedural
    objects, docs/evaluate.md). The Shadow's (Kp 1-5) asks 0.4-0.6 rad: there the force sets the grip."""
