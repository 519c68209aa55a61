"""UV layouts and UV-space rasterization tables."""
