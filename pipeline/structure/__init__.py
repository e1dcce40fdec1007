"""The structure model of a building (slabs, walls, columns, beams; the ground outdoors) and the labels it decides."""

from aftershock.pipeline.structure.elements import Element, Kind
from aftershock.pipeline.structure.model import StructureModel

__all__ = ["Element", "Kind", "StructureModel"]
