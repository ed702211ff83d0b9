"""Unit-free numerics (canonical units): mascon sets, potential terms as heyoka expressions,
the model and its one compile cache, propagation, the arc least-squares problem and field
errors. Imports neither trimesh, h5py, matplotlib nor the body catalogue."""
