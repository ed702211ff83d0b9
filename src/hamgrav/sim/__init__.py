"""Simulation: orbit families, tracking and noise, campaigns (TOML), descents."""
