"""Attitude fusion: pure numpy, no I/O, time passed in. See docs/design.md for frames and conventions."""
