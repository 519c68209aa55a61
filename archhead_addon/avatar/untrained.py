"""Write an untrained avatar of the built-in model (benchmarks and tests of decode cost):

python -m archhead_addon.avatar.untrained OUT.npz [--seed 0] [--preset demo]

Without --preset the avatar has the model's full size (S_max 256: about 60k Gaussians at
LOD 0); with one, the size of that training preset's avatars.
"""

from __future__ import annotations

import argparse
import sys


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--preset", help="a training preset or config whose avatar size to use")
    args = parser.parse_args(argv)
    import torch

    from ..flame import load_model
    from ..train.config import TrainConfig
    from .checkpoint import save_avatar
    from .model import ArchHeadAvatar

    torch.manual_seed(args.seed)
    model = load_model()
    config = TrainConfig.load(args.preset).avatar_config(model.n_expr) if args.preset else None
    save_avatar(args.out, ArchHeadAvatar.create(model, config=config))
    return 0


if __name__ == "__main__":
    sys.exit(main())
