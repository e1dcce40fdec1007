"""One typed configuration with defaults that work; overridable from a TOML/JSON file and `--set a.b=value`.

Every threshold named in METHODS.md lives here, so a run's settings are one object that can be printed,
saved next to its results and loaded again.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import fields
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Final, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from aftershock.pipeline.errors import InputError

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

S = TypeVar("S", bound="DataclassInstance")


class Environment(StrEnum):
    """Indoor and outdoor logs differ in range limits, voxel sizes and clustering threshold."""

    AUTO = "auto"
    INDOOR = "indoor"
    OUTDOOR = "outdoor"


# Every numeric setting is finite (NaN would collapse a map into one voxel) and in its range; checked when the
# config is loaded, before any work, so a bad value is one line naming the setting.
Positive = Annotated[float, Field(gt=0)]  # sizes, distances, ratios
NonNegative = Annotated[float, Field(ge=0)]  # 0 turns a step off
Fraction = Annotated[float, Field(ge=0, le=1)]  # shares and probabilities
Cosine = Annotated[float, Field(ge=-1, le=1)]  # cosine similarities
Angle = Annotated[float, Field(gt=0, le=180)]  # degrees
Count = Annotated[int, Field(ge=1)]
NonNegativeCount = Annotated[int, Field(ge=0)]
Seed = Annotated[int, Field(ge=0, le=2**32 - 1)]  # numpy and torch take 32-bit seeds
TimeOffset = Annotated[float, Field(ge=0, le=1e9)]  # seconds from a log's start: 31 years, past any mission
# Voxel and cell sizes: below a millimetre a site's voxel keys overflow 64-bit integers and nothing is gained
VoxelSize = Annotated[float, Field(ge=1e-3, le=1e3)]


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)


class SourceConfig(_Section):
    topic: str | None = None
    pose_topic: str | None = None
    start_s: TimeOffset | None = None  # seconds from the log start
    end_s: TimeOffset | None = None
    max_scans: Count | None = None
    every: Count = 1


class RegisterConfig(_Section):
    """KISS-ICP settings; None = chosen from the environment (indoor logs need a finer map)."""

    voxel_size_m: VoxelSize | None = None
    min_range_m: NonNegative | None = None
    max_range_m: Positive | None = None
    deskew: bool = True
    max_points_per_voxel: Count = 20
    # A frame whose ICP moved it further than this from the constant-velocity prediction is flagged.
    max_correction_m: Positive = 1.0
    # Turn the world so that z is up, from the first scan's floors and walls (pipeline.level); off keeps
    # KISS-ICP's world, the first scan's sensor frame.
    level: bool = True
    # "truth": the log's own true poses replace KISS-ICP (to score labelling without registration errors)
    poses: Literal["estimated", "truth"] = "estimated"
    threads: Annotated[int, Field(ge=0)] = 0  # KISS-ICP's threads; 0 = every core (`batch` gives each mission one)


class StreamConfig(_Section):
    # Read and register the next scans on a second thread while this one is labelled, clustered and sent to
    # the sinks (the results are the same as one stage after the other; a test checks it). Off by default: it
    # gains little (the stages hold Python's GIL most of the time) and costs peak memory a long mission cannot
    # spare (docs/benchmarks/stream.md#reading-and-registering-on-a-second-thread).
    overlap: bool = False
    ahead: Count = 2  # scans read and registered ahead at most (bounds the memory they hold)


class MapConfig(_Section):
    voxel_size_m: VoxelSize = 0.1
    context_cell_m: VoxelSize = 0.3  # MCPNet context: 3 x 3 x 3 cells of this size around a point
    # points kept per context cell; every voxel holds this many slots, so a billion would take gigabytes at once
    context_points: Annotated[int, Field(ge=1, le=4096)] = 50


class LabelConfig(_Section):
    labeller: str = "mcpnet"  # "mcpnet" or "region-growing" (classical online baseline)
    environment: Environment = Environment.AUTO
    # Horizontal range kept for labelling. The study's 2 m suits its -45..80 degree scanner; a VLP-16 (+-15
    # degrees) at robot height first meets the floor ~3.4 m away, so indoors we keep 4 m (MCPNet is trained so).
    indoor_range_m: Positive = 4.0
    outdoor_range_m: Positive = 10.0
    relabel_old_voxels: bool = False
    instance_vote: bool = True  # MCPNet: an instance's voxels take the class they vote for (confidence-weighted)
    weights: str | None = None  # None = the shipped weights in models/weights
    # MCPNet on logs without colour (#12): None = the shipped colour-free network, or `weights` when that is set
    weights_no_color: str | None = None
    # `eval --oracle`: the truth in place of the labeller's classes or embeddings (pipeline.labellers.oracle)
    oracle: Literal["none", "classes", "objects"] = "none"


class ClusterConfig(_Section):
    beta_indoor: Cosine = 0.9  # cosine similarity of embeddings needed to link two voxels
    beta_outdoor: Cosine = 0.92
    # Labellers with embeddings: neighbouring instances merge when their mean embeddings agree this well
    # (cosine similarity); > 1 turns it off.
    merge_beta: Annotated[float, Field(ge=-1)] = 0.85
    # Fragments under this many voxels that stopped growing for `absorb_after_scans` scans join the
    # neighbouring instance whose mean embedding agrees best, at `absorb_beta` or more (1 voxel = off).
    absorb_voxels: Count = 30
    absorb_after_scans: NonNegativeCount = 10
    absorb_beta: Cosine = 0.7
    link_reach_voxels: Count = 1  # a new voxel links to voxels up to this many voxels away (1 = the 26 around it)
    # Geometry (pipeline.cluster.Geometry): a piece of at least plane_min_voxels is planar when its smallest
    # spread is at most plane_thickness x its middle one and that is at least plane_min_spread_m; a voxel joins
    # a planar instance only on its plane, and two planar pieces merge only when parallel and coplanar.
    plane_min_voxels: Count = 15
    plane_thickness: Positive = 0.2
    plane_min_spread_m: NonNegative = 0.1
    plane_angle_deg: Angle = 20.0
    plane_offset_m: NonNegative = 0.2
    plane_wide_m: Positive = 0.3  # any thin piece this wide (middle spread, std) is planar whatever its class
    plane_beta: Annotated[float, Field(ge=-1)] = (
        0.75  # two planar pieces of one plane merge at this mean-embedding similarity (> 1: off)
    )
    # Voxel links checked against local surface normals (pipeline.cluster): "off", "agree" (two flat voxels
    # with normals apart do not link) or "strict" (besides, a flat voxel does not link to one at an edge).
    normal_links: Literal["off", "agree", "strict"] = "strict"
    # Pieces sharing a long boundary (touching voxel pairs >= contact_ratio x the smaller piece's voxels)
    # merge at this mean-embedding similarity (> 1: off).
    contact_beta: Annotated[float, Field(ge=-1)] = 2.0
    contact_ratio: NonNegative = 2.0
    merge_same_class: bool = False  # instances whose majority classes differ never merge
    merge_min_contacts: Count = 1  # touching voxel pairs two instances need before they may merge
    merge_links: NonNegativeCount = (
        1  # instances joined by this many linked voxel pairs merge (geometry allowing; 0 = never)
    )
    # Objects shown to the user (viewer, exports, `eval`) have at least this many voxels; at the end of a
    # run smaller fragments join the touching instance whose mean embedding agrees at final_beta or more.
    min_object_voxels: Count = 50
    # Geometry decides structural objects (issue #28): a voxel on a confirmed slab, column or beam of the
    # structure model takes that element's object (one per element), the rest is clustered by embeddings.
    structure_objects: bool = True
    final_beta: Annotated[float, Field(ge=-1)] = 0.7  # > 1: off
    normal_angle_deg: Angle = 20.0  # region-growing baseline: neighbouring normals within this angle
    color_distance: NonNegative = 0.12  # region-growing baseline: RGB distance in [0, 1] units

    def link_beta(self, environment: Environment) -> float:
        """The embedding similarity that links two voxels in this environment (`beta_indoor` unless outdoor)."""
        return self.beta_outdoor if environment is Environment.OUTDOOR else self.beta_indoor


class RerunConfig(_Section):
    # The accumulated map shown in the viewer, and each scan's labelled layer, are downsampled to this (the
    # voxel map's own resolution by default: one point per labelled voxel).
    map_voxel_m: Positive = 0.1
    map_every: Count = 10  # re-log the accumulated map every N scans
    # The map is logged in square tiles of this size and only changed tiles are re-logged (a tile whose
    # points stayed and only labels changed gets its labels alone): small tiles keep a long mission light.
    map_tile_m: Positive = 4.0
    # Raw scans go into the recording only where the log cannot be opened beside it (ROS 1, files, sim://),
    # downsampled to this; 0 keeps them at full resolution.
    raw_voxel_m: NonNegative = 0.3
    raw_points: bool = True
    # Full-resolution per-stage layers of every scan (registered, labelled, instances, embedding): for
    # debugging a scan, about 15x the size of a recording without them.
    debug_layers: bool = False
    # A saved recording larger than this is rewritten at the end in fewer, larger chunks (a long mission's
    # opens in Rerun's web viewer in minutes instead of not at all); 0 = every one.
    compact_above_mb: NonNegative = 64.0
    embeddings: bool = True  # with debug_layers: the MCPNet embedding layer too
    # Map voxels whose labeller confidence (its probability for the class shown) is under this are drawn again
    # in `world/uncertain` in one warning colour, so that a glance shows where the labels are guesses.
    uncertain_below: Fraction = 0.5


class LRGNetConfig(_Section):
    voxel_size_m: Positive = 0.1
    # I and J: the pooled samples of a region and its neighbours. The network is trained on 128; pooling 256 beat
    # 512 on validation rooms of the training buildings (docs/decisions.md#lrgnet-before-12).
    inliers: Count = 256  # I
    neighbours: Count = 256  # J
    delta_m: Positive = 0.1  # δ: neighbour set = unlabelled points within this distance of the region
    max_steps: Count = 200  # a floor grows by one voxel ring a step: 60 cut large floors and ceilings apart
    # smaller segments join the nearest large one (docs/decisions.md#round-k-lrgnet-minimum-segment-size)
    min_segment_points: Count = 25
    seed_min_neighbours: NonNegativeCount = 6  # seeds: voxels with fewer occupied neighbours come after all others
    search: str = "greedy"  # greedy | restart | beam
    restarts: Count = 10
    beam_width: Count = 3
    beam_expansions: Count = 3
    score: str = "ml"  # ml (summed log-likelihood) | np (number of points)
    seed: Seed = 0
    weights: str | None = None
    remove_threshold: Fraction = 0.9  # greedy: an inlier goes when P(remove) exceeds this (its loss is class-balanced)
    # The next six depend on whether the cloud has colour: None = the default of its mode (LRGNET_MODE_DEFAULTS);
    # a value given here serves both modes.
    # greedy: a neighbour joins when P(add) exceeds this
    add_threshold: Fraction | None = None
    # Consolidation after growth (pipeline.refine.merge): touching flat segments within this angle and plane offset
    # join; 0 turns it off.
    merge_angle_deg: NonNegative | None = None
    merge_offset_m: NonNegative | None = None
    # Before it, segments are cut at creases (pipeline.refine.merge.split_creases): flat parts of at least this many
    # voxels, smooth within this angle, become their own segments; 0 turns it off.
    crease_angle_deg: NonNegative | None = None
    crease_min_voxels: Count | None = None
    # While a grown region is a plane, it takes only voxels whose normals lie within this angle of its normal
    # (pipeline.refine.grow.Grower.within_plane); 0 = off.
    flat_gate_deg: NonNegative | None = None
    # Baselines run beside LRGNet (pipeline.refine.baselines)
    baseline_normal_angle_deg: Angle = 10.0  # threshold region growing: normals within this angle (tuned)
    baseline_color_distance: NonNegative = 0.12  # ... and RGB (0..1) closer than this
    smoothness_k: Count = 16  # Rabbani et al.: neighbours per point
    smoothness_angle_deg: Angle = 10.0
    smoothness_curvature_percentile: Annotated[float, Field(ge=0, le=100)] = (
        98.0  # points above this curvature percentile stop growing
    )
    fpfh_similarity: Cosine = 0.98  # cosine similarity of FPFH histograms to link touching voxels (tuned likewise)
    mcpnet_similarity: Cosine = 0.9  # cosine similarity of MCPNet embeddings (the clustering stage's β indoor)

    def for_color(self, color: bool) -> LRGNetConfig:
        """These settings for a cloud with colour (or without): every mode-dependent setting left at None takes
        its mode's default."""
        unset = {k: v for k, v in LRGNET_MODE_DEFAULTS[color].items() if getattr(self, k) is None}
        return self.model_copy(update=unset) if unset else self


