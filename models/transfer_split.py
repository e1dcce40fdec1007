"""The data split of the transfer benchmark and of training meant to transfer, defined once.

One scene generator (`wing`) stays out of all training and of every choice of settings: it is touched only by
`make bench-transfer`. Training uses the other generators' training seeds; settings are chosen on their
validation seeds; test seeds of every generator are never trained on or looked at while choosing.
Benchmark missions are the issue's setting: a VLP-16 at 1.0 m on a wheeled robot driving 1 m/s and turning
at 45 deg/s.
"""

from __future__ import annotations

from typing import Final

FAMILIES: Final[tuple[str, ...]] = ("office", "disaster")  # what the weights shipped before #12 were trained on
TRAIN_GENERATORS: Final[tuple[str, ...]] = ("office", "disaster", "hall")
HELDOUT_GENERATOR: Final = "wing"
TRAIN_SEEDS: Final[tuple[int, ...]] = tuple(range(100, 110))
VALIDATION_SEEDS: Final[tuple[int, ...]] = (800, 801)
TEST_SEEDS: Final[tuple[int, ...]] = (900, 901)
BENCH_SENSOR: Final = "vlp16"
BENCH_ROBOT: Final = "robot=wheeled&height=1&speed=1&turn=45"


def bench_uri(generator: str, seed: int, scans: int, color: bool = True) -> str:
    """The benchmark's mission of one generator and seed, with or without colour."""
    uri = f"sim://{generator}?seed={seed}&sensor={BENCH_SENSOR}&scans={scans}&{BENCH_ROBOT}"
    return uri if color else uri + "&color=0"
