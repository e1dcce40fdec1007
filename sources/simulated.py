"""`sim://` sources: simulated missions streamed as scans, without a file.

    sim://disaster?seed=3&sensor=vlp16&scans=300
    sim://office?seed=1&sensor=dense&duration=20&story=1&speed=0.8
    sim://wing?seed=7&sensor=os1-64&robot=wheeled&height=0.4&color=0&conditions=random
    sim://hall?seed=2&randomize=1

The scene generator is the URI's host (default `disaster`; office, disaster, hall, wing, flats); query keys:
seed, sensor, scans, duration (s), story, speed (m/s), spacing (m: a scan every so far instead of at the
sensor rate), robot (legged, wheeled, tracked), height (m, the LiDAR mount), tilt (deg, pitched down),
turn (deg/s, fastest turn), sway (deg, body roll), palette (natural, random, grey, swap), color (0: a
LiDAR without a camera), conditions (plain, random: noise, dropouts, mixed edges, glass, mirrors) and
randomize (1: robot settings, palette and conditions drawn from the seed; explicit keys still win).
With neither scans nor duration the mission has `DEFAULT_SCANS` scans, or as many
as `max_scans` / `end_s` ask for. The options of `sources.open` apply as for logs (times are seconds
from the mission start).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import asdict, dataclass, replace
from typing import TYPE_CHECKING, Any, Final
from urllib.parse import parse_qs, urlsplit

import numpy as np

from aftershock.pipeline.errors import InputError
from aftershock.pipeline.types import Scan

if TYPE_CHECKING:
    from aftershock.sources.simulator.conditions import Conditions
    from aftershock.sources.simulator.mission import Mission
    from aftershock.sources.simulator.robots import RobotSpec

SCHEME: Final = "sim"
DEFAULT_FAMILY: Final = "disaster"
# bool: 1/0, true/false, yes/no, on/off (_BOOLS); the others are read with their type
_KEYS: Final[dict[str, type]] = {
    "seed": int,
    "sensor": str,
    "scans": int,
    "duration": float,
    "story": int,
    "speed": float,
    "spacing": float,
    "robot": str,
    "height": float,
    "tilt": float,
    "turn": float,
    "sway": float,
    "palette": str,
    "color": bool,
    "conditions": str,
    "randomize": bool,
}
_BOOLS: Final = {
    "1": True,
    "true": True,
    "yes": True,
    "on": True,
    "0": False,
    "false": False,
    "no": False,
    "off": False,
}
CONDITIONS: Final = ("plain", "random")
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
    robot: str = "legged"
    height_m: float | None = None  # None: the robot's own (or drawn, with randomize)
    tilt_deg: float | None = None
    turn_deg_s: float | None = None
    sway_deg: float | None = None
    palette: str | None = None  # None: natural (or drawn, with randomize)
    color: bool = True
    conditions: str | None = None  # None: plain (or random, with randomize)
    randomize: bool = False

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
        if self.robot != "legged":
            q += f"&robot={self.robot}"
        for key, value in (("height", self.height_m), ("tilt", self.tilt_deg), ("turn", self.turn_deg_s)):
            if value is not None:
                q += f"&{key}={value:g}"
        if self.sway_deg is not None:
            q += f"&sway={self.sway_deg:g}"
        if self.palette is not None:
            q += f"&palette={self.palette}"
        if not self.color:
            q += "&color=0"
        if self.conditions is not None:
            q += f"&conditions={self.conditions}"
        if self.randomize:
            q += "&randomize=1"
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
        kind = _KEYS[key]
        if kind is bool:
            if vals[-1].lower() not in _BOOLS:
                raise InputError(f"simulator option {key}={vals[-1]!r} is not 0 or 1", uri)
            values[key] = _BOOLS[vals[-1].lower()]
            continue
        try:
            values[key] = kind(vals[-1])
        except ValueError:
            raise InputError(f"simulator option {key}={vals[-1]!r} is not a {kind.__name__}", uri) from None
    spec = SimSpec(
        family=family,
        seed=values.get("seed", 0),
        sensor=values.get("sensor", "vlp16"),
        scans=values.get("scans"),
        duration_s=values.get("duration"),
        story=values.get("story", 0),
        speed=values.get("speed"),
        spacing_m=values.get("spacing"),
        robot=values.get("robot", "legged"),
        height_m=values.get("height"),
        tilt_deg=values.get("tilt"),
        turn_deg_s=values.get("turn"),
        sway_deg=values.get("sway"),
        palette=values.get("palette"),
        color=values.get("color", True),
        conditions=values.get("conditions"),
        randomize=values.get("randomize", False),
    )
    check_spec(spec, uri)
    return spec


SEED_MAX = 2**32 - 1


def check_spec(spec: SimSpec, where: str) -> None:
    from aftershock.sources.simulator.generators import check_generator
    from aftershock.sources.simulator.looks import check_palette
    from aftershock.sources.simulator.profiles import get_profile
    from aftershock.sources.simulator.robots import MOUNT_HEIGHT_RANGE_M, get_robot

    try:
        check_generator(spec.family)
        get_profile(spec.sensor)
        get_robot(spec.robot)
        if spec.palette is not None:
            check_palette(spec.palette)
    except InputError as exc:
        raise InputError(str(exc), where) from None
    if spec.conditions is not None and spec.conditions not in CONDITIONS:
        raise InputError(f"unknown conditions {spec.conditions!r} (known: {', '.join(CONDITIONS)})", where)
    if spec.height_m is not None and not MOUNT_HEIGHT_RANGE_M[0] <= spec.height_m <= MOUNT_HEIGHT_RANGE_M[1]:
        raise InputError(f"height must be between {MOUNT_HEIGHT_RANGE_M[0]:g} and {MOUNT_HEIGHT_RANGE_M[1]:g} m", where)
    if spec.tilt_deg is not None and not -45.0 <= spec.tilt_deg <= 45.0:
        raise InputError("tilt must be between -45 and 45 degrees", where)
    if spec.turn_deg_s is not None and not 5.0 <= spec.turn_deg_s <= 360.0:
        raise InputError("turn must be between 5 and 360 degrees per second", where)
    if spec.sway_deg is not None and not 0.0 <= spec.sway_deg <= 10.0:
        raise InputError("sway must be between 0 and 10 degrees", where)
    if not 0 <= spec.seed <= SEED_MAX:
        raise InputError(f"seed must be between 0 and {SEED_MAX} (numpy and torch take 32-bit seeds)", where)
    if spec.scans is not None and spec.scans < 0:
        raise InputError("scans cannot be negative", where)
    if spec.duration_s is not None and not 0 <= spec.duration_s < float("inf"):
        raise InputError("duration must be a number of seconds, not negative", where)
    if spec.speed is not None and not 0.05 <= spec.speed <= 5.0:
        raise InputError("speed must be between 0.05 and 5 m/s", where)
    if spec.spacing_m is not None and not 0.01 <= spec.spacing_m <= 100.0:
        raise InputError("spacing must be between 0.01 and 100 m", where)


def make_mission(spec: SimSpec) -> Mission:
    """The scene and mission of a spec."""
    from aftershock.sources.simulator import Mission, get_profile
    from aftershock.sources.simulator.generators import generate
    from aftershock.sources.simulator.robots import DEFAULT_ROBOT, get_robot
    from aftershock.sources.simulator.trajectory import WALK_SPEED_MPS

    choices = resolve(spec)
    scene = generate(spec.family, spec.seed, choices.palette)
    if not 0 <= spec.story < scene.num_stories:
        raise InputError(f"story {spec.story} is not in this building (it has {scene.num_stories})", spec.uri())
    legged = get_robot(DEFAULT_ROBOT)
    # the simulator as it always was, draw for draw (the speed is passed on its own)
    plain = replace(choices.robot, speed_mps=legged.speed_mps) == legged
    return Mission(
        scene,
        get_profile(spec.sensor),
        seed=spec.seed,
        scans=spec.scans,
        duration_s=spec.duration_s,
        story=spec.story,
        speed=spec.speed or (WALK_SPEED_MPS if plain else choices.robot.speed_mps),
        spacing_m=spec.spacing_m,
        robot=None if plain else choices.robot,
        conditions=choices.conditions,
        color=spec.color,
    )


@dataclass(frozen=True, slots=True)
class Choices:
    """What a spec comes to once randomisation is drawn: the robot, the palette and the sensor conditions."""

    robot: RobotSpec
    palette: str
    conditions: Conditions

    def to_dict(self) -> dict[str, Any]:
        return {"robot": asdict(self.robot), "palette": self.palette, "conditions": self.conditions.to_dict()}


def resolve(spec: SimSpec) -> Choices:
    """The robot, palette and conditions of a spec: explicit keys, else drawn from the seed (randomize), else
    the plain simulator's."""
    from aftershock.sources.simulator.conditions import Conditions
    from aftershock.sources.simulator.looks import PALETTES
    from aftershock.sources.simulator.robots import get_robot, randomized

    rng = np.random.default_rng([spec.seed, 23])
    robot = randomized(spec.robot, rng) if spec.randomize else get_robot(spec.robot)
    palette = str(rng.choice(PALETTES)) if spec.randomize else "natural"
    cond_kind = spec.conditions or ("random" if spec.randomize else "plain")
    conditions = Conditions.randomized(rng) if cond_kind == "random" else Conditions()
    over: dict[str, Any] = {
        k: v
        for k, v in (
            ("mount_height_m", spec.height_m),
            ("tilt_deg", spec.tilt_deg),
            ("turn_rate_deg_s", spec.turn_deg_s),
            ("sway_deg", spec.sway_deg),
        )
        if v is not None
    }
    if spec.speed is not None:
        over["speed_mps"] = spec.speed
    return Choices(replace(robot, **over), spec.palette or palette, conditions)


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
        last = mission.count_before(float(end_s) + 1e-9, "--end")
    elif max_scans is not None:
        last = first + int(max_scans) * every
    else:
        last = DEFAULT_SCANS
    if end_s is not None:
        last = min(last, mission.count_before(float(end_s) + 1e-9, "--end"))
    keep = range(first, last, every)
    if max_scans is not None:
        keep = keep[: int(max_scans)]
    return _stream(mission, keep, bool(options.get("progress", False)))


def _stream(mission: Mission, keep: range, progress: bool) -> Iterator[Scan]:
    from aftershock.pipeline.progress import track

    for k in track(keep, total=len(keep), desc="simulating", show=None if progress else False):
        yield mission.scan(k)