# LRGNet's mode-dependent defaults, with colour (True) and without (False): without colour growth does not stop at
# creases, so each mode has its own, chosen on validation buildings of the training generators (rounds G, G4, I-I3;
# kept for the round-P2 network by rounds Q-S: docs/decisions.md#round-g-lrgnet-settings-per-colour-mode).
LRGNET_MODE_DEFAULTS: Final[dict[bool, dict[str, float]]] = {
    True: {"add_threshold": 0.3, "merge_angle_deg": 5.0, "merge_offset_m": 0.05, "crease_angle_deg": 15.0,
           "crease_min_voxels": 20, "flat_gate_deg": 0.0},
    False: {"add_threshold": 0.4, "merge_angle_deg": 10.0, "merge_offset_m": 0.1, "crease_angle_deg": 10.0,
            "crease_min_voxels": 20, "flat_gate_deg": 50.0},
}  # fmt: skip


class CrackConfig(_Section):
    resolution_m: Positive | None = None  # None = 1 mm for columns and walls, 1 cm for slabs
    features: str = "shade+crackembed"  # best balance of real elements and unseen simulated ones (bench_cracks)
    # "ridge" and "region" (issue 30) did not beat it left out on the real elements (ridge round C, region round R1)
    detector: str = "isolation-forest"
    neighbourhood_m: Positive = 0.01
    shade_cell_m: NonNegative = (
        0.0  # shade: darkness against the mean of the 3 x 3 x 3 block of these voxels (0 = median)
    )
    severe_width_m: Positive = 0.0032  # 1/8 inch
    min_crack_points: Count = 20
    seed: Seed = 0
    normal_cell_m: Positive = 0.015  # normals/curvature: PCA over the 3 x 3 x 3 block of these voxels (the study's)
    fpfh_radius_m: Positive = 0.02
    smooth_cell_m: NonNegative = 0.02  # detector scores averaged over the 3 x 3 x 3 block of these voxels; 0 = off
    smooth_keep_raw: bool = True  # a point's own score also counts (thin cracks survive the smoothing)
    link_m: NonNegative = 0.01  # crack points closer than this (or link_spacings x the spacing) belong to one crack
    link_spacings: NonNegative = 2.0
    support_spacings: Positive = 3.0  # a crack point needs min_support of the points within this many spacings ...
    min_support: Fraction = 0.5  # ... to be crack points too (0 = no clean-up before linking)
    min_elongation: NonNegative = 3.0  # a reported crack is at least this many times longer than its opening is wide
    # How the anomaly detectors' scores become crack candidates (bench_cracks chooses, leave-one-object-out):
    # "null": above the scores' median + null_sigmas robust sigmas (sound concrete rarely scores more; calibrated
    # on simulated intact elements); "mixture": where a two-component mixture's upper component (a crack
    # population of at least mixture_min_weight, mixture_separation sigmas above the rest) takes over, else
    # "null"; "valley": the valley before a separate mode of high scores (never below "null" when null_sigmas > 0);
    # "detector": the detector's own
    threshold: Literal["null", "mixture", "valley", "detector"] = "valley"
    null_sigmas: NonNegative = 0.0
    mixture_min_weight: Fraction = 0.03
    mixture_separation: NonNegative = 3.0
    valley_rise: Positive = 2.0
    edge_spacings: NonNegative = (
        0.0  # points on the scan's edge (cells this many spacings; 0 = off) score at most the median
    )
    cracks_only: bool = True  # crack points are those of reported cracks (not round blobs, not tiny groups)
    # a reported crack lies at least depth_sigmas local noise sigmas behind the surface around it (90th percentile
    # over its points; 0 = no test): cracks are openings, stains and streaks are flat (calibrated on simulated
    # intact elements, chosen leave-one-object-out in bench_cracks: off, since the real elements' cracks are not
    # recessed in their scans); depth against the plane of the 3 x 3 x 3 block of depth_cell_m voxels
    depth_sigmas: NonNegative = 0.0
    depth_cell_m: Positive = 0.02
    # a reported crack changes the surface's hue by at least min_chroma_contrast percent of chromaticity (its core
    # against the sound ring around it; 0 = no test): shade and most dirt change only the brightness (damage/tint)
    min_chroma_contrast: NonNegative = 0.0
    # a reported crack is narrow: at least min_area_elongation times longer than its mean width (its points' area
    # over its length; 0 = no test) and holding at most max_share of the element's points (1 = no test): stains and
    # shaded patches or faces are broad. Off: calibrated on simulated elements (0.3, 6) the test drops the real
    # slab's wide crack bands and loses leave-one-object-out
    # (docs/decisions.md#cracks-fainter-cracks-narrowness-and-face-rules)
    min_area_elongation: NonNegative = 0.0
    max_share: Fraction = 1.0
    grow_m: NonNegative = (
        0.03  # after the support rule (0 = off), points this close to a crack whose smoothed score ...
    )
    grow_sigmas: float = 0.25  # ... is above the threshold less this many robust sigmas of the scores join it
    max_spacing_m: Positive = 0.02  # coarser clouds are refused as too sparse to measure cracks
    fit_points: Count = 20000  # detectors are fitted on at most this many points (seeded sample), applied to all
    weights: str | None = None  # CrackEmbed weights; None = the shipped ones
    # detector "ridge" (damage/ridge.py): thin dark ridges on each face's orthoimages against the face's background;
    # chosen in bench_cracks_ridge (round C: best on the four real elements; ridge_high calibrated on simulated intact
    # elements only); docs/benchmarks/cracks.md
    ridge_scales_m: tuple[float, ...] = (0.004, 0.008, 0.016, 0.032, 0.064)
    ridge_channels: tuple[str, ...] = ("grey",)
    ridge_high: Positive = 8.0  # seed score in robust sigmas of the face's own line contrast
    ridge_low_ratio: Fraction = 0.5
    ridge_min_length_m: NonNegative = 0.1
    ridge_min_elongation: NonNegative = 4.0
    ridge_line_ratio: Fraction = 0.5  # |smaller| / larger Hessian eigenvalue of a line, at most
    ridge_max_chroma: NonNegative = 4.5  # a region this far from the face's hue (% chromaticity) is paint; 0 = off
    # thinner straight axis-aligned strips are joints/marks (0 = off: off, since columns crack straight along them)
    ridge_straight_width_m: NonNegative = 0.0
    ridge_rim: bool = True  # at a face's rim (one side off the face) the other side alone is the reference
    ridge_member_z: NonNegative = 1.0  # a region's crack points: darker than around by this many robust sigmas
    # detector "region" (damage/region.py): damaged regions on each face's orthoimages, evidence channels in robust
    # z-scores of the face's own surface; chosen in bench_cracks_region (region_high calibrated on simulated intact
    # elements only, the rest leave-one-out on the real elements); docs/benchmarks/cracks.md
    # round R1: best on the four real elements (raw-mask F1: slab2 only, the columns 0); it did not transfer
    region_channels: tuple[str, ...] = ("dark", "rough", "deficit")
    region_scales_m: tuple[float, ...] = (0.02, 0.04, 0.08)
    region_combine: Literal["sum", "max"] = "sum"
    region_high: Positive = 17.0  # a region's peak evidence (90th percentile, robust sigmas) reaches this
    region_gate_ratio: Positive = 1.25  # an element has cracks only if some region's peak reaches high x this
    region_low_ratio: Fraction = 0.5
    region_smooth_m: NonNegative = 0.01
    region_open_m: NonNegative = 0.04  # evidence narrower than this (a joint's groove, a line) is no region; 0 = off
    region_min_area_m2: NonNegative = 0.002
    element_voxel_m: Positive = 0.05  # element extraction: region growing on this grid ...
    element_radius_m: Positive = 0.1  # ... joining neighbours within this distance ...
    element_angle_deg: Angle = 20.0  # ... whose normals differ by less than this ...
    element_color_distance: NonNegative = 0.15  # ... and colours (RGB in 0..1) by less than this
    element_min_points: Count = 500  # elements with fewer input points are not assessed
    dims_tolerance: NonNegative = 0.3  # picking elements by expected size: each extent within ±30 %


