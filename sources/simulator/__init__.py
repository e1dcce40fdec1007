"""The simulator of damaged buildings: procedural scenes, a virtual LiDAR on a walking robot, full truth.

scene = build_scene("disaster", seed=3)
for scan in Mission(scene, get_profile("vlp16"), scans=50):
    ...
static = scene.sample_static_cloud(spacing_m=0.05, seed=0)
"""

from aftershock.sources.simulator.building import build_scene
from aftershock.sources.simulator.cracks import ELEMENTS, cracked_element
from aftershock.sources.simulator.damage import CrackTruth
from aftershock.sources.simulator.families import FAMILIES, FamilySpec
from aftershock.sources.simulator.mission import Mission
from aftershock.sources.simulator.profiles import PROFILES, SensorProfile, get_profile
from aftershock.sources.simulator.scene import Scene, SceneTruth, StoryTruth

__all__ = [
    "ELEMENTS",
    "FAMILIES",
    "PROFILES",
    "CrackTruth",
    "FamilySpec",
    "Mission",
    "Scene",
    "SceneTruth",
    "SensorProfile",
    "StoryTruth",
    "build_scene",
    "cracked_element",
    "get_profile",
]
