"""Step 1, contact generation: an object's point cloud -> five finger contacts and their quality.

``generate`` (:func:`generate_contacts`: strategy, slices, optimization, ranking) uses ``frame`` (the
object's principal frame and symmetry), ``slicing`` (the slices and their candidate contacts), ``optimize``
(the contact set's refinement) and ``force_closure`` (Ferrari-Canny epsilon, :func:`ferrari_canny`).
"""

from __future__ import annotations

from ges_core.synthesis.contacts.force_closure import ForceClosureConfig, ferrari_canny
from ges_core.synthesis.contacts.generate import LIBRARY_CENTER_OF_MASS, ContactConfig, generate_contacts

__all__ = ["LIBRARY_CENTER_OF_MASS", "ContactConfig", "ForceClosureConfig", "ferrari_canny", "generate_contacts"]
