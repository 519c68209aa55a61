"""The synthetic subject's motion: a seeded FLAME trajectory of the built-in head and a fixed
camera in front of it.

Every signal is pose-to-pose animation: random key values, each held for a while and then
eased into the next (smoothstep, so velocity is zero at the keys and continuous everywhere).
What moves, per frame:

- head: neck turns within +-26 degrees yaw, +-12 pitch, +-8 roll, plus a global sway of
  +-4 degrees and +-8 mm, so the head never turns more than 30 degrees from the camera;
- jaw: talking (syllables at 2.5-4 Hz under an on/off envelope) and a few wide openings,
  with the `jaw_open` expression following the jaw rotation;
- the other named expressions (smile ... sneer) switch on and off at random strengths; the
  blinks are short events every 1.5-5 s; expressions 10 and up wander at sizes that decay
  with the component index;
- eyes: fixations held 0.3-1.5 s joined by fast glances (saccades of 40-90 ms).

Each signal draws from its own random stream (a child of `seed`) key by key, so the same
seed gives the same motion bit for bit, and a shorter clip is a prefix of a longer one.
"""

from __future__ import annotations

import numpy as np

from ..flame.builtin.blendshapes import EXPRESSION_NAMES
from ..sequences.sequence import Sequence

EXPRESSION_PEAKS = {
    "smile": 1.0,
    "brow_raise": 1.0,
    "pucker": 0.8,
    "frown": 0.8,
    "cheek_puff": 0.7,
    "lip_press": 0.8,
    "sneer": 0.8,
}
NECK_LIMITS = np.radians([12.0, 26.0, 8.0])  # pitch (x), yaw (y), roll (z)
SWAY_LIMITS = np.radians([4.0, 4.0, 4.0])
TRANSLATION_LIMITS = np.array([0.008, 0.008, 0.005])  # metres
JAW_MAX = 0.3  # radians of opening
JAW_OPEN_PER_RADIAN = 2.0  # the jaw_open expression per radian of jaw rotation
EYE_LIMITS = np.array([0.2, 0.35])  # pitch, yaw in radians
CAMERA_DISTANCE = 0.9  # metres from the FLAME origin to the camera
CAMERA_TARGET_Y = -0.004  # metres; the height the camera looks at (the nose)
FOCAL_PER_PIXEL = 2.8  # focal length in units of the image width (a 20 degree view)
_STREAMS = (
    "neck",
    "sway",
    "translation",
    "talk",
    "syllables",
    "wide",
    "named",
    "blinks",
    "wander",
    "eyes",
)


def eased_keys(
    rng: np.random.Generator,
    times: np.ndarray,
    hold: tuple[float, float],
    move: tuple[float, float],
    draw,
) -> np.ndarray:
    """Values at `times` (s) of keys drawn by `draw()`, each held `hold` s, then eased into the
    next over `move` s (both uniform in the given ranges). Shape (T, *draw().shape)."""
    knot_t, knot_v = [0.0], [np.asarray(draw(), dtype=np.float64)]
    while knot_t[-1] <= times[-1]:
        held = knot_t[-1] + rng.uniform(*hold)
        knot_t += [held, held + rng.uniform(*move)]
        knot_v += [knot_v[-1], np.asarray(draw(), dtype=np.float64)]
    knot_t, knot_v = np.array(knot_t), np.array(knot_v)
    i = np.searchsorted(knot_t, times, side="right") - 1
    span = np.maximum(knot_t[i + 1] - knot_t[i], 1e-12)
    u = np.clip((times - knot_t[i]) / span, 0.0, 1.0)
    ease = (u * u * (3 - 2 * u)).reshape(-1, *([1] * (knot_v.ndim - 1)))
    return knot_v[i] + (knot_v[i + 1] - knot_v[i]) * ease


def _blinks(rng: np.random.Generator, times: np.ndarray) -> np.ndarray:
    """Lid closure in [0, 1]: events every 1.5-5 s, closing in 70 ms and opening in 150 ms."""
    closure = np.zeros_like(times)
    start = rng.uniform(0.3, 2.0)
    while start <= times[-1]:
        close, reopen = 0.07, 0.15
        u = times - start
        closing = (u >= 0) & (u < close)
        opening = (u >= close) & (u < close + reopen)
        closure[closing] = np.sin(0.5 * np.pi * u[closing] / close) ** 2
        closure[opening] = np.cos(0.5 * np.pi * (u[opening] - close) / reopen) ** 2
        start += rng.uniform(1.5, 5.0)
    return closure


