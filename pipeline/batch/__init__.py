"""`aftershock batch`'s engine: every mission one Ray task running the mission library, resumable, failures
isolated.

- `sources`: the arguments expanded into named missions;
- `folder`: the output folder, its configuration and which missions in it are complete;
- `worker`: one mission inside a Ray worker, and its row of the index;
- `ray_pool`: starting or joining Ray and running the missions on it;
- `site_index`: the index, `DIR/missions.parquet`.

A mission's folder `DIR/<mission>/` holds `recording.rrd`, `map.ply`, `poses_tum.txt`, `poses_kitti.txt`,
`summary.json` (and `damage.json`), and — written last, atomically — `mission.json`: the mission's index row
and the configuration's fingerprint. A folder with a matching `mission.json` and every file it names is
complete and skipped on a re-run; any other folder (interrupted, failed) is redone. `DIR/batch.json`
records the configuration the folder's results were made with; another configuration is refused unless
`--force`.

Ray: without `--address` a local instance sized to `--workers` (default: the cores), its servers and
workers listening on 127.0.0.1 only, no dashboard, a small object store (results are small rows). With
`--address` the driver joins that cluster the same way and keeps at most `--workers` (default: the
cluster's CPUs) missions in flight. Each mission asks Ray for one CPU and `worker_memory` bytes (so Ray
never packs more missions onto a node than its memory holds) and aborts with an error if its worker grows
beyond that bound. Every mission runs single-threaded (KISS-ICP, torch, BLAS, no reader thread), so missions,
not threads, share the cores.
"""
