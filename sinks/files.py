"""File exports into one folder: the final labelled map, the trajectory in two common text formats, a summary.

- `map.ply`: the final labelled map in the DESIGN.md PLY format (`x y z`, `red green blue` = class colour,
  `class_id`, `instance_id`, and `confidence`: the labeller's probability for the class), through
  `pipeline.cloud_io.write_cloud`.
- `poses_tum.txt`: `timestamp tx ty tz qx qy qz qw` per scan (TUM RGB-D format, seconds since the epoch).
- `poses_kitti.txt`: the first three rows of each 4 x 4 pose, row-major, 12 numbers per line (KITTI odometry).
- `summary.json`: the `RunSummary` fields, the source, and per-class instance and point counts of the map.
- `refined.ply` (with `run --refine`): the map with LRGNet's class-agnostic `instance_id`.
- `damage.json` (with `run --damage`): the damage report — cracks with length and width, stories with drift
  and tilt, and what could not be measured.

Poses are the sensor poses at the scan stamps, written line by line as the scans are registered (into
`poses_tum.txt.part`, renamed when the run ends), so an interrupted run keeps every pose it computed, and a killed
one leaves them in the `.part` files; the map and summary are written at the end (also after Ctrl-C). The folder is
locked while the run writes it (`pipeline.outputs.FolderLock`): a second run into it is refused naming the first.
"""

from __future__ import annotations

import json
from contextlib import suppress
from dataclasses import asdict, replace
from pathlib import Path
from typing import IO, Final

import numpy as np

from aftershock.pipeline.classes import CLASS_NAMES, NUM_CLASSES, class_colors
from aftershock.pipeline.cloud_io import write_cloud
from aftershock.pipeline.errors import OutputError
from aftershock.pipeline.outputs import FolderLock, StreamedOutput, check_output, write_atomically
from aftershock.pipeline.pointcloud2 import matrix_to_quaternion
from aftershock.pipeline.sink import Sink, Stage
from aftershock.pipeline.structure.elements import Element
from aftershock.pipeline.types import DamageFound, Frame, LabelledCloud, RunInfo, RunSummary
from aftershock.sinks.structure_layer import write_structure_json

MAP_FILE: Final = "map.ply"
TUM_FILE: Final = "poses_tum.txt"
KITTI_FILE: Final = "poses_kitti.txt"
SUMMARY_FILE: Final = "summary.json"
REFINED_FILE: Final = "refined.ply"
DAMAGE_FILE: Final = "damage.json"
STRUCTURE_FILE: Final = "structure.json"


def tum_line(stamp_ns: int, pose: np.ndarray) -> str:
    """One TUM trajectory line; the stamp is printed exactly (integer seconds and nanoseconds)."""
    sec, ns = divmod(int(stamp_ns), 1_000_000_000)
    t = pose[:3, 3]
    q = matrix_to_quaternion(pose[:3, :3])
    values = " ".join(f"{v:.9g}" for v in (*t, *q))
    return f"{sec}.{ns:09d} {values}\n"


def kitti_line(pose: np.ndarray) -> str:
    return " ".join(f"{v:.9g}" for v in np.asarray(pose, dtype=np.float64)[:3, :4].reshape(-1)) + "\n"


def map_statistics(cloud: LabelledCloud) -> dict[str, dict[str, int]]:
    """Points per class and distinct instances per class (by each instance's majority class) of a map."""
    out: dict[str, dict[str, int]] = {"points_per_class": {}, "instances_per_class": {}}
    if cloud.class_ids is None:
        return out
    cls = cloud.class_ids.astype(np.int64)
    known = cls < NUM_CLASSES
    counts = np.bincount(cls[known], minlength=NUM_CLASSES)
    out["points_per_class"] = {CLASS_NAMES[c]: int(counts[c]) for c in np.flatnonzero(counts)}
    if cloud.instance_ids is not None:
        inst = cloud.instance_ids.astype(np.int64)
        ok = known & (inst > 0)
        if ok.any():
            ids, inv = np.unique(inst[ok], return_inverse=True)
            votes = np.zeros((len(ids), NUM_CLASSES), np.int64)
            np.add.at(votes, (inv.reshape(-1), cls[ok]), 1)
            per_class = np.bincount(votes.argmax(axis=1), minlength=NUM_CLASSES)
            out["instances_per_class"] = {CLASS_NAMES[c]: int(per_class[c]) for c in np.flatnonzero(per_class)}
    return out


