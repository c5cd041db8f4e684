"""``ges hand lint``: check a hand definition before anyone simulates it.

Each check returns :class:`LintProblem` lines that say what is wrong and how to fix it.
Static checks read the URDF and the description; physical checks run forward kinematics
(pytorch-kinematics) and every installed simulator.
"""

from ges_core.lint.problems import LintProblem
from ges_core.lint.runner import CHECKS, lint_hand

__all__ = ["CHECKS", "LintProblem", "lint_hand"]
