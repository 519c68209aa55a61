"""The synthetic subject: the built-in head rendered along a known FLAME trajectory.

`scripts/synthetic_subject.py` renders it with Blender Cycles; this package holds what
needs no Blender: the trajectory and camera (`trajectory`) and the output folder
(`subject`). The folder it writes (docs/formats.md, "Synthetic subject"):

    OUT/frames/00000.png   RGB, 8-bit sRGB, straight (unassociated) colour: composite over a
                           background with the mask, image = mask * frame + (1 - mask) * bg
    OUT/masks/00000.png    8-bit grey, the render's alpha (soft at the silhouette)
    OUT/tracking.npz       the exact trajectory and camera, canonical sequence format
"""
