"""FLAME-format head models: files, the built-in model, linear blend skinning, teeth."""

from .model import JOINT_NAMES, FlameModel, load_model

__all__ = ["JOINT_NAMES", "FlameModel", "load_model"]
