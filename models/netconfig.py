"""What a network weights file was built with (MCPNet, its no-context variant, PointNet): widths, the feature
layout and the labelling range. Recorded in every weights file so that a file trained on another layout is
refused."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Final

from aftershock.pipeline.classes import NETWORK_CLASSES

# Feature layout, recorded in every weights file so that a file trained on another layout is refused.
POINT_FEATURES: Final[tuple[str, ...]] = ("x", "y", "z", "r", "g", "b", "has_color")
CONTEXT_FEATURES: Final[tuple[str, ...]] = ("dx", "dy", "dz", "dr", "dg", "db")
POINT_DIM: Final = len(POINT_FEATURES)
CONTEXT_DIM: Final = len(CONTEXT_FEATURES)
# Local shape of a voxel's neighbourhood, from its context points (what transfers between buildings: how
# upright, flat, line-like or scattered the surface is, and how far it reaches up and down).
GEOMETRY_FEATURES: Final[tuple[str, ...]] = ("abs_nz", "planarity", "linearity", "sphericity", "dz_std")
# The same shape at a wider view (a second, coarser context, #12): 1.5 m reaches past a table top to the floor
# around it, or up a wall; plus how far the surroundings reach above and below the point.
COARSE_GEOMETRY_FEATURES: Final[tuple[str, ...]] = (
    "abs_nz_wide",
    "planarity_wide",
    "linearity_wide",
    "sphericity_wide",
    "dz_std_wide",
    "dz_max_wide",
    "dz_min_wide",
)
COARSE_CONTEXT_FEATURES: Final[tuple[str, ...]] = ("dx", "dy", "dz")  # geometry only: colour habits do not transfer
COARSE_CONTEXT_DIM: Final = len(COARSE_CONTEXT_FEATURES)
# MCPNet since #12: height, colour, the local shape at two scales (x, y relative to the robot left out: they carry
# the simulator's paths and room sizes rather than what a point is).
TRANSFER_FEATURES: Final[tuple[str, ...]] = POINT_FEATURES[2:] + GEOMETRY_FEATURES + COARSE_GEOMETRY_FEATURES
# Evidence from the live structure model of the building (#28, pipeline.structure.features computes them): height
# above the storey's floor plane, distance to the nearest wall plane, inside a column's footprint, under a slab.
STRUCTURE_FEATURES: Final[tuple[str, ...]] = ("height_above_floor", "wall_distance", "in_column", "under_slab")
STRUCTURE_TRANSFER_FEATURES: Final[tuple[str, ...]] = TRANSFER_FEATURES + STRUCTURE_FEATURES
# The layouts this version runs, per kind of network (the baselines read no context, so no shape either).
LAYOUTS: Final[dict[str, tuple[tuple[str, ...], ...]]] = {
    "mcpnet": (STRUCTURE_TRANSFER_FEATURES, TRANSFER_FEATURES, POINT_FEATURES),
    "mcpnet-nocontext": (POINT_FEATURES,),
    "pointnet": (POINT_FEATURES,),
}


@dataclass(frozen=True, slots=True)
class NetConfig:
    """What a weights file was built with: widths, the feature layout and how features were normalised."""

    kind: str = "mcpnet"  # mcpnet | mcpnet-nocontext | pointnet
    point_dim: int = POINT_DIM
    context_dim: int = CONTEXT_DIM
    width: int = 200
    embed_dim: int = 50
    num_classes: int = NETWORK_CLASSES
    context_points: int = 50
    context_cell_m: float = 0.3
    voxel_m: float = 0.1
    range_m: float = 4.0  # horizontal labelling range the network was trained with (see LabelConfig)
    features: tuple[str, ...] = POINT_FEATURES
    context_features: tuple[str, ...] = CONTEXT_FEATURES
    coarse_points: int = 0  # the wider context's draws (0: none)
    coarse_cell_m: float = 0.5  # its 3 x 3 x 3 cells: a 1.5 m block
    coarse_width: int = 64

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["features"] = list(self.features)
        d["context_features"] = list(self.context_features)
        return d

    @staticmethod
    def from_dict(d: dict[str, Any]) -> NetConfig:
        d = dict(d)
        d["features"] = tuple(d.get("features", ()))
        d["context_features"] = tuple(d.get("context_features", ()))
        return NetConfig(**d)

    @property
    def geometry(self) -> bool:
        """Whether the point features include the local shape from the context."""
        return any(f in self.features for f in GEOMETRY_FEATURES + COARSE_GEOMETRY_FEATURES)

    @property
    def structure(self) -> bool:
        """Whether the point features include the structure model's evidence (the labeller needs the live model)."""
        return any(f in self.features for f in STRUCTURE_FEATURES)
