"""The zenoh front end keeps the same time budget per detection as HTTP (issue 20)."""

from __future__ import annotations

import json

import cv2

from schemas import Detection
from service.bench.rings import rings_image
from service.perception import warm_up
from tests.service.test_bus import (
    bus_and_client,
    encoded_scene,
    publisher_to_bus,
    query,
    subscribe,
    take,
    wait_for_subscriber,
)


def test_a_frame_past_its_budget_gets_an_error_and_the_next_one_is_detected() -> None:
    heavy = cv2.imencode(".png", rings_image(4_000))[1].tobytes()  # seconds of work
    warm_up()  # as the service does before it is ready: no budget spent loading kernels
    with bus_and_client(max_detect_seconds=1.0) as (bus, client):
        chains = subscribe(client, "dlo/cam1/chains")
        errors = subscribe(client, "dlo/cam1/errors")
        publisher = publisher_to_bus(client, "dlo/cam1/image", bus.session)
        wait_for_subscriber(bus.session, "dlo/cam1/errors")

        publisher.put(heavy)
        record = json.loads(take(errors)[1])
        assert record["error"] == "time_budget_exceeded"
        assert "budget of 1 s" in record["detail"]

        publisher.put(encoded_scene())
        Detection.model_validate_json(take(chains)[1])
        reply = query(client, heavy)
        assert json.loads(reply.err.payload.to_bytes())["error"] == "time_budget_exceeded"
        assert bus.counts["rejected"] == 1 and bus.counts["published"] == 1
        assert bus.counts["query_rejected"] == 1
        assert bus.metrics.over_budget._value.get() == 2
