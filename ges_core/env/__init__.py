"""Stage 2 grasp-execution environment: observation layout, rewards, success protocol, environments.

Pure-torch pieces (:mod:`layout`, :mod:`rotations`, :mod:`reward`, :mod:`success`) import no simulator.
"""
