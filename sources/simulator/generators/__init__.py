"""Scene generators by name: the two families of `building.py` and generators built independently of them.

    scene = generate("wing", seed=3, palette="random")

`office` and `disaster` are the families (families.py); `hall` (open hall on a column grid, mezzanine,
racks), `wing` (a turning corridor with doors along it, L-shaped rooms round closets and washrooms) and
`flats` (a floor of flats, hotel rooms or a dormitory: stair core and lift lobby, a double-loaded corridor,
an access gallery or a dogleg, apartments of hall, passage, bathroom, kitchen, living room and bedrooms)
share none of their layout, furniture or damage code with the families. `hall` and `wing` share the low-level
parts (parts.py), some pieces (things.py) and the damage kinds (wreck.py) with each other; `flats` takes only
walls, slabs, openings, footprints and `finish` from parts.py. `palette` repaints any of them (looks.py).
"""

from __future__ import annotations

from collections.abc import Callable
from importlib import import_module
from typing import Final

from aftershock.pipeline.errors import InputError
from aftershock.sources.simulator.scene import Scene


def _family(name: str) -> Callable[[int], Scene]:
    def build(seed: int) -> Scene:
        from aftershock.sources.simulator.building import build_scene

        return build_scene(name, seed)

    return build


def _independent(module: str) -> Callable[[int], Scene]:
    """The `build(seed)` of an independent generator's module, imported when first used."""

    def build(seed: int) -> Scene:
        return import_module(f"{__name__}.{module}").build(seed)

    return build


GENERATORS: Final[dict[str, Callable[[int], Scene]]] = {
    "office": _family("office"),
    "disaster": _family("disaster"),
    "hall": _independent("hall"),
    "wing": _independent("wing"),
    "flats": _independent("flats"),
}


def check_generator(name: str) -> None:
    if name not in GENERATORS:
        raise InputError(f"unknown scene generator {name!r} (known: {', '.join(GENERATORS)})")


def generate(name: str, seed: int, palette: str = "natural") -> Scene:
    """The scene of generator `name` and `seed` (deterministic), repainted with `palette`."""
    from aftershock.sources.simulator.looks import check_palette, repaint

    check_generator(name)
    check_palette(palette)
    scene = GENERATORS[name](int(seed))
    if palette != "natural":
        repaint(scene, palette, int(seed))
    return scene