class DriftConfig(_Section):
    bin_m: Positive = 0.05
    density_ratio: Positive = 1.5  # a slab bin has 50 % more points than the median of its neighbourhood
    neighbourhood_bins: Count = 24  # 1.2 m: a slab tilted 1° across a 20 m building spans 0.35 m
    ransac_threshold_m: Positive = 0.02
    ransac_iterations: Count = 1000
    gravity: str = "frame-z"  # frame-z | ground-plane
    slab_merge_m: NonNegative = 0.6  # density bands closer than this (a slab's top and underside) are one slab
    max_slab_tilt_deg: Annotated[float, Field(gt=0, le=90)] = 20.0  # a fitted plane steeper than this is not a slab
    min_slab_share: Fraction = 0.2  # a slab plane has at least this share of the largest slab plane's points
    wall_planes: NonNegativeCount = 40  # drift: vertical planes tried per story (RANSAC, one after another)
    wall_threshold_m: Positive = 0.01
    wall_min_points: Count = 150
    wall_s_min: Fraction = 0.05  # walls are read between these fractions of the local story height (beams
    wall_s_max: Fraction = 0.78  # hang below the ceiling down to about 0.85)
    wall_end_s: Fraction = 0.12  # a wall's foot and head are read in windows this share of the story high
    wall_min_count: Count = 3  # tall walls/columns needed for a story's drift
    wall_outlier_m: Positive = 0.006  # a wall whose lean disagrees by more is left out (IRLS, Tukey)
    slab_pad_m: NonNegative = 0.3  # a slab plane is sought this far around its density band (tilted slabs)
    seed: Seed = 0


