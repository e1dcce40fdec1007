"""The simulator of damaged buildings: procedural scenes, a virtual LiDAR on a walking robot, full truth.

scene = build_scene("disaster", seed=3)
for scan in Mission(scene, get_profile("vlp16"), scans=50):
    ...
static = scene.sample_static_cloud(spacing_m=0.05, seed=0)
"""

from sources.simulator.building import build_scene
from sources.simulator.cracks import ELEMENTS, cracked_element
from sources.simulator.damage import CrackTruth
from sources.simulator.families import FAMILIES, FamilySpec
from sources.simulator.mission import Mission
from sources.simulator.profiles import PROFILES, SensorProfile, get_profile
from sources.simulator.scene import Scene, SceneTruth, StoryTruth

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
