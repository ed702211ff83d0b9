"""hamgrav: gravity fields of small bodies learned from tracking arcs."""

__version__ = "0.1.0"
