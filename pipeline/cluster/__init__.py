"""Clustering stage: incremental instance clustering over the voxel map, objects rather than fragments.

Two levels, so that every decision to join two *instances* passes one place that sees their geometry:

1. Voxels. Each new voxel links to its neighbouring voxels (new ones of the same scan, and older ones that
   already carry an instance) where the labeller's affinity says they agree (for MCPNet: cosine similarity
   of the embeddings above β) and, with `normal_links`, where their local surface normals do not say that
   two surfaces meet (so two walls seen in one scan split at their corner). A group of linked new voxels
   joins the older instance it has most links to -- but a voxel only joins a *planar* instance (a wall, a
   floor) when it lies on that instance's plane, so a wall cannot grow round a corner into the next wall.
   New voxels that reach no older instance form new instances (connected components). A scan's voxels
   never merge two older instances here.
2. Instances. Every pair of instances that touch is kept with its number of touching voxel pairs and of
   linked ones. Pairs merge when a voxel link joins them or their mean embeddings agree (`merge_beta`;
   two pieces of one plane: `plane_beta`) *and* their geometry agrees: two planar instances only when
   their normals are parallel and they lie in one plane (`Geometry`). This runs after every scan on the
   pairs the scan touched, and over the whole map at the end of the run (`finish`), which also lets every
   fragment under `min_object_voxels` join the touching instance it agrees with most (`final_beta`).

With `absorb`, a small fragment that has stopped growing (an object still being scanned keeps growing)
joins the neighbouring instance it agrees with most, at a lower similarity. Objects under
`min_object_voxels` are not shown (`shown_ids`): they stay in the map, as "no object", until they grow.
Merges are recorded on the frame as `InstanceMerge`s (and returned by `finish`), so the sinks can show them.

Where the structure model runs (`cluster.structure_objects`), geometry decides structural objects (#28): a voxel
on a confirmed slab, column or beam shows that element's object (one per element; a refitted element keeps its
object id), a voxel on a wall its wall's object (`structure.wall_objects`: one per wall line, both faces, openings
and furniture faces left out), over the clustering, which goes on underneath unchanged (so do the class votes over
its instances); at the end of the run the map itself takes the element objects (`claim`), and an element's object
never merges with another's.
Every setting was chosen on validation missions (docs/decisions.md#clustering-before-12-objects-not-fragments).

Modules: `clusterer` (InstanceClusterer: the two levels above), `stats` (per-instance sums, the plane cache and
`Geometry`), `pairs` (the table of touching instance pairs), `stage` (the stage over frames).
"""

from aftershock.pipeline.cluster.clusterer import Affinity, InstanceClusterer
from aftershock.pipeline.cluster.pairs import PairTable
from aftershock.pipeline.cluster.stage import cluster_frame, cluster_stage
from aftershock.pipeline.cluster.stats import Geometry, InstanceStats

__all__ = [
    "Affinity",
    "Geometry",
    "InstanceClusterer",
    "InstanceStats",
    "PairTable",
    "cluster_frame",
    "cluster_stage",
]
