"""Simulated field devices that speak the rig wire protocol over zenoh (stand-ins for ESP32 + zenoh-pico)."""
