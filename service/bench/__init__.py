"""``dlo bench``: how fast the detector runs per stage on one thread
(:mod:`service.bench.detector`), what HTTP and zenoh add to it (:mod:`service.bench.overhead`,
``--service``) and how long whole ``dlo`` processes take to start and finish
(:mod:`service.bench.startup`, ``--startup``)."""
