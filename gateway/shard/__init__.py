"""Gateway shards: several gateway processes, on one machine or many, share the devices over zenoh.

`ownership` (which shard serves a device), `node` (one shard's zenoh side), `routes` (the REST front),
`launch` (`python -m gateway --shards N`), `router` (a zenoh router as a Python session). docs/gateway.md, Shards.
"""

import time

STARTED_S = time.time()
"""When this process started (imported before `--shards` starts the local shards, so the parent is the oldest)."""
