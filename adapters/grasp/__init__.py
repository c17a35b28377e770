"""Pure grasp planning: no robot, no I/O, no :mod:`service` (schemas, numpy and OpenCV only).

* :mod:`.target`: a detected chain in pixels to a :class:`~schemas.GraspTarget` on the table
  plane or a depth surface, in the robot base frame.
* :mod:`.depth`: depth images: decoding, checking against the camera, sampling.
* :mod:`.motions`: a top-down arm pick (approach, descend, close, lift) as UR poses, and the
  offline workspace check.
* :mod:`.pick`: both together, the :class:`~schemas.grasp.GraspPlan` that ``dlo ur3 plan`` and
  ``POST /v1/grasp`` return.
* :mod:`.errors`: why a grasp cannot be planned.
"""
