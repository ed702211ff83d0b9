"""Files: arcs and fitted models in HDF5, checkpoints in npz (never pickle), CCSDS OEM export;
every write is atomic."""
