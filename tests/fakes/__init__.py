"""Test helpers for the devices layer: a controllable clock and fake peers."""
