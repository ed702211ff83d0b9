"""Small bodies: the catalogue and synthetic bodies, mesh-based truth interiors, the exact
constant-density polyhedron, the imaged-shape prior, evaluation sets and body reports."""
