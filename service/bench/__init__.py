"""``dlo bench``: how fast the detector runs per stage on one thread
(:mod:`service.bench.detector`), what HTTP and zenoh add to it (:mod:`service.bench.overhead`,
``--service``) how long whole ``dlo`` processes take to start and finish
(:mod:`service.bench.startup`, ``--startup``) and what a ROS 2 recording adds per frame
(:mod:`service.bench.recording`, ``--recording``, also part of the full run)."""
