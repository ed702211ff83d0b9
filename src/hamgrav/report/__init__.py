"""Reports: figures from plain data (no backend forced) and the atomic writers of an
experiment's folder."""
