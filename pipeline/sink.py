"""The sink interface, owned by the stream that calls it: sinks are the only code that writes. The stream
hands every frame to every sink after each stage, and the accumulated map and on-demand results when they
are ready. Sinks (`aftershock.sinks`) implement it; nothing here knows about them."""

from __future__ import annotations

from enum import StrEnum

import numpy as np

from aftershock.pipeline.structure.elements import Element
from aftershock.pipeline.types import DamageFound, Frame, InstanceMerge, LabelledCloud, RunInfo, RunSummary


class Stage(StrEnum):
    RAW = "raw"
    REGISTERED = "registered"
    LABELLED = "labelled"
    CLUSTERED = "clustered"


class Sink:
    """Base class with no-op hooks; a sink overrides the ones it needs. `close` is always called, also on Ctrl-C."""

    def begin(self, info: RunInfo) -> None:
        """Before the first frame: static layers (annotation context, blueprint, file headers)."""

    def stage(self, frame: Frame, stage: Stage) -> None:
        """After each stage of each frame."""

    def merges(self, merges: list[InstanceMerge], seq: int) -> None:
        """Instances joined outside a frame (the end-of-run consolidation); per-frame ones are on `frame.merges`."""

    def map_update(self, cloud: LabelledCloud, seq: int) -> None:
        """The accumulated labelled map as of scan `seq` (sent every few scans, and once at the end)."""

    def structure(self, elements: list[Element], seq: int, notes: list[str]) -> None:
        """The building's structural elements as of scan `seq` (with the map's updates, and once at the end,
        before `end`); `notes` says what the structure model could not do (no floor found)."""

    def refined(self, cloud: LabelledCloud, steps: list[tuple[np.ndarray, np.ndarray]] | None = None) -> None:
        """LRGNet's re-segmentation of the map; `steps` = (inlier indices, neighbour indices) of one object's growth."""

    def damage(self, found: DamageFound) -> None:
        """Cracks and story drift/tilt found on the map; `found.report` is the whole damage report as JSON data."""

    def end(self, summary: RunSummary, final_map: LabelledCloud) -> None:
        """After the last frame (also after an interruption), with what was measured."""

    def close(self) -> None:
        """Flush and release files; must leave valid output even after an interruption."""