class ReportConfig(_Section):
    """Limits `aftershock report` flags against (advisory: an engineer decides). Drift limits are residual
    inter-storey drift ratios after FEMA P-58-1 (2012), Appendix C, residual drift damage states: 0.5 %
    (1/200) realignment of the frame required, 1 % (1/100) major realignment, possibly not practical."""

    drift_restricted_ratio: Annotated[float, Field(gt=0, lt=1)] = 1 / 200
    drift_unsafe_ratio: Annotated[float, Field(gt=0, lt=1)] = 1 / 100
    # Slab tilt flagged at the same slopes (an assumption of this tool, not a published limit)
    tilt_restricted_deg: Annotated[float, Field(gt=0, le=90)] = 0.29  # atan(1/200)
    tilt_unsafe_deg: Annotated[float, Field(gt=0, le=90)] = 0.57  # atan(1/100)
    # Storeys are re-measured on the map with up from the lowest slab: `run` levels a map from its first scan,
    # and on 2 drift frames (missing-slab 5, partial-collapse 6) that left 8-9 mm per storey, 0.3-2.6 mm with this
    drift_gravity: Literal["ground-plane", "frame-z"] = "ground-plane"
    # The worst drift error per storey seen on those frames through run (docs/benchmarks/report.md)
    drift_uncertainty_mm: Positive = 3.0
    # With drift_gravity frame-z: how far a levelled map's up may be off (0.31° seen on a drift frame)
    level_uncertainty_deg: Annotated[float, Field(ge=0, le=10)] = 0.35
    min_storey_height_m: Positive = 2.0  # slabs closer than this: the upper one is furniture or a platform
    collapse_debris_share: Fraction = 0.25  # debris over this share of a storey's floor: partial collapse
    exit_clearance_m: Positive = 1.0  # debris within this of a door blocks it
    plan_cell_m: Positive = 0.1  # grid of the debris volume and floor area
    plan_points: Count = 150_000  # most map points drawn per plan view


