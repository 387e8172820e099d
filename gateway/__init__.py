"""Device gateway for motion-sensing rigs: zenoh ingest, attitude fusion, alarms, reel control, dashboard."""
