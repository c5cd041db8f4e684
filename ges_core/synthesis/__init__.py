"""Stage 1: contact-guided grasp synthesis.

One module per step, in data-flow order: ``contacts`` (point cloud -> five contacts),
``force_closure`` (grasp quality), ``retarget`` (contacts -> wrist pose and joint angles),
``refine`` (collision-aware closing in a simulator), ``pregrasp`` (back off and open),
``validate`` (lift-and-hold in physics). Hands and simulators enter only through their interfaces.
"""
