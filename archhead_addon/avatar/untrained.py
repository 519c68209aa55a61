"""Write an untrained avatar of the built-in model (benchmarks and tests of decode cost):

python -m archhead_addon.avatar.untrained OUT.npz [--seed 0]
"""

from __future__ import annotations

import argparse
import sys


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    import torch

    from ..flame import load_model
    from .checkpoint import save_avatar
    from .model import ArchHeadAvatar

    torch.manual_seed(args.seed)
    save_avatar(args.out, ArchHeadAvatar.create(load_model()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
