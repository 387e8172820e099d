"""control layer of the gateway."""
