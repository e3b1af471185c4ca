"""The simulator: scenes -> loads -> pillar resistances, through the listed effects."""

from sim.dataset import generate_dataset
from sim.scene import (
    LoadSpec,
    PatchSpec,
    Scene,
    load_scene,
    on_patches,
    scene_from_dict,
    shipped_scenes,
)
from sim.simulator import Frame, Simulator

__all__ = [
    "Frame",
    "LoadSpec",
    "PatchSpec",
    "Scene",
    "Simulator",
    "generate_dataset",
    "load_scene",
    "on_patches",
    "scene_from_dict",
    "shipped_scenes",
]