class StructureConfig(_Section):
    """The structure model (pipeline.structure): slabs, walls, columns, beams and the ground found from geometry
    and gravity in the levelled map, and labels fused with the network's (geometry decides what it can)."""

    enabled: bool = True
    tile_m: Positive = 2.0  # walls, columns and beams are found per square tile of this size, where the map changed
    tiles_per_scan: Count = 2  # at most this many changed tiles refitted a scan (the rest wait their turn) ...
    # ... and refits go through at most this many voxels (of a tile and the 8 around it) a scan on average (all
    # changed tiles are refitted at the end): a budget in voxels, so that labels never depend on the machine's speed
    budget_voxels: Count = 500
    min_new_voxels: Count = 40  # a tile is refitted once this many voxels were added to it since its last fit
    plane_threshold_m: Positive = 0.06  # a voxel lies on a plane within this distance
    slab_bin_m: Positive = 0.05  # height histogram of the map for the story slabs (pipeline.damage.drift)
    slab_density_ratio: Positive = 1.5
    slab_neighbourhood_bins: Count = 24
    slab_merge_m: NonNegative = 0.3
    slab_min_voxels: Count = 150
    slab_refit_growth: Positive = 0.25  # a slab is refitted when its band gained this share of voxels
    max_slab_tilt_deg: Annotated[float, Field(gt=0, le=45)] = 5.0
    sensor_margin_m: NonNegative = 0.2  # floors lie this far below the sensor at least, ceilings above it
    wall_min_height_m: Positive = 1.2  # a wall spans at least this high ...
    wall_min_width_m: Positive = 1.0  # ... and (its tiles' pieces merged) this wide
    wall_piece_min_voxels: Count = 25
    wall_merge_deg: Angle = 10.0  # pieces of one wall: normals within this angle, planes within plane_threshold_m
    # A wall is one object (issue #28; the simulator's truth: both faces, the whole line, openings in it): its
    # coplanar stretches along one line and its two faces (parallel, facing away, this far apart at most) are one
    # wall object; a face with a taller face behind it, seen from the same side, is furniture against a wall.
    wall_objects: bool = True
    wall_thickness_m: Positive = 0.4
    column_max_width_m: Positive = 1.0  # a column's footprint fits in a square this wide
    column_min_cover: Fraction = 0.6  # ... its cells are occupied over this share of the story's height ...
    column_min_height_m: Positive = 1.8  # ... or of this height above the floor, if less
    # an engaged column (built into a wall or against it) stands proud of the wall's plane by at most this ...
    column_max_proud_m: Annotated[float, Field(gt=0, le=1.0)] = 0.5
    engaged_min_proud_m: Positive = 0.12  # ... and by at least this (a wall seen twice stands off itself less) ...
    column_min_width_m: Positive = 0.3  # ... along the wall at least this wide ...
    engaged_max_width_m: Annotated[float, Field(gt=0, le=2.0)] = 0.8  # ... and at most this wide ...
    engaged_min_face: Fraction = 0.4  # ... with this share of its voxels on one face parallel to the wall
    # ... and the wall one clean plane on both sides; with this on, one side may be unseen (nothing there: a wall's
    # end, an opening) if the face is flat. Off: it also takes wall ends seen thick (docs/benchmarks/structure.md)
    engaged_one_sided: bool = False
    # a beam is geometry's to find: the network's beam where the structure found none is, once every tile was
    # looked at, a wall's head beside a wall, else clutter (a lamp); columns likewise, off: on validation it
    # cost as much as it gave (docs/decisions.md)
    beams_need_element: bool = True
    columns_need_element: bool = False
    beam_max_depth_m: Positive = 0.8  # beams hang at most this far under a ceiling ...
    beam_min_length_m: Positive = 1.2  # ... run at least this long ...
    beam_max_width_m: Positive = 0.8  # ... and are at most this wide, and not within this of a wall's plane
    beam_wall_reach_m: Positive = 0.3  # (a wall's head seen without its lower part)
    beams_recheck_walls: bool = True  # ... checked again at the end against every wall found by then
    default_story_m: Positive = 2.8  # a story's height where no ceiling was found
    min_story_m: Positive = 2.0  # a floor this close above another is furniture (desks, beds), not a story's slab
    ground_cell_m: Positive = 1.0  # outdoors: the ground's height per cell of this size ...
    ground_band_m: Positive = 0.2  # ... and a voxel within this height above it is ground
    keep_confidence: Fraction = 0.9  # a confident non-structural network label on an element is kept
    # new voxels on a confirmed element take its class, confidence and embedding without the network (a labeller
    # with embeddings only: the clustering reads them) ...
    skip_explained: bool = True
    # ... in logs with colour too (off: there it cost the validation missions a point of mean IoU and 2 of NMI)
    skip_with_colour: bool = False
    # openings (pipeline.structure.openings): gaps in a wall's face the sensor saw through
    openings: bool = True
    opening_cell_m: Positive = 0.1  # the wall's occupancy grid (along it, height above the floor)
    door_min_width_m: Positive = 0.5  # a door is a gap from the floor up this wide at least ...
    door_max_width_m: Positive = 2.5  # ... and at most
    window_min_width_m: Positive = 0.4  # a window is a gap over a sill this wide at least ...
    window_max_width_m: Positive = 3.5  # ... and at most ...
    sill_min_m: NonNegative = 0.6  # ... its sill (the lowest rays through it) this high above the floor at least ...
    sill_max_m: Positive = 1.5  # ... and at most
    door_min_height_m: Positive = 1.95  # a door's head stands this high at least (where the map reaches that high)
    opening_min_height_m: Positive = 0.6  # an opening's height seen, at least
    opening_max_width_m: Positive = 3.5  # wall pieces this far apart along one line may bound one opening
    opening_min_seen: Fraction = 0.3  # the sensor saw through this share of an opening's width (not a shadow)
    opening_depth_m: Positive = 0.35  # an opening's voxels (frames, glass) lie at most this far behind the face
    door_leaf_columns: bool = True  # a column hung at a door's jamb, square off the wall, is the door's open leaf
    # debris (pipeline.structure.debris): masses on a floor slab on no element, that no furniture is shaped like
    debris: bool = True
    debris_max_height_m: Positive = 1.2  # a mass reaching higher (95th percentile) stands: furniture, a wall
    debris_layer_m: Positive = 0.2  # a layer: within this of the floor ...
    debris_layer_cells: Count = 25  # ... over at least this many footprint cells (of one voxel) ...
    debris_layer_min_m: NonNegative = 0.05  # ... its median this far above the floor around it (not the floor)
    debris_mound_m: Positive = 0.7  # a mound: at most this high (95th percentile) ...
    debris_mound_min_m: NonNegative = 0.7  # ... this wide across at least (a heap, not a box or a bag) ...
    debris_min_oblique: Fraction = 0.3  # ... with this share of its voxels' normals oblique (many small faces) ...
    debris_max_flat_top: Fraction = 0.4  # ... and at most this share of its footprint at one top height


