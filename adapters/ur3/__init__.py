"""The UR3 arm over ur_rtde: picks a cable at a grasp target planned by :mod:`adapters.grasp`.

* :mod:`.driver`: :class:`~.driver.UR3Picker` over ur_rtde's three interfaces (injected
  through a ``connect`` factory), with the robot-state checks before any motion and the
  stop-and-report rules after a failure.
* :mod:`.fakes`: in-process fakes of the three interfaces (method names only).
* :mod:`.fake_controller`: a fake UR controller on the network (RTDE, script and dashboard
  ports) for the real ur_rtde client; ``python -m adapters.ur3.fake_controller``.
* :mod:`.cli`: ``dlo ur3 plan|pick``.
"""
