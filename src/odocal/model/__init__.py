"""The wheel-odometry model (METHOD 1): the floor everything else stands on.

Owns the parameters and inputs (:mod:`.parameters`), the one model step with its derivatives
(:mod:`.step`), every rollout and Jacobian built from it (:mod:`.kinematics`, :mod:`.jacobians`),
and the model run backwards: the wheel revolutions a step's motion implies.

May import: numpy, numba, :mod:`odocal.errors`, :mod:`odocal.arrays`. Nothing else of odocal.
"""