class Config(_Section):
    source: SourceConfig = SourceConfig()
    registration: RegisterConfig = RegisterConfig()
    stream: StreamConfig = StreamConfig()
    map: MapConfig = MapConfig()
    label: LabelConfig = LabelConfig()
    cluster: ClusterConfig = ClusterConfig()
    rerun: RerunConfig = RerunConfig()
    lrgnet: LRGNetConfig = LRGNetConfig()
    cracks: CrackConfig = CrackConfig()
    drift: DriftConfig = DriftConfig()
    report: ReportConfig = ReportConfig()
    structure: StructureConfig = StructureConfig()


def settings_from(section: BaseModel, settings: type[S], prefix: str = "", **renamed: str) -> S:
    """A component's settings (a dataclass) from the section's fields named `prefix` + each field's name
    (`renamed`: field -> the section's name, where it differs)."""
    return settings(**{f.name: getattr(section, renamed.get(f.name, prefix + f.name)) for f in fields(settings)})


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> Config:
    """Defaults, then a TOML or JSON file, then `section.key=value` overrides (values parsed as JSON if they can be)."""
    data: dict[str, Any] = {}
    if path is not None:
        p = Path(path)
        data = _read_config_file(p)
    if not isinstance(data, dict):
        raise InputError(f"a config is a table of sections (source, map, label …), not a {type(data).__name__}", path)
    for item in overrides or []:
        key, sep, raw = item.partition("=")
        if not sep or "." not in key:
            raise InputError(f"override {item!r} is not of the form section.key=value")
        value = _override_value(key, raw)
        section, _, name = key.partition(".")
        table = data.setdefault(section, {})
        if not isinstance(table, dict):
            raise InputError(f"config {section} is a {type(table).__name__}, not a table of settings", path)
        table[name] = value
    try:
        return Config.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(x) for x in first["loc"])
        option = OPTION_OF.get(where)
        named = f"{where} ({option})" if option else where
        given = first.get("input")
        value_text = f" (given {_shown(given)})" if isinstance(given, int | float | str) else ""
        raise InputError(f"config {named}: {first['msg']}{value_text}", path) from None


