"""deploy/: the zenoh configurations load in zenoh, the YAML files parse and say what they must.

No container is built or run here (no docker on the test machines); these checks catch the
mistakes that need none: a configuration zenoh rejects, a manifest that does not parse, a
probe on the wrong path, a ConfigMap that drifted from the files. Sessions are opened only
on loopback: the local configurations are tried end to end with their port replaced by a
free one.
"""

from __future__ import annotations

import json
import queue
import re
from pathlib import Path
from typing import Any

import cv2
import pytest
import yaml
import zenoh

from schemas import Detection
from service.bus.config import make_config
from service.bus.detection import DetectionBus
from service.synthetic import make_scene
from tests.helpers import free_port, wait_until
from tests.service.test_bus import wait_for_subscriber

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
ZENOH_CONFIGS = sorted((DEPLOY / "zenoh").glob("*.json5"))
TIMEOUT = 15.0


def manifests() -> dict[str, dict[str, Any]]:
    """Every Kubernetes object of deploy/k8s, by ``kind/name``."""
    objects = {}
    for path in sorted((DEPLOY / "k8s").glob("*.yaml")):
        if path.name == "kustomization.yaml":
            continue
        for document in yaml.safe_load_all(path.read_text()):
            objects[f"{document['kind']}/{document['metadata']['name']}"] = document
    return objects


@pytest.mark.parametrize("path", ZENOH_CONFIGS, ids=lambda path: path.name)
def test_zenoh_configurations_load(path: Path) -> None:
    config = zenoh.Config.from_file(str(path))
    assert json.loads(config.get_json("mode")) in ("router", "peer", "client")
    # nothing in deploy/ relies on multicast scouting: it does not cross container networks
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False


def test_the_expected_zenoh_configurations_are_there() -> None:
    names = {path.name for path in ZENOH_CONFIGS}
    assert names >= {"router.json5", "dlo-client.json5", "local-peer.json5", "local-client.json5"}
    router = zenoh.Config.from_file(str(DEPLOY / "zenoh" / "router.json5"))
    assert json.loads(router.get_json("listen/endpoints")) == ["tcp/0.0.0.0:7447"]
    service = zenoh.Config.from_file(str(DEPLOY / "zenoh" / "dlo-client.json5"))
    assert json.loads(service.get_json("connect/endpoints")) == ["tcp/router:7447"]


def test_the_local_configurations_join_a_service_and_a_script(free_endpoint: str) -> None:
    """local-peer.json5 (the service) and local-client.json5 (a script), on a free port."""
    service_config = make_config(DEPLOY / "zenoh" / "local-peer.json5", listen=[free_endpoint])
    script_config = make_config(DEPLOY / "zenoh" / "local-client.json5", connect=[free_endpoint])
    ok, image = cv2.imencode(".png", make_scene(240, 160, 2, seed=0, loops=False).image)
    assert ok
    with DetectionBus(service_config) as bus, zenoh.open(script_config) as script:
        received: queue.Queue[bytes] = queue.Queue()
        script.declare_subscriber("dlo/*/chains", lambda s: received.put(s.payload.to_bytes()))
        publisher = script.declare_publisher(  # BLOCK: see tests/service/test_bus.py
            "dlo/cam1/image", congestion_control=zenoh.CongestionControl.BLOCK
        )
        wait_until(lambda: publisher.matching_status.matching, "the service's subscriber")
        wait_for_subscriber(bus.session, "dlo/cam1/chains")
        publisher.put(image.tobytes())
        assert Detection.model_validate_json(received.get(timeout=TIMEOUT)).chains


def test_kubernetes_manifests() -> None:
    objects = manifests()
    assert set(objects) == {
        "ConfigMap/zenoh-config",
        "Deployment/router",
        "Service/router",
        "Deployment/dlo",
        "Service/dlo",
    }
    kustomization = yaml.safe_load((DEPLOY / "k8s" / "kustomization.yaml").read_text())
    for resource in kustomization["resources"]:
        assert (DEPLOY / "k8s" / resource).is_file(), resource

    dlo = only_container(objects["Deployment/dlo"])
    assert dlo["readinessProbe"]["httpGet"]["path"] == "/readyz"
    assert dlo["livenessProbe"]["httpGet"]["path"] == "/healthz"
    assert {"cpu", "memory"} <= set(dlo["resources"]["limits"])
    environment = {variable["name"]: variable["value"] for variable in dlo["env"]}
    assert environment["DLO_ZENOH_CONFIG"] == "/etc/zenoh/dlo.json5"
    router = only_container(objects["Deployment/router"])
    assert router["args"] == ["-c", "/etc/zenoh/router.json5"]
    assert {"cpu", "memory"} <= set(router["resources"]["limits"])

    # each Service selects its Deployment's pods and reaches a named container port
    for name in ("dlo", "router"):
        service, deployment = objects[f"Service/{name}"], objects[f"Deployment/{name}"]
        pod_labels = deployment["spec"]["template"]["metadata"]["labels"]
        assert service["spec"]["selector"].items() <= pod_labels.items()
        port_names = {port["name"] for port in only_container(deployment)["ports"]}
        assert {port["targetPort"] for port in service["spec"]["ports"]} <= port_names


