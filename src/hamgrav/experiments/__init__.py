"""Experiments of the paper, each a function from settings to a JSON-able result."""