_CONFIG_MAX_BYTES: Final = 1 << 20  # a settings file; anything larger is not one


def _read_config_file(p: Path) -> Any:
    """A TOML or JSON config file's table; one line naming the file for whatever it is instead (missing, a
    folder, a pipe, unreadable, nested past what a parser holds, numbers past Python's 4300 digits)."""
    try:
        if not p.exists():
            raise InputError("config file not found", p)
        if p.is_dir():
            raise InputError("is a folder, not a config file", p)
        if not p.is_file():
            raise InputError("is not a regular file (a config is read from a TOML or JSON file)", p)
        if p.stat().st_size > _CONFIG_MAX_BYTES:
            raise InputError(f"is {p.stat().st_size} bytes, too large for a config file", p)
        text = p.read_text()
    except OSError as exc:
        raise InputError(f"cannot read the config file ({exc.strerror or exc})", p) from None
    except UnicodeDecodeError:
        raise InputError("not a valid config: it is not UTF-8 text", p) from None
    kind = p.suffix.lstrip(".") or "TOML"
    try:
        return json.loads(text) if p.suffix == ".json" else tomllib.loads(text)
    except RecursionError:
        raise InputError(f"not a valid {kind} config: it nests deeper than can be read", p) from None
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"not a valid {kind} config: {str(exc).splitlines()[0] if str(exc) else exc}", p) from None
    except ValueError as exc:  # int() past sys.get_int_max_str_digits()
        raise InputError(f"not a valid {kind} config: {_first_line(exc)}", p) from None


