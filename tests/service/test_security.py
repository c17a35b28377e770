"""Secure by default: what a default ``dlo serve`` exposes, and the optional bearer token.

The sockets of a running service are read from ``/proc`` (Linux): the inodes of the
process's open file descriptors, matched against the namespace's TCP and UDP tables.
A multicast membership needs a UDP socket, so a process without one has none.
"""

from __future__ import annotations

import contextlib
import ipaddress
import os
import re
import subprocess
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest
import zenoh

from schemas import Detection
from service.bus.config import make_config
from service.http import Settings
from service.runtime.settings import DEFAULT_ZENOH_LISTEN
from tests.helpers import DLO, free_port
from tests.helpers import dlo_serve as serving_process
from tests.service.test_bus import encoded_scene, query
from tests.service.test_http import running_server

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
TOKEN = "s3cret-token-for-the-test-0123456789"
linux_only = pytest.mark.skipif(not Path("/proc/self/net/tcp").exists(), reason="needs /proc")


@dataclass(frozen=True)
class Socket:
    protocol: str  # tcp, tcp6, udp or udp6
    address: ipaddress.IPv4Address | ipaddress.IPv6Address
    port: int
    listening: bool

    @property
    def on_loopback(self) -> bool:
        address = self.address
        if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
            address = address.ipv4_mapped
        return address.is_loopback


def sockets_of(pid: int) -> list[Socket]:
    """The TCP and UDP sockets process ``pid`` holds, with their local address."""
    inodes = set()
    for descriptor in Path(f"/proc/{pid}/fd").iterdir():
        with contextlib.suppress(OSError):  # closed while we looked
            found = re.fullmatch(r"socket:\[(\d+)\]", os.readlink(descriptor))
            if found:
                inodes.add(found[1])
    sockets = []
    for protocol in ("tcp", "tcp6", "udp", "udp6"):
        table = Path(f"/proc/{pid}/net/{protocol}").read_text().splitlines()[1:]
        for line in table:
            fields = line.split()
            if fields[9] not in inodes:
                continue
            address_hex, port_hex = fields[1].split(":")
            raw = bytes.fromhex(address_hex)
            # the kernel prints each 32-bit word in host (little-endian) order
            raw = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
            address = ipaddress.ip_address(raw)
            listening = protocol.startswith("tcp") and fields[3] == "0A"  # TCP_LISTEN
            sockets.append(Socket(protocol, address, int(port_hex, 16), listening))
    return sockets


def beyond_loopback(sockets: list[Socket]) -> list[Socket]:
    """Sockets bound to an address other than loopback (unbound ones, port 0, aside)."""
    return [
        s for s in sockets if not s.on_loopback and not (s.address.is_unspecified and not s.port)
    ]


def port_is_free(port: int) -> bool:
    import socket

    with socket.socket() as probe:
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def dlo_serve(
    arguments: list[str], environment: dict[str, str], log: Path
) -> contextlib.AbstractContextManager[tuple[subprocess.Popen[bytes], str]]:
    """A ready ``dlo serve`` process with one worker; yields it and its base URL."""
    return serving_process(["--workers", "1", *arguments], log, environment)


def listening_line(log: Path) -> str:
    (line,) = [line for line in log.read_text().splitlines() if "listening: HTTP on" in line]
    return line


# --- the default: loopback only, no scouting ------------------------------------------------


@linux_only
def test_a_default_dlo_serve_is_reachable_from_loopback_only(tmp_path: Path) -> None:
    default_port = int(DEFAULT_ZENOH_LISTEN.rsplit(":", 1)[1])
    if not port_is_free(default_port):
        pytest.skip(f"port {default_port} is taken (a `make run`?): the default cannot bind it")
    # what a user's shell has: none of the variables the test session sets
    environment = {
        name: value
        for name, value in os.environ.items()
        if not name.startswith(("DLO_ZENOH", "DLO_API_TOKEN"))
    }
    log = tmp_path / "serve.log"
    with dlo_serve([], environment, log) as (process, base):
        sockets = sockets_of(process.pid)
        assert {s.port for s in sockets if s.listening} >= {default_port, int(base.rsplit(":")[2])}
        assert beyond_loopback(sockets) == []
        assert [s for s in sockets if s.protocol.startswith("udp")] == []  # no scouting socket
        line = listening_line(log)
        assert f"HTTP on {base} (no token required)" in line
        assert f"zenoh peer listening on {DEFAULT_ZENOH_LISTEN}, multicast scouting off" in line

        # the README's camera snippet, unchanged: deploy/zenoh/local-client.json5 reaches it
        client_config = zenoh.Config.from_file(str(DEPLOY / "zenoh" / "local-client.json5"))
        with zenoh.open(client_config) as client:
            reply = query(client, encoded_scene())
            assert reply.ok is not None and Detection.model_validate_json(
                reply.ok.payload.to_bytes()
            )
        assert beyond_loopback(sockets_of(process.pid)) == []


