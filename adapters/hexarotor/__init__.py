"""The fully-actuated hexarotor over MAVLink 2: approach a cable and close the gripper on it.

* :mod:`.approach`: frames (local NED, cell ENU, body FRD), the geofence and the
  standoff-then-approach plan; pure.
* :mod:`.protocol`: MAVLink 2 through pymavlink and the autopilots' mode numbers.
* :mod:`.driver`: :class:`~.driver.MavlinkVehicle`, the link: heartbeat, commands with
  acknowledgements, the setpoint stream and the grasp approach.
* :mod:`.fake_vehicle`: a SITL-free fake vehicle speaking MAVLink over UDP
  (``python -m adapters.hexarotor.fake_vehicle``); its physics in :mod:`.fake_dynamics`.
* :mod:`.wrench`: the wrench-set feasibility linear programs (can it pull this hard?);
  :mod:`.force_plot` draws them.
* :mod:`.trial`: the aerial grasp experiment against the fake.
* :mod:`.cli`: ``dlo hexa trial`` and ``dlo feasibility``.
"""
