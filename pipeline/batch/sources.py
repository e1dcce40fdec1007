"""What `batch SOURCE...` means: the arguments expanded into missions, each with a stable folder name.

- a log file (`.mcap`, ROS 1 `.bag`, anything else that is not a list) is one mission; so is a ROS 2 bag
  folder, a `sim://…` URI, a folder of point-cloud files, or a glob that matches only point-cloud files;
- a folder is searched (recursively) for logs: every `.mcap`, `.bag` and ROS 2 bag folder in it is a mission;
- a glob is expanded and each match is taken as above;
- a text file (`.txt`, `.list`, `.lst`) lists sources, one per line (blank lines and `# comments` skipped;
  relative paths are relative to the list).

Problems found here (a path that does not exist, a glob that matches nothing, a folder without logs) are
kept as missions with an error, so they show up in the site index beside the others. Names are the file
or folder stem; when two sources share one, each gets a short hash of its full path, so names do not
depend on the order of the arguments.
"""

from __future__ import annotations

import glob
import hashlib
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from aftershock.sources import SIM_SCHEME
from aftershock.sources.bag import is_ros2_bag
from aftershock.sources.files import SUFFIXES as CLOUD_SUFFIXES
from aftershock.sources.files import is_glob

LOG_SUFFIXES: Final[tuple[str, ...]] = (".mcap", ".bag")
LIST_SUFFIXES: Final[tuple[str, ...]] = (".txt", ".list", ".lst")
MAX_LIST_DEPTH: Final = 4  # lists may name lists; this stops a list that names itself


@dataclass(frozen=True, slots=True)
class MissionSource:
    source: str  # absolute path, glob or sim:// URI, as handed to `sources.open`
    name: str = ""  # folder name under the output folder (set by `name_missions`)
    error: str | None = None  # why it cannot be a mission (reported in the index, never run)


def expand_sources(args: Iterable[str], exclude: Path | None = None) -> list[MissionSource]:
    """The missions named by the arguments, in order, duplicates removed; `exclude` (the output folder) is
    never searched for logs."""
    found: list[MissionSource] = []
    for arg in args:
        found.extend(_expand(arg, Path.cwd(), exclude, 0))
    seen: set[str] = set()
    unique = []
    for m in found:
        if m.source not in seen:
            seen.add(m.source)
            unique.append(m)
    return unique


def _expand(arg: str, base: Path, exclude: Path | None, depth: int) -> list[MissionSource]:
    arg = arg.strip()
    if arg.startswith(SIM_SCHEME):
        return [MissionSource(arg)]
    path = Path(arg).expanduser()
    if not path.is_absolute():
        path = base / path
    text = str(path)
    if is_glob(arg) and not path.exists():
        matches = sorted(Path(p) for p in glob.glob(text, recursive=True))
        if not matches:
            return [MissionSource(text, error=f"{arg}: the pattern matches nothing")]
        if all(p.is_file() and p.suffix.lower() in CLOUD_SUFFIXES for p in matches):
            return [MissionSource(text)]  # a glob of point-cloud files is one mission, as for `run`
        return [m for p in matches for m in _expand(str(p), base, exclude, depth)]
    if not path.exists():
        return [MissionSource(text, error=f"{text}: no such file or directory")]
    if path.is_dir():
        return _expand_folder(path.resolve(), exclude)
    if path.suffix.lower() in LIST_SUFFIXES:
        return _expand_list(path, exclude, depth)
    return [MissionSource(str(path.resolve()))]


def _expand_folder(folder: Path, exclude: Path | None) -> list[MissionSource]:
    if is_ros2_bag(folder):
        return [MissionSource(str(folder))]
    skip = exclude.resolve() if exclude is not None else None
    bags = sorted(p.parent for p in folder.rglob("metadata.yaml") if is_ros2_bag(p.parent))

    def inside(p: Path, roots: Iterable[Path]) -> bool:
        return any(r == p or r in p.parents for r in roots)

    logs = sorted(
        p
        for p in folder.rglob("*")
        if p.suffix.lower() in LOG_SUFFIXES and p.is_file() and not inside(p, bags)  # a ROS 2 bag's own files
    )
    found = [p for p in sorted([*bags, *logs]) if skip is None or not inside(p, [skip])]
    if found:
        return [MissionSource(str(p)) for p in found]
    if any(p.suffix.lower() in CLOUD_SUFFIXES for p in folder.iterdir() if p.is_file()):
        return [MissionSource(str(folder))]  # a folder of scans is one mission
    return [MissionSource(str(folder), error=f"{folder}: no logs (.mcap, .bag, ROS 2 bags) or point-cloud files")]


def _expand_list(path: Path, exclude: Path | None, depth: int) -> list[MissionSource]:
    if depth >= MAX_LIST_DEPTH:
        return [MissionSource(str(path), error=f"{path}: lists nested more than {MAX_LIST_DEPTH} deep")]
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) else "not a text file"
        return [MissionSource(str(path), error=f"{path}: cannot read the list ({reason})")]
    out: list[MissionSource] = []
    for line in lines:
        entry = line.split("#", 1)[0].strip() if not line.lstrip().startswith(SIM_SCHEME) else line.strip()
        if entry:
            out.extend(_expand(entry, path.parent, exclude, depth + 1))
    if not out:
        return [MissionSource(str(path), error=f"{path}: the list names no sources")]
    return out


def mission_stem(source: str) -> str:
    """A folder name for a source: the file or folder stem, or the sim:// URI flattened."""
    if source.startswith(SIM_SCHEME):
        stem = "sim-" + source[len(SIM_SCHEME) :]
    elif is_glob(source):
        p = Path(source)
        stem = f"{p.parent.name}-{p.name}"
    else:
        p = Path(source)
        stem = p.stem if p.suffix.lower() in LOG_SUFFIXES else p.name
    stem = re.sub(r"[^A-Za-z0-9._-]+", "-", stem).strip("-.")
    return stem or "mission"


def short_hash(text: str) -> str:
    return hashlib.sha1(text.encode()).hexdigest()[:8]


def name_missions(missions: list[MissionSource], taken: dict[str, str] | None = None) -> list[MissionSource]:
    """Give every mission a unique folder name. `taken` maps names already used in the output folder to
    their sources: a name held by another source there gets the hash too (so results never mix)."""
    taken = taken or {}
    stems = [mission_stem(m.source) for m in missions]
    counts: dict[str, int] = {}
    for s in stems:
        counts[s] = counts.get(s, 0) + 1
    out = []
    for m, stem in zip(missions, stems, strict=True):
        # The plain stem when no other source wants it (here or in the output folder already); a source
        # that already holds the stem in the output folder keeps it, so its results are found again.
        held = taken.get(stem)
        clash = held != m.source if held is not None else counts[stem] > 1
        name = f"{stem}-{short_hash(m.source)}" if clash else stem
        out.append(MissionSource(m.source, name, m.error))
    return out
