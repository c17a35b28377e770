"""Lifted chains as a simulation model: :func:`to_mjcf` writes MuJoCo's MJCF (text; no
MuJoCo needed), :mod:`.figure` renders the settled model (needs the ``mujoco`` package).
"""

from service.simulation.mjcf import ModelError, to_mjcf

__all__ = ["ModelError", "to_mjcf"]
