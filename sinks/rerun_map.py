"""The map layers of a recording: `world/map/x{i}y{j}` (the labelled map, tile by tile) and
`world/uncertain/x{i}y{j}` (the tile's voxels the labeller is unsure of, drawn larger over it). At each update only
the tiles `rerun_tiles` found changed are logged again, only their labels where their points stayed.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from aftershock.pipeline.config import RerunConfig
from aftershock.pipeline.types import LabelledCloud
from aftershock.sinks import rerun_blueprint as L
from aftershock.sinks import rerun_convert as C
from aftershock.sinks.rerun_tiles import MapTiles


class MapLayer:
    """The tiles last logged (`rerun_tiles.MapTiles`) and the uncertain-voxel tiles not cleared since."""

    def __init__(self, cfg: RerunConfig) -> None:
        self.cfg = cfg
        self.tiles = MapTiles(cfg.map_voxel_m, cfg.map_tile_m)
        self._uncertain: set[str] = set()

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The extent of the last map that had points (story planes span it)."""
        return self.tiles.bounds

    def log(self, rec: rr.RecordingStream, cloud: LabelledCloud) -> None:
        """Re-log only the map tiles whose content changed since the last update."""
        update = self.tiles.update(cloud)
        if update is None:
            return
        radius = C.MAP_RADIUS_OF_VOXEL * self.cfg.map_voxel_m
        colors = update.colors
        for tile in update.changed:
            name, sel = f"{L.MAP}/{tile.name}", tile.sel
            conf = update.confidence[sel] if update.confidence is not None else None
            self._log_uncertain(rec, tile.name, update.points[sel], conf)
            if tile.labels_only:
                rec.log(name, *C.tile_labels(update.class_ids[sel], update.instance_ids[sel], conf))
                continue
            cls = update.class_ids[sel] if colors is None else None
            tile_colors = colors[sel] if colors is not None else None
            rec.log(name, *C.map_tile(update.points[sel], cls, tile_colors, update.instance_ids[sel], radius, conf))
        for gone in update.gone:
            rec.log(f"{L.MAP}/{gone}", rr.Clear(recursive=False))
            self._log_uncertain(rec, gone, np.zeros((0, 3)), None)

    def _log_uncertain(
        self, rec: rr.RecordingStream, tile: str, points: np.ndarray, confidence: np.ndarray | None
    ) -> None:
        """The tile's voxels under `cfg.uncertain_below`, over the map in one colour (cleared when none is left)."""
        name = f"{L.UNCERTAIN}/{tile}"
        low = np.zeros(len(points), bool) if confidence is None else confidence < self.cfg.uncertain_below
        if confidence is not None and low.any():
            self._uncertain.add(name)
            radius = C.UNCERTAIN_RADIUS_OF_VOXEL * self.cfg.map_voxel_m
            rec.log(name, *C.uncertain_points(points[low], confidence[low], radius))
        elif name in self._uncertain:
            self._uncertain.discard(name)
            rec.log(name, rr.Clear(recursive=False))
