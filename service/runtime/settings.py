"""Settings of one service process (``dlo serve``): where HTTP listens, the worker pool, the
input limits both transports check, and the zenoh session; read from ``DLO_*`` variables."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    """Where the service listens, how much work it takes on and what input it accepts.

    Every field can be set by an environment variable named ``DLO_`` + the field name in
    upper case, e.g. ``DLO_WORKERS=2``; ``dlo serve`` options override them.
    """

    model_config = SettingsConfigDict(env_prefix="DLO_", extra="ignore", frozen=True)

    host: str = Field("127.0.0.1", description="Address to listen on.")
    port: int = Field(8000, ge=0, le=65535, description="TCP port to listen on (0: any free).")
    workers: int = Field(
        2, ge=1, le=64, description="Detection threads (detection is CPU-bound: one per core)."
    )
    queue_size: int = Field(
        4,
        ge=0,
        le=1000,
        description="Requests that may wait for a busy worker; beyond that: 503 + Retry-After.",
    )
    max_megapixels: float = Field(
        40.0, gt=0, le=1000, description="Largest image accepted, in millions of pixels (413)."
    )
    max_body_mb: float = Field(
        25.0, gt=0, le=1000, description="Largest request body accepted, in MiB (413)."
    )
    max_detect_seconds: float = Field(
        30.0,
        gt=0,
        le=3600,
        description="Time one detection may take (decoding included); past it the request "
        "gets 422 time_budget_exceeded and the worker is free again.",
    )
    zenoh: bool = Field(
        True, description="Also serve detection over zenoh (dlo/*/image, dlo/detect)."
    )
    zenoh_config: Path | None = Field(
        None, description="zenoh JSON5 configuration file; default: an embedded peer."
    )
    zenoh_multicast: bool | None = Field(
        None,
        description="Multicast scouting on/off; default: as the configuration file (or zenoh).",
    )
    log_level: Literal["critical", "error", "warning", "info", "debug"] = Field(
        "info", description="Server log level."
    )

    @field_validator("log_level", mode="before")
    @classmethod
    def _lower_case(cls, value: object) -> object:
        return value.lower() if isinstance(value, str) else value

    @model_validator(mode="after")
    def _zenoh_config_exists(self) -> Settings:
        # Checked at start: a missing file would otherwise leave the service never ready.
        path = self.zenoh_config
        if self.zenoh and path is not None and not path.is_file():
            problem = "is a directory, not a file" if path.is_dir() else "no such file"
            raise ValueError(
                f"zenoh configuration {path}: {problem} (--zenoh-config, DLO_ZENOH_CONFIG)"
            )
        return self

    @property
    def max_body_bytes(self) -> int:
        return int(self.max_body_mb * 1024 * 1024)

    @property
    def max_pixels(self) -> int:
        return int(self.max_megapixels * 1_000_000)
