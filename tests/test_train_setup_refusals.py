"""Training refuses at set-up what would fail at its first step (issue 33)."""

import shutil

import numpy as np
import pytest

from archhead_addon.flame.model import load_model
from archhead_addon.io.errors import InputError, InputWarning
from archhead_addon.train.dataset import TRACKING_FILE, FrameDataset


def test_codes_beyond_what_training_can_use_are_refused_at_set_up(tiny_subject, tmp_path):
    subject = tmp_path / "subject"
    shutil.copytree(tiny_subject, subject)
    with np.load(subject / TRACKING_FILE) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["expr"] = np.full_like(arrays["expr"], 1e30)  # read with a warning; Inf at step 1
    np.savez(subject / TRACKING_FILE, **arrays)
    with (
        pytest.raises(InputError, match="'expr': magnitude 1e\\+30 .* beyond what training"),
        pytest.warns(InputWarning, match="'expr': magnitude 1e\\+30 is above the plausible"),
    ):
        FrameDataset(subject, 48, load_model(), split="train")