def _override_value(key: str, raw: str) -> Any:
    """A `--set` value: JSON if it parses as JSON, else the text itself; one line for what no parser holds."""
    try:
        return json.loads(raw)
    except RecursionError:
        raise InputError(f"--set {key}: the value nests deeper than can be read") from None
    except json.JSONDecodeError:
        return raw
    except ValueError as exc:  # int() past sys.get_int_max_str_digits()
        raise InputError(f"--set {key}: {_first_line(exc)}") from None


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    if "digits" in text and "integer" in text:
        return "a number of more than 4300 digits"
    return text.splitlines()[0] if text else type(exc).__name__


def _shown(value: object) -> str:
    """A given value for an error line: at most 40 characters (a 5,000-digit number cannot even be printed)."""
    try:
        text = repr(value)
    except ValueError:
        return "a number of more than 4300 digits"
    return text if len(text) <= 40 else text[:37] + "..."


# Settings the command line sets through their own options, named in errors as the user typed them.
OPTION_OF: Final[dict[str, str]] = {
    "source.start_s": "--start",
    "source.end_s": "--end",
    "source.every": "--every",
    "source.max_scans": "--max-scans",
    "source.topic": "--topic",
    "label.labeller": "--labeller",
    "cracks.resolution_m": "--resolution",
}
