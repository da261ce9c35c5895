"""Shared pieces: field model, SE(2) geometry, camera models, dataset folders, HDF5 artifacts."""
