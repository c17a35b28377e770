"""dlo-service: detection core, HTTP app, zenoh bus and CLI."""
