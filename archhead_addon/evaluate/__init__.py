"""Evaluation of a trained avatar (paper section 4): test-frame metrics per level of detail
and precision, timings, tables and a plot, and cross-identity reenactment.

    python -m archhead_addon.evaluate --avatar RUN/avatar.npz --data DIR --out EVAL

Frames are rendered as Blender renders them: the numpy runtime decodes (fp32 or fp16) and the
C++ splat kernel rasterizes (docs/training.md).
"""
