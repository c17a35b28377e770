"""Detection over zenoh: the key expressions and session configuration
(:mod:`service.bus.config`), the detection front end :class:`DetectionBus`
(:mod:`service.bus.detection`), which replica owns which camera
(:mod:`service.bus.ownership`) and a router (:mod:`service.bus.router`, ``dlo router``).

``from service.bus import DetectionBus, service_config`` works; each name is imported when
first used, so that the router and zenoh clients do not load the detector.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from service.bus.config import (
        QUERY_KEY,
        chains_key,
        errors_key,
        make_config,
        service_config,
    )
    from service.bus.detection import DetectionBus, params_from_attachment, read_attachment
    from service.bus.ownership import REPLICAS_KEY, assign

_EXPORTS = {
    "QUERY_KEY": "service.bus.config",
    "chains_key": "service.bus.config",
    "errors_key": "service.bus.config",
    "make_config": "service.bus.config",
    "service_config": "service.bus.config",
    "DetectionBus": "service.bus.detection",
    "params_from_attachment": "service.bus.detection",
    "read_attachment": "service.bus.detection",
    "REPLICAS_KEY": "service.bus.ownership",
    "assign": "service.bus.ownership",
}

__all__ = [
    "QUERY_KEY",
    "REPLICAS_KEY",
    "DetectionBus",
    "assign",
    "chains_key",
    "errors_key",
    "make_config",
    "params_from_attachment",
    "read_attachment",
    "service_config",
]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(module), name)
