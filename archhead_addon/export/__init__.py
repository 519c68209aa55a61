"""Gaussians out of ArchHead: the standard 3DGS PLY, and the change of space for it."""