def _jaw(rngs: dict, times: np.ndarray) -> np.ndarray:
    """Jaw opening in [0, JAW_MAX]: talking under an on/off envelope, and wide openings."""
    talk_rng = rngs["talk"]
    envelope = eased_keys(
        talk_rng,
        times,
        (0.2, 1.2),
        (0.2, 0.5),
        lambda: talk_rng.uniform(0.4, 1.0) * (talk_rng.random() < 0.65),
    )
    rate = rngs["syllables"].uniform(2.5, 4.0)
    phase = rngs["syllables"].uniform(0, 2 * np.pi)
    syllables = (1 - np.cos(2 * np.pi * rate * times + phase)) / 2
    talk = 0.85 * envelope * syllables
    wide_rng = rngs["wide"]
    wide = eased_keys(
        wide_rng,
        times,
        (0.5, 2.5),
        (0.3, 0.7),
        lambda: wide_rng.uniform(0.6, 1.0) * (wide_rng.random() < 0.2),
    )
    return JAW_MAX * np.clip(np.maximum(talk, wide), 0.0, 1.0)


def _expressions(rngs: dict, times: np.ndarray, jaw_open: np.ndarray, n_expr: int):
    expr = np.zeros((len(times), n_expr))
    expr[:, EXPRESSION_NAMES.index("jaw_open")] = JAW_OPEN_PER_RADIAN * jaw_open
    rng = rngs["named"]
    peaks = np.array(list(EXPRESSION_PEAKS.values()))
    named = eased_keys(
        rng,
        times,
        (0.2, 1.5),
        (0.3, 0.9),
        lambda: peaks * rng.uniform(0.3, 1.0, len(peaks)) * (rng.random(len(peaks)) < 0.3),
    )
    for k, name in enumerate(EXPRESSION_PEAKS):
        expr[:, EXPRESSION_NAMES.index(name)] = named[:, k]
    blink = _blinks(rngs["blinks"], times)
    expr[:, EXPRESSION_NAMES.index("blink_left")] = blink
    expr[:, EXPRESSION_NAMES.index("blink_right")] = blink
    n_named = len(EXPRESSION_NAMES)
    if n_expr > n_named:
        sizes = np.exp(-np.arange(n_expr - n_named) / 25.0)
        rng = rngs["wander"]
        expr[:, n_named:] = eased_keys(
            rng, times, (0.0, 0.4), (0.5, 1.2), lambda: rng.normal(0.0, sizes)
        )
    return expr


def synthetic_sequence(
    frames: int = 300,
    size: int = 256,
    seed: int = 0,
    fps: float = 25.0,
    n_shape: int = 300,
    n_expr: int = 100,
) -> Sequence:
    """The trajectory (module docstring) with a fixed camera for square `size` images.

    The identity is the built-in head's own (shape codes zero)."""
    if frames < 1 or size < 1:
        raise ValueError(f"frames and size must be positive, got {frames} and {size}")
    if n_expr < len(EXPRESSION_NAMES):
        raise ValueError(f"n_expr must be at least {len(EXPRESSION_NAMES)}, got {n_expr}")
    children = np.random.SeedSequence(seed).spawn(len(_STREAMS))
    rngs = {name: np.random.default_rng(s) for name, s in zip(_STREAMS, children, strict=True)}
    times = np.arange(frames) / fps

    def box(name, limits, hold, move):
        rng = rngs[name]
        return eased_keys(rng, times, hold, move, lambda: rng.uniform(-limits, limits))

    neck = box("neck", NECK_LIMITS, (0.1, 1.0), (1.0, 2.5))
    rotation = box("sway", SWAY_LIMITS, (0.3, 1.5), (1.5, 3.0))
    translation = box("translation", TRANSLATION_LIMITS, (0.3, 1.5), (1.5, 3.0))
    jaw_open = _jaw(rngs, times)
    eye = box("eyes", EYE_LIMITS, (0.3, 1.5), (0.04, 0.09))
    eyes = np.concatenate([eye, np.zeros((frames, 1))] * 2, axis=1)  # both eyes look alike
    zeros = np.zeros(frames)
    K, w2c = fixed_camera(size)
    return Sequence(
        shape=np.zeros((frames, n_shape)),
        expr=_expressions(rngs, times, jaw_open, n_expr),
        jaw=np.stack([jaw_open, zeros, zeros], axis=1),
        neck=neck,
        eyes=eyes,
        rotation=rotation,
        translation=translation,
        fps=fps,
        frame_ids=np.arange(frames),
        source=f"synthetic subject (seed {seed})",
        format="synthetic",
        K=np.tile(K, (frames, 1, 1)),
        w2c=np.tile(w2c, (frames, 1, 1)),
        image_size=(size, size),
    ).validate()


def fixed_camera(size: int) -> tuple[np.ndarray, np.ndarray]:
    """K (pixels, centres at +0.5) and OpenCV w2c of a camera on the +z axis facing the head."""
    f = FOCAL_PER_PIXEL * size
    K = np.array([[f, 0.0, size / 2], [0.0, f, size / 2], [0.0, 0.0, 1.0]])
    w2c = np.diag([1.0, -1.0, -1.0, 1.0])  # camera y down, looking down FLAME's -z
    w2c[:3, 3] = [0.0, CAMERA_TARGET_Y, CAMERA_DISTANCE]  # -R @ centre, centre (0, y, d)
    return K, w2c