class FileExportSink(Sink):
    """Writes map.ply, poses_tum.txt, poses_kitti.txt and summary.json into `folder`.

    Every path is checked when the sink is made (exists without `force`, folder not writable); files are
    created from `begin` on.
    """

    def __init__(self, folder: Path, force: bool = False, refine: bool = False, damage: bool = False) -> None:
        self.folder = Path(folder)
        if self.folder.exists() and not self.folder.is_dir():
            raise OutputError("exists and is not a folder", self.folder)
        self._lock = FolderLock(self.folder).acquire()
        try:
            self.map_path = check_output(self.folder / MAP_FILE, force)
            self.tum_path = check_output(self.folder / TUM_FILE, force)
            self.kitti_path = check_output(self.folder / KITTI_FILE, force)
            self.summary_path = check_output(self.folder / SUMMARY_FILE, force)
            self.refined_path = check_output(self.folder / REFINED_FILE, force) if refine else None
            self.damage_path = check_output(self.folder / DAMAGE_FILE, force) if damage else None
            self.structure_path = check_output(self.folder / STRUCTURE_FILE, force)
        except OutputError:
            self._lock.release()  # a refused sink is never closed: it must not keep the folder locked
            raise
        self._structure: tuple[list[Element], list[str]] | None = None
        self.force = force
        self._info: RunInfo | None = None
        self._tum: IO[str] | None = None
        self._kitti: IO[str] | None = None
        self._tum_out = StreamedOutput(self.tum_path)
        self._kitti_out = StreamedOutput(self.kitti_path)
        self._written: set[int] = set()
        self._poses_closed = False
        self._failed = False  # the disk refused a pose line: the map and summary are not attempted
        self.poses_written = 0

    def begin(self, info: RunInfo) -> None:
        self._info = info
        self._open_poses()

    def stage(self, frame: Frame, stage: Stage) -> None:
        if stage is not Stage.REGISTERED or frame.seq in self._written:
            return
        pose = frame.stamp_pose if frame.stamp_pose is not None else frame.pose
        if pose is None or not self._open_poses():
            return
        assert self._tum is not None and self._kitti is not None
        self._written.add(frame.seq)
        # Flushed with each scan: after a SIGKILL or a crash the pose files hold every pose of every scan
        # that reached the sinks (a few hundred bytes a scan; the OS still decides when they reach the disk).
        for f, line, path in (
            (self._tum, tum_line(frame.scan.stamp_ns, pose), self.tum_path),
            (self._kitti, kitti_line(pose), self.kitti_path),
        ):
            try:
                f.write(line)
                f.flush()
            except OSError as exc:
                self._failed = True
                self._close_poses()
                raise OutputError(
                    f"cannot write: {exc.strerror or exc}; the poses before stay readable", path
                ) from None
        self.poses_written += 1

    def end(self, summary: RunSummary, final_map: LabelledCloud) -> None:
        self._close_poses()
        if self._failed:
            return
        cloud = final_map
        if cloud.class_ids is not None and cloud.colors is None:
            cloud = replace(cloud, colors=class_colors(cloud.class_ids), normals=None)
        # the path was checked at construction; class colours stand in for a colour the log did not have
        write_cloud(self.map_path, cloud, force=True, stand_in_color=final_map.colors is None)
        data = asdict(summary)
        stats = map_statistics(final_map)
        if not data["instances_per_class"]:
            data["instances_per_class"] = stats["instances_per_class"]
        data["map_points"] = len(final_map)
        data["map_points_per_class"] = stats["points_per_class"]
        data["poses_written"] = self.poses_written
        if self._info is not None:
            data["source"] = asdict(self._info)
        data["files"] = {"map": MAP_FILE, "poses_tum": TUM_FILE, "poses_kitti": KITTI_FILE}
        if self._structure is not None:
            elements, notes = self._structure
            data["files"]["structure"] = STRUCTURE_FILE
            write_atomically(self.structure_path, lambda tmp: write_structure_json(tmp, elements, notes))
        text = json.dumps(data, indent=2) + "\n"
        write_atomically(self.summary_path, lambda tmp: tmp.write_text(text))

    def structure(self, elements: list[Element], seq: int, notes: list[str]) -> None:
        self._structure = (elements, notes)  # written with the map, at the end

    def refined(self, cloud: LabelledCloud, steps: list[tuple[np.ndarray, np.ndarray]] | None = None) -> None:
        if self.refined_path is not None:
            write_cloud(self.refined_path, cloud, force=True)  # checked at construction

    def damage(self, found: DamageFound) -> None:
        if self.damage_path is None or found.report is None:
            return
        text = json.dumps(found.report, indent=2) + "\n"
        write_atomically(self.damage_path, lambda tmp: tmp.write_text(text))

    def close(self) -> None:
        try:
            self._close_poses()
        finally:
            self._lock.release()

    def _open_poses(self) -> bool:
        """Open the pose files once (in `begin`, or with the first pose); False once they were closed."""
        if self._poses_closed:
            return False
        if self._tum is None or self._kitti is None:
            try:
                self._tum = self._tum_out.open("w")
                self._kitti = self._kitti_out.open("w")
            except OSError as exc:
                raise OutputError(f"cannot write: {exc.strerror}", self.folder) from None
        return True

    def _close_poses(self) -> None:
        for f, out in ((self._tum, self._tum_out), (self._kitti, self._kitti_out)):
            if f is not None:
                with suppress(OSError):  # a write that failed before was reported; the lines before it are kept
                    out.close()
                self._poses_closed = True
        self._tum = self._kitti = None
