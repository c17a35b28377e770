"""Why a request is not processed: :class:`RequestError`, with a status and a one-line message.

Both transports answer with it: HTTP as a JSON error of that status, zenoh as an error
record or error reply holding the code and the message.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from pydantic import ValidationError

SHOWN_INPUT_CHARS = 80
"""How much of an offending value a validation message quotes."""


@dataclass
class RequestError(Exception):
    """A request the service does not process; answered with ``status`` and ``message``.

    ``status`` is an HTTP status code (413, 415, 422, 503 ...), ``code`` a short machine
    name (``invalid_image``, ``busy`` ...), ``headers`` extra HTTP headers (``Retry-After``).
    """

    status: int
    code: str
    message: str
    headers: Mapping[str, str] = field(default_factory=dict)

    def __str__(self) -> str:
        return self.message


def describe_fields(error: ValidationError) -> list[str]:
    """Each problem of a nested model as ``a.b.0.c: message (got <value, shortened>)``."""
    problems = []
    for detail in error.errors(include_url=False):
        message = str(detail["msg"]).removeprefix("Value error, ")
        where = ".".join(str(part) for part in detail["loc"])
        if not where or detail["type"] in ("missing", "json_invalid", "json_type"):
            problems.append(f"{where}: {message}" if where else message)
            continue
        problems.append(f"{where}: {message} (got {shortened(repr(detail.get('input')))})")
    return problems


def shortened(text: str, limit: int = SHOWN_INPUT_CHARS) -> str:
    """``text`` cut to ``limit`` characters (ending in ``...``): a client's input is quoted
    in a message, never echoed back whole."""
    return text if len(text) <= limit else text[: limit - 3] + "..."
