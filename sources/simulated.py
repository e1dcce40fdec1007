"""`sim://` sources: simulated missions streamed as scans, without a file.

    sim://disaster?seed=3&sensor=vlp16&scans=300
    sim://office?seed=1&sensor=dense&duration=20&story=1&speed=0.8

The family is the URI's host (default `disaster`); query keys: seed, sensor, scans, duration (s),
story, speed (m/s), spacing (m: a scan every so far instead of at the sensor rate). With neither
scans nor duration the mission has `DEFAULT_SCANS` scans, or as many
as `max_scans` / `end_s` ask for. The options of `sources.open` apply as for logs (times are seconds
from the mission start).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final
from urllib.parse import parse_qs, urlsplit

from aftershock.pipeline.errors import InputError
from aftershock.pipeline.types import Scan

if TYPE_CHECKING:
    from aftershock.sources.simulator.mission import Mission

SCHEME: Final = "sim"
DEFAULT_FAMILY: Final = "disaster"
_KEYS: Final = {
    "seed": int,
    "sensor": str,
    "scans": int,
    "duration": float,
    "story": int,
    "speed": float,
    "spacing": float,
}
_OPTIONS: Final = {"max_scans", "every", "start_s", "end_s", "progress", "topic", "pose_topic"}


@dataclass(frozen=True, slots=True)
class SimSpec:
    """What a `sim://` URI asks for."""

    family: str = DEFAULT_FAMILY
    seed: int = 0
    sensor: str = "vlp16"
    scans: int | None = None
    duration_s: float | None = None
    story: int = 0
    speed: float | None = None
    spacing_m: float | None = None  # a scan every this many metres instead of at the sensor rate

    def uri(self) -> str:
        q = f"seed={self.seed}&sensor={self.sensor}&story={self.story}"
        if self.scans is not None:
            q += f"&scans={self.scans}"
        if self.duration_s is not None:
            q += f"&duration={self.duration_s:g}"
        if self.speed is not None:
            q += f"&speed={self.speed:g}"
        if self.spacing_m is not None:
            q += f"&spacing={self.spacing_m:g}"
        return f"{SCHEME}://{self.family}?{q}"


def parse_sim_uri(uri: str) -> SimSpec:
    """The mission a `sim://FAMILY?key=value&…` URI describes; InputError for anything it cannot mean."""
    parts = urlsplit(uri)
    if parts.scheme != SCHEME:
        raise InputError(f"not a simulator URI (expected {SCHEME}://FAMILY?seed=N&…)", uri)
    family = parts.netloc or parts.path.strip("/") or DEFAULT_FAMILY
    values: dict[str, Any] = {}
    for key, vals in parse_qs(parts.query, keep_blank_values=True).items():
        if key not in _KEYS:
            raise InputError(f"unknown simulator option {key!r} (known: {', '.join(_KEYS)})", uri)
        try:
            values[key] = _KEYS[key](vals[-1])
        except ValueError:
            raise InputError(f"simulator option {key}={vals[-1]!r} is not a {_KEYS[key].__name__}", uri) from None
    spec = SimSpec(
        family=family,
        seed=values.get("seed", 0),
        sensor=values.get("sensor", "vlp16"),
        scans=values.get("scans"),
        duration_s=values.get("duration"),
        story=values.get("story", 0),
        speed=values.get("speed"),
        spacing_m=values.get("spacing"),
    )
    check_spec(spec, uri)
    return spec


def check_spec(spec: SimSpec, where: str) -> None:
    from aftershock.sources.simulator.families import family_spec
    from aftershock.sources.simulator.profiles import get_profile

    family_spec(spec.family)
    get_profile(spec.sensor)
    if spec.scans is not None and spec.scans < 0:
        raise InputError("scans cannot be negative", where)
    if spec.duration_s is not None and not spec.duration_s >= 0:
        raise InputError("duration cannot be negative", where)
    if spec.speed is not None and not 0.05 <= spec.speed <= 5.0:
        raise InputError("speed must be between 0.05 and 5 m/s", where)
    if spec.spacing_m is not None and not 0.01 <= spec.spacing_m <= 100.0:
        raise InputError("spacing must be between 0.01 and 100 m", where)


def make_mission(spec: SimSpec) -> Mission:
    """The scene and mission of a spec."""
    from aftershock.sources.simulator import Mission, build_scene, get_profile
    from aftershock.sources.simulator.trajectory import WALK_SPEED_MPS

    scene = build_scene(spec.family, spec.seed)
    if not 0 <= spec.story < scene.num_stories:
        raise InputError(f"story {spec.story} is not in this building (it has {scene.num_stories})", spec.uri())
    return Mission(
        scene,
        get_profile(spec.sensor),
        seed=spec.seed,
        scans=spec.scans,
        duration_s=spec.duration_s,
        story=spec.story,
        speed=spec.speed or WALK_SPEED_MPS,
        spacing_m=spec.spacing_m,
    )


def open_simulated(uri: str, **options: Any) -> Iterator[Scan]:
    """Scans of the mission a `sim://` URI describes; options max_scans, every, start_s, end_s, progress."""
    from aftershock.sources.simulator.mission import DEFAULT_SCANS, POINTS_TOPIC

    options = {k: v for k, v in options.items() if v is not None}
    unknown = set(options) - _OPTIONS
    if unknown:
        raise InputError(f"unknown source option(s) for the simulator: {', '.join(sorted(unknown))}", uri)
    topic = options.get("topic")
    if topic is not None and topic != POINTS_TOPIC:
        raise InputError(f"the simulator publishes {POINTS_TOPIC!r}, not {topic!r}", uri)
    spec = parse_sim_uri(uri)
    every = int(options.get("every", 1))
    if every < 1:
        raise InputError("every must be at least 1", uri)
    max_scans = options.get("max_scans")
    end_s = options.get("end_s")
    mission = make_mission(spec)
    first = mission.first_at_or_after(float(options.get("start_s", 0.0)))
    if spec.scans is not None or spec.duration_s is not None:
        last = len(mission)
    elif end_s is not None:
        last = mission.count_before(float(end_s) + 1e-9)
    elif max_scans is not None:
        last = first + int(max_scans) * every
    else:
        last = DEFAULT_SCANS
    if end_s is not None:
        last = min(last, mission.count_before(float(end_s) + 1e-9))
    keep = range(first, last, every)
    if max_scans is not None:
        keep = keep[: int(max_scans)]
    return _stream(mission, keep, bool(options.get("progress", False)))


def _stream(mission: Mission, keep: range, progress: bool) -> Iterator[Scan]:
    from aftershock.pipeline.progress import track

    for k in track(keep, total=len(keep), desc="simulating", show=None if progress else False):
        yield mission.scan(k)