def test_the_service_reads_its_api_token_from_a_secret() -> None:
    """The bearer token comes from a Secret's file, never from a value in the manifest."""
    deployment = manifests()["Deployment/dlo"]
    dlo = only_container(deployment)
    environment = {variable["name"]: variable for variable in dlo["env"]}
    assert "DLO_API_TOKEN" not in environment
    token_file = Path(environment["DLO_API_TOKEN_FILE"]["value"])
    (mount,) = [m for m in dlo["volumeMounts"] if token_file.parent == Path(m["mountPath"])]
    assert mount["readOnly"] is True
    volumes = {
        volume["name"]: volume for volume in deployment["spec"]["template"]["spec"]["volumes"]
    }
    secret = volumes[mount["name"]]["secret"]
    assert secret["secretName"] == "dlo-api-token"
    assert secret.get("optional") is not True  # without the Secret, no pod: never open by mistake
    assert {"key": "token", "path": token_file.name} in secret["items"]
    # a Secret with a value checked into the repository would defeat it
    assert not any(kind.startswith("Secret/") for kind in manifests())


def test_the_config_map_holds_the_zenoh_files_unchanged() -> None:
    data = manifests()["ConfigMap/zenoh-config"]["data"]
    assert data["router.json5"] == (DEPLOY / "zenoh" / "router.json5").read_text()
    assert data["dlo.json5"] == (DEPLOY / "zenoh" / "dlo-client.json5").read_text()
    for text in data.values():
        zenoh.Config.from_json5(text)


def test_compose_file() -> None:
    compose = yaml.safe_load((DEPLOY / "compose.yaml").read_text())
    router, dlo = compose["services"]["router"], compose["services"]["dlo"]
    assert router["image"].startswith("eclipse/zenoh:")
    assert router["command"] == ["-c", "/etc/zenoh/router.json5"]
    assert dlo["build"] == {"context": "..", "dockerfile": "deploy/Dockerfile"}
    assert dlo["environment"]["DLO_ZENOH_CONFIG"] == "/etc/zenoh/dlo.json5"
    assert "router" in dlo["depends_on"]
    for service in (router, dlo):
        for volume in service["volumes"]:
            source = volume.split(":", 1)[0]
            assert (DEPLOY / source).is_file(), volume
    # the router's image and the Kubernetes one are the same version
    assert router["image"] == only_container(manifests()["Deployment/router"])["image"]


def test_dockerfile() -> None:
    """What the image needs; building it needs docker (see deploy/README.md)."""
    text = (DEPLOY / "Dockerfile").read_text()
    assert re.search(r"^FROM python:3\.12-slim$", text, re.MULTILINE)
    copied = [line.split()[1:-1] for line in text.splitlines() if line.startswith("COPY ")]
    assert {"pyproject.toml", "service"} <= {source for sources in copied for source in sources}
    for sources in copied:
        for source in sources:
            assert (DEPLOY.parent / source).exists(), source
    assert "HEALTHCHECK" in text and "/healthz" in text
    assert re.search(r'^CMD \["dlo", "serve"\]$', text, re.MULTILINE)
    # a numeric user: Kubernetes checks runAsNonRoot only against a uid
    (user,) = re.findall(r"^USER (\S+)$", text, re.MULTILINE)
    assert user.isdigit() and user != "0"
    dlo = only_container(manifests()["Deployment/dlo"])
    assert dlo["securityContext"]["runAsUser"] == int(user)


def only_container(deployment: dict[str, Any]) -> dict[str, Any]:
    (container,) = deployment["spec"]["template"]["spec"]["containers"]
    return container


@pytest.fixture
def free_endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


def test_scouting_is_off_unless_asked_for() -> None:
    """The service's default session scouts nothing (neither multicast nor gossip), and
    ``make_config`` writes gossip scouting only when told: loopback tests and tools that
    connect to explicit endpoints turn it off, as the service does."""
    from service.bus.config import service_config

    def scouting(config: zenoh.Config, kind: str) -> object:
        return json.loads(config.get_json(f"scouting/{kind}/enabled"))

    default = service_config()
    assert scouting(default, "multicast") is False
    assert scouting(default, "gossip") is False
    assert scouting(service_config(multicast=True), "gossip") is True
    assert scouting(make_config(gossip=False), "gossip") is False
    untouched = zenoh.Config()
    assert scouting(make_config(), "gossip") == scouting(untouched, "gossip")
