"""The wheel-odometry model (METHOD 1): the floor everything else stands on.

Owns the parameters and inputs (:mod:`.parameters`), the one compiled model step with its
derivatives, every rollout and Jacobian built from it, and the model run backwards: the wheel
revolutions a step's motion implies (:mod:`.kinematics`).

May import: numpy, numba, :mod:`odocal.errors`. Nothing else of odocal.
"""
