"""Scene families as data: the ranges a building of each family is drawn from.

`office` is an intact office building (plastered rooms off a corridor, open-plan floors, full furniture);
`disaster` is a damaged bare reinforced-concrete structure (drifted and tilted stories, debris piles,
collapsed walls and slab panels, spalled columns, cracks, furniture thrown about). Train on one, test on
the other to measure cross-domain generalisation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from aftershock.pipeline.errors import InputError


@dataclass(frozen=True, slots=True)
class FamilySpec:
    name: str
    bays_x: tuple[int, int]  # inclusive range of column bays along x
    bays_y: tuple[int, int]
    bay_m: tuple[float, float]
    stories: tuple[int, int]
    story_height_m: tuple[float, float]
    room_width_m: tuple[float, float]
    corridor_width_m: tuple[float, float]
    open_plan_prob: float  # a side of the corridor is one open-plan room
    furniture: float  # multiplier on furniture counts
    clutter: float  # multiplier on clutter counts
    door_closed_prob: float
    wall_colors: tuple[tuple[int, int, int], ...]
    floor_colors: tuple[tuple[int, int, int], ...]
    ceiling_colors: tuple[tuple[int, int, int], ...]
    structure_colors: tuple[tuple[int, int, int], ...]  # columns and beams
    plastered: bool  # walls plaster (smooth) or bare concrete / block
    # damage
    damage: float  # 0 = intact; scales the counts below
    drift_ratio: tuple[float, float]  # inter-story drift / story height
    tilt_deg: tuple[float, float]  # magnitude of the tilt of each level about x and y
    debris_piles_per_story: tuple[int, int]
    broken_wall_prob: float
    collapsed_panels: tuple[int, int]
    damaged_column_prob: float
    cracks: tuple[int, int]
    tip_prob: float  # a piece of furniture is tipped over


FAMILIES: Final[dict[str, FamilySpec]] = {
    "office": FamilySpec(
        name="office",
        bays_x=(3, 5),
        bays_y=(2, 3),
        bay_m=(4.8, 6.6),
        stories=(2, 4),
        story_height_m=(3.2, 3.7),
        room_width_m=(3.0, 6.0),
        corridor_width_m=(1.8, 2.6),
        open_plan_prob=0.3,
        furniture=1.0,
        clutter=1.0,
        door_closed_prob=0.1,
        wall_colors=((226, 222, 212), (236, 232, 220), (208, 214, 222), (218, 230, 214), (238, 224, 204)),
        floor_colors=((92, 96, 108), (112, 92, 80), (72, 82, 102), (150, 146, 140), (176, 160, 130)),
        ceiling_colors=((240, 240, 236), (232, 232, 228)),
        structure_colors=((224, 220, 212), (200, 198, 192)),
        plastered=True,
        damage=0.0,
        drift_ratio=(0.0, 0.0),
        tilt_deg=(0.0, 0.0),
        debris_piles_per_story=(0, 0),
        broken_wall_prob=0.0,
        collapsed_panels=(0, 0),
        damaged_column_prob=0.0,
        cracks=(0, 0),
        tip_prob=0.0,
    ),
    "disaster": FamilySpec(
        name="disaster",
        bays_x=(2, 4),
        bays_y=(2, 3),
        bay_m=(5.0, 7.0),
        stories=(2, 4),
        story_height_m=(3.0, 3.6),
        room_width_m=(3.5, 7.0),
        corridor_width_m=(2.0, 3.0),
        open_plan_prob=0.4,
        furniture=0.6,
        clutter=1.6,
        door_closed_prob=0.05,
        wall_colors=((178, 174, 166), (160, 152, 142), (190, 180, 164), (150, 150, 150), (196, 188, 176)),
        floor_colors=((150, 140, 125), (130, 124, 116), (165, 155, 140)),
        ceiling_colors=((170, 168, 160), (158, 154, 148)),
        structure_colors=((172, 168, 160), (150, 146, 140), (184, 178, 168)),
        plastered=False,
        damage=1.0,
        drift_ratio=(0.002, 0.012),
        tilt_deg=(0.1, 1.3),
        debris_piles_per_story=(3, 7),
        broken_wall_prob=0.25,
        collapsed_panels=(1, 2),
        damaged_column_prob=0.3,
        cracks=(12, 30),
        tip_prob=0.35,
    ),
}


def family_spec(name: str) -> FamilySpec:
    try:
        return FAMILIES[name]
    except KeyError:
        raise InputError(f"unknown scene family {name!r} (known: {', '.join(FAMILIES)})") from None
