"""Face tracking from a plain video on a CPU: MediaPipe landmarks fitted with FLAME.

`python -m archhead_addon track VIDEO --out DIR` writes a training data folder
(`archhead_addon.train` reads it). The pieces:

- `media`: frames from a video file, a folder of numbered images or one image;
- `detect`: MediaPipe Face Mesh (478 landmarks with iris) and selfie segmentation, from the
  models inside the `mediapipe==0.10.21` wheel (never downloaded);
- `embedding`: where those landmarks sit on any FLAME-format model, derived by rendering the
  model and detecting landmarks on the renders (no MPI asset);
- `fit`: identity, per-frame expression, jaw, eyes, head pose, translation and focal length
  from the landmarks, with priors and temporal smoothness (torch);
- `folder`: the training folder, written into a temporary sibling and renamed when complete;
- `pipeline`: the whole run with progress; `accuracy`: measurements against known codes.
"""

# Frames tracked at most, every k-th of a longer clip: every stage's time grows with the frames
# (the webcam clip's 765 took 7.9 min on 2 cores) and training's steps do not, so a minute of
# phone video at 30 fps is tracked on every 2nd frame (docs/tracking.md, "Long videos"). Here,
# not in `pipeline`: Blender's side reads it without the tracker's imports.
FRAME_BUDGET = 900
