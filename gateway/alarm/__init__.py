"""alarm layer of the gateway."""
