"""The ArchitectHead avatar: feature field, encodings, decoder (torch), numpy runtime, checkpoint.

Only `model` (training and the reference decoder), `resample` (its feature field),
`checkpoint` (saves and loads the model) and `untrained` (which writes an untrained avatar
with them) import torch; `runtime` and everything it uses (config, lod, bicubic, gaussians,
checkpoint_format) are numpy alone, for Blender.
"""
