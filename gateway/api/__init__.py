"""api layer of the gateway."""
