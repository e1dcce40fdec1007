"""What a real LiDAR does that a perfect ray caster does not: scaled range noise and dropouts, lost returns on
dark far surfaces, mixed points at depth edges, glass that lets the beam through, mirrors that fold it.

`Conditions()` is the plain simulator (nothing but the profile's own noise and dropout, bit for bit);
`Conditions.randomized(rng)` draws a site's conditions. Everything here is vectorised over a whole sweep.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, Final

import numpy as np

from aftershock.sources.simulator.meshes import SPECULAR, TRANSPARENT

if TYPE_CHECKING:
    from aftershock.sources.simulator.scene import Scene

EDGE_JUMP_M: Final = 0.25  # a range jump between neighbouring columns of one beam that makes an edge
RECAST_EPS_M: Final = 1e-3  # start a second ray this far past the surface it left
MAX_PANES: Final = 2


@dataclass(frozen=True, slots=True)
class Conditions:
    noise_scale: float = 1.0  # multiplies the profile's range noise
    dropout_scale: float = 1.0  # multiplies the profile's dropout
    dark_dropout: float = 0.0  # extra loss on dark surfaces, growing with range (at 20 m and reflectivity 0)
    mixed_edges: float = 0.0  # share of edge returns that land between fore- and background
    glass_pass: float = 0.0  # share of rays on glass that pass through (the rest return from it or are lost)
    glass_lost: float = 0.0  # share of rays on glass that are lost
    mirrors: bool = False  # mirrors fold the beam: a ghost point behind the mirror, unlabelled

    @property
    def optics(self) -> bool:
        return self.glass_pass > 0 or self.glass_lost > 0 or self.mirrors

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def randomized(rng: np.random.Generator) -> Conditions:
        """A site's conditions: noise 0.5-2.5x, dropouts 0.5-4x, edges, glass and mirrors as they come."""
        lost = float(rng.uniform(0.0, 0.4))
        return Conditions(
            noise_scale=round(float(rng.uniform(0.5, 2.5)), 3),
            dropout_scale=round(float(rng.uniform(0.5, 4.0)), 3),
            dark_dropout=round(float(rng.uniform(0.0, 0.4)), 3),
            mixed_edges=round(float(rng.uniform(0.0, 0.8)), 3),
            glass_pass=round(float(rng.uniform(0.3, 1.0 - lost)), 3),
            glass_lost=round(lost, 3),
            mirrors=bool(rng.random() < 0.8),
        )


def apply_optics(
    scene: Scene,
    cond: Conditions,
    origins: np.ndarray,
    dirs: np.ndarray,
    t: np.ndarray,
    tri: np.ndarray,
    cos: np.ndarray,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Glass and mirrors, one interaction each. Returns range along the ray (inf = lost), the triangle the
    return comes from, its cosine and a ghost mask (points that are not where a surface is)."""
    ghost = np.zeros(len(t), bool)
    optic = scene.mesh.optic
    if not cond.optics or optic is None:
        return t, tri, cos, ghost
    hit = tri >= 0
    kind = np.zeros(len(t), np.uint8)
    kind[hit] = optic[tri[hit]]
    t, tri, cos = t.copy(), tri.copy(), cos.copy()
    glass = np.flatnonzero(kind == TRANSPARENT)
    if len(glass):
        u = rng.random(len(glass))
        through = glass[u < cond.glass_pass]
        lost = glass[(u >= cond.glass_pass) & (u < cond.glass_pass + cond.glass_lost)]
        t[lost], tri[lost] = np.inf, -1
        # a pane has two faces (and a window may have two panes): go on through glass a few times
        for _ in range(MAX_PANES * 2):
            if not len(through):
                break
            start = origins[through] + dirs[through] * (t[through, None] + RECAST_EPS_M)
            t2, tri2, cos2 = scene.raycaster.cast(start, dirs[through])
            t[through] = t[through] + RECAST_EPS_M + t2
            tri[through], cos[through] = tri2, cos2
            more = tri2 >= 0
            more[more] = optic[tri2[more]] == TRANSPARENT
            through = through[more]
    mirror = np.flatnonzero(kind == SPECULAR) if cond.mirrors else np.zeros(0, np.int64)
    if len(mirror):
        normals = scene.raycaster.normals[tri[mirror]]
        d = dirs[mirror]
        folded = d - 2.0 * (d * normals).sum(1, keepdims=True) * normals
        start = origins[mirror] + d * t[mirror, None] + folded * RECAST_EPS_M
        t2, tri2, cos2 = scene.raycaster.cast(start, folded)
        # the sensor measures the folded path's length along the ray it sent: a point behind the mirror
        t[mirror] = t[mirror] + RECAST_EPS_M + t2
        tri[mirror], cos[mirror] = tri2, cos2
        ghost[mirror] = np.isfinite(t2)
    return t, tri, cos, ghost


def dark_losses(scene: Scene, cond: Conditions, t: np.ndarray, tri: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Returns lost on dark, far surfaces (True = lost)."""
    lost = np.zeros(len(t), bool)
    if cond.dark_dropout <= 0:
        return lost
    hit = np.flatnonzero(tri >= 0)
    refl = scene.mesh.reflectivity[tri[hit]]
    p = cond.dark_dropout * (1.0 - refl) * np.clip(t[hit] / 20.0, 0.0, 1.0)
    lost[hit] = rng.random(len(hit)) < p
    return lost


def mix_edges(ranges: np.ndarray, cond: Conditions, rng: np.random.Generator) -> np.ndarray:
    """Mixed points at depth edges on a (columns, beams) range grid (inf = no return): where a beam's range
    jumps between neighbouring columns, a share of the near returns lands somewhere between the two
    surfaces, as a footprint straddling the edge averages them."""
    if cond.mixed_edges <= 0:
        return ranges
    prev = np.roll(ranges, 1, axis=0)
    both = np.isfinite(ranges) & np.isfinite(prev)
    jump = np.where(both, prev - np.where(both, ranges, 0.0), 0.0)
    edge = both & (jump > EDGE_JUMP_M)  # this column is the near side of the edge
    edge &= rng.random(ranges.shape) < cond.mixed_edges
    out = ranges.copy()
    a = rng.random(int(edge.sum()))
    out[edge] = ranges[edge] + a * (prev[edge] - ranges[edge])
    return out
