"""Ports and adapters around the pure planning: from a grasp point to robot motions.

* :mod:`adapters.grasp`: pure planning (pixel to grasp target, arm pick motions); no robot.
* :mod:`adapters.ur3`: the UR3 arm over ur_rtde: driver, fakes and the ``dlo ur3`` CLI.
* :mod:`adapters.hexarotor`: the hexarotor over MAVLink: driver, fake vehicle, wrench-set
  feasibility and the ``dlo hexa`` / ``dlo feasibility`` CLI.
* :mod:`adapters.errors`: the error types every robot shares.

The package ``__init__`` modules import nothing, so importing one robot's CLI loads neither
the other robot nor the heavy libraries a command does not use.
"""
