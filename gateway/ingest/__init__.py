"""ingest layer of the gateway."""
