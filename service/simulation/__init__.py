"""Lifted chains as a simulation model: :func:`to_mjcf` writes MuJoCo's MJCF (text; no
MuJoCo needed). The README's picture of it: ``python -m service.evaluation.model_figure``.
"""

from service.simulation.mjcf import ModelError, to_mjcf

__all__ = ["ModelError", "to_mjcf"]
