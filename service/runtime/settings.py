"""Settings of one service process (``dlo serve``): where HTTP listens, the worker pool, the
input limits both transports check, and the zenoh session; read from ``DLO_*`` variables."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

DEFAULT_ZENOH_LISTEN = "tcp/127.0.0.1:7447"
"""Where the embedded zenoh peer listens when nothing else is configured: loopback only."""
IMAGE_KEYS = "dlo/*/image"
"""Where cameras publish their frames; ``*`` is the camera's name."""


def _comma_separated(value: object) -> object:
    """``"a, b"`` (an environment variable) as ``["a", "b"]``; lists pass unchanged."""
    if isinstance(value, str):
        return [item.strip() for item in value.split(",") if item.strip()]
    return value


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
        None,
        description="zenoh JSON5 configuration file; default: an embedded peer listening on "
        f"{DEFAULT_ZENOH_LISTEN} only, without scouting.",
    )
    zenoh_listen: Annotated[list[str] | None, NoDecode] = Field(
        None,
        description="zenoh endpoints to listen on, comma separated (e.g. tcp/0.0.0.0:7447), "
        "written over the configuration file's; default: the file's, else "
        f"{DEFAULT_ZENOH_LISTEN}.",
    )
    zenoh_image_keys: Annotated[list[str], NoDecode] = Field(
        [IMAGE_KEYS],
        min_length=1,
        description="Key expressions of the frames this replica takes, comma separated, each "
        "dlo/<camera or pattern>/image (e.g. dlo/line1-*/image): a static group of cameras.",
    )
    zenoh_assignment: Literal["balanced", "rendezvous"] = Field(
        "balanced",
        description="How replicas sharing image keys split the cameras: rendezvous hashing "
        "with loads kept within one camera of each other (balanced), or plain rendezvous "
        "hashing, which moves fewest cameras when replicas come and go.",
    )
    zenoh_multicast: bool | None = Field(
        None,
        description="Multicast scouting on/off; default: as the configuration file, else off.",
    )
    track: Annotated[list[str], NoDecode] = Field(
        [],
        description="Cameras whose frames are also tracked (their Tracks on "
        "dlo/<camera>/tracks), comma separated: names or key expressions of names "
        "(line1-$*), or * for every camera; empty: none.",
    )
    track_memory_s: float = Field(
        5.0, ge=0, le=3600, description="How long a tracked cable out of view is remembered."
    )
    api_token: SecretStr | None = Field(
        None,
        description="Bearer token required on /v1/* (and on /metrics with protect_metrics); "
        "default: none required.",
    )
    api_token_file: Path | None = Field(
        None, description="File holding the bearer token (e.g. a mounted Secret); not both."
    )
    protect_metrics: bool = Field(
        False, description="Require the bearer token on /metrics too (when a token is set)."
    )
    segmenter_model: Path | None = Field(
        None,
        description="ONNX segmenter model for requests with segmentation=model "
        "(needs onnxruntime: the dlo-service[onnx] extra).",
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

    @field_validator("zenoh_listen", mode="before")
    @classmethod
    def _endpoints(cls, value: object) -> object:
        return _comma_separated(value) or None  # an empty variable: as if unset

    @field_validator("track", mode="before")
    @classmethod
    def _camera_list(cls, value: object) -> object:
        return _comma_separated(value) or []

    @field_validator("track")
    @classmethod
    def _camera_patterns(cls, names: list[str]) -> list[str]:
        for name in names:
            if "/" in name or not name.strip():
                raise ValueError(
                    f"{name!r} is not a camera name or pattern (one chunk, e.g. cam1, line1-$*, *)"
                )
        return list(dict.fromkeys(names))

    @field_validator("zenoh_image_keys", mode="before")
    @classmethod
    def _key_list(cls, value: object) -> object:
        return _comma_separated(value) or [IMAGE_KEYS]  # an empty variable: as if unset

    @field_validator("zenoh_image_keys")
    @classmethod
    def _image_keys(cls, keys: list[str]) -> list[str]:
        for key in keys:
            chunks = key.split("/")
            if len(chunks) != 3 or chunks[0] != "dlo" or chunks[2] != "image" or not chunks[1]:
                raise ValueError(
                    f"{key!r} is not dlo/<camera>/image (the camera's name or a pattern of "
                    "them, e.g. dlo/*/image, dlo/line1-$*/image)"
                )
            if chunks[1] == "**":
                raise ValueError(f"{key!r}: the camera is one chunk: use * instead of **")
        return list(dict.fromkeys(keys))

    @field_validator("api_token")
    @classmethod
    def _token_not_blank(cls, value: SecretStr | None) -> SecretStr | None:
        if value is not None and not value.get_secret_value().strip():
            raise ValueError("the token is empty")
        return value

    @model_validator(mode="after")
    def _one_token_source(self) -> Settings:
        if self.api_token is not None and self.api_token_file is not None:
            raise ValueError("set DLO_API_TOKEN or DLO_API_TOKEN_FILE, not both")
        if self.api_token_file is not None:
            self.read_api_token()  # unreadable or empty: refuse to start, not every request
        return self

    def read_api_token(self) -> str | None:
        """The bearer token (from ``api_token``, or ``api_token_file`` without its trailing
        line break); None when no token is required.

        Raises
        ------
        ValueError
            The file cannot be read or holds no token.
        """
        if self.api_token is not None:
            return self.api_token.get_secret_value().strip()
        if self.api_token_file is None:
            return None
        try:
            token = self.api_token_file.read_text(encoding="utf-8").strip()
        except (OSError, UnicodeDecodeError) as exc:
            reason = exc.strerror if isinstance(exc, OSError) else "not UTF-8 text"
            raise ValueError(
                f"cannot read the token file {self.api_token_file}: {reason}"
            ) from None
        if not token:
            raise ValueError(f"the token file {self.api_token_file} is empty")
        return token

    @property
    def max_body_bytes(self) -> int:
        return int(self.max_body_mb * 1024 * 1024)

    @property
    def max_pixels(self) -> int:
        return int(self.max_megapixels * 1_000_000)