@linux_only
def test_the_socket_check_sees_a_socket_on_every_interface() -> None:
    """The check above is not blind: a zenoh peer on 0.0.0.0, opened here, is caught."""
    port = free_port("0.0.0.0")
    config = make_config(mode="peer", multicast=False, listen=[f"tcp/0.0.0.0:{port}"], connect=[])
    with zenoh.open(config):
        caught = beyond_loopback(sockets_of(os.getpid()))
    assert [(str(s.address), s.port, s.listening) for s in caught] == [("0.0.0.0", port, True)]


def test_the_local_client_configuration_connects_where_the_default_listens() -> None:
    client = zenoh.Config.from_file(str(DEPLOY / "zenoh" / "local-client.json5"))
    assert client.get_json("connect/endpoints") == f'["{DEFAULT_ZENOH_LISTEN}"]'


# --- the bearer token -----------------------------------------------------------------------


def assert_unauthorized(response: httpx.Response) -> None:
    assert response.status_code == 401
    body = response.json()
    assert body["status"] == 401 and body["error"] == "unauthorized"
    assert body["request_id"] == response.headers["x-request-id"]
    assert response.headers["www-authenticate"].startswith("Bearer")
    assert TOKEN not in response.text


@pytest.mark.parametrize("path", ["/v1/detect", "/v1/detect/overlay", "/v1/grasp"])
def test_every_data_route_asks_for_the_token(path: str) -> None:
    with running_server(Settings(workers=1, zenoh=False, api_token=TOKEN)) as base:
        assert_unauthorized(httpx.post(f"{base}{path}", content=b"x"))


def test_detect_needs_the_right_token_and_probes_stay_open(tmp_path: Path) -> None:
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN + "\n")  # as `echo token > file` writes it
    image = encoded_scene()
    headers = {"Content-Type": "image/png"}
    with running_server(Settings(workers=1, zenoh=False, api_token_file=token_file)) as base:
        url = f"{base}/v1/detect"
        assert_unauthorized(httpx.post(url, content=image, headers=headers))
        for wrong in ("Bearer nope", f"Bearer {TOKEN}x", f"Basic {TOKEN}", TOKEN):
            response = httpx.post(url, content=image, headers={**headers, "Authorization": wrong})
            assert_unauthorized(response)
        response = httpx.post(
            url, content=image, headers={**headers, "Authorization": f"Bearer {TOKEN}"}
        )
        assert response.status_code == 200
        assert Detection.model_validate_json(response.content).chains
        for path in ("/healthz", "/readyz", "/metrics"):  # /metrics: open unless protected
            assert httpx.get(f"{base}{path}").status_code == 200
        metrics = httpx.get(f"{base}/metrics").text
        assert 'dlo_http_requests_total{method="POST",route="/v1/detect",status="401"} 5.0' in (
            metrics
        )


def test_metrics_may_ask_for_the_token_too() -> None:
    settings = Settings(workers=1, zenoh=False, api_token=TOKEN, protect_metrics=True)
    with running_server(settings) as base:
        assert_unauthorized(httpx.get(f"{base}/metrics"))
        authorized = {"Authorization": f"Bearer {TOKEN}"}
        assert httpx.get(f"{base}/metrics", headers=authorized).status_code == 200
        assert httpx.get(f"{base}/readyz").status_code == 200


def test_without_a_token_nothing_is_asked() -> None:
    with running_server(Settings(workers=1, zenoh=False)) as base:
        response = httpx.post(
            f"{base}/v1/detect", content=encoded_scene(), headers={"Content-Type": "image/png"}
        )
        assert response.status_code == 200


@pytest.mark.parametrize(
    ("environment", "message"),
    [
        ({"DLO_API_TOKEN": TOKEN, "DLO_API_TOKEN_FILE": __file__}, "not both"),
        ({"DLO_API_TOKEN_FILE": "/nonexistent/token"}, "cannot read the token file"),
        ({"DLO_API_TOKEN": "  "}, "the token is empty"),
    ],
)
def test_bad_token_settings_stop_dlo_serve_with_one_line(
    environment: dict[str, str], message: str
) -> None:
    result = subprocess.run(
        [*DLO, "serve"],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, **environment},
    )
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr
    assert TOKEN not in result.stderr


def test_the_token_never_reaches_the_log(tmp_path: Path) -> None:
    """Debug logging, uvicorn's access log, refused and accepted requests: no token."""
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    environment = {**os.environ, "DLO_API_TOKEN_FILE": str(token_file), "DLO_LOG_LEVEL": "debug"}
    log = tmp_path / "serve.log"
    with dlo_serve(["--zenoh-listen", endpoint], environment, log) as (_, base):
        image = encoded_scene()
        for header in (f"Bearer {TOKEN}", f"Bearer {TOKEN[:-1]}", f"Basic {TOKEN}"):
            httpx.post(
                f"{base}/v1/detect",
                content=image,
                headers={"Content-Type": "image/png", "Authorization": header},
            )
        line = listening_line(log)
        assert "bearer token required on /v1/*" in line
        assert f"zenoh peer listening on {endpoint}, multicast scouting off" in line
    text = log.read_text()
    assert "POST /v1/detect" in text  # the access log was on
    assert TOKEN[:12] not in text
