"""The per-scan scalars of a recording (`stats/time_ms/<stage>`, `stats/counts/<name>`): each once per scan (the
first value seen), buffered and sent as columns every STATS_EVERY scans instead of one `log` per value."""

from __future__ import annotations

from typing import Final

import numpy as np
import rerun as rr

from aftershock.pipeline.types import Frame
from aftershock.sinks import rerun_blueprint as L

STATS_EVERY: Final = 10  # per-scan scalars go out as columns every this many scans (live plots lag by as much)


class ScanScalars:
    def __init__(self) -> None:
        self._logged: set[str] = set()  # what was already recorded for the scan `_seq`
        self._seq: int | None = None
        self._rows: dict[str, list[tuple[int, int | None, int, float]]] = {}  # entity -> (seq, log, stamp, value)
        self._scans = 0  # scans buffered in `_rows`

    def __bool__(self) -> bool:
        return bool(self._rows)

    def next_scan(self, seq: int, rec: rr.RecordingStream) -> None:
        """Called whenever the recording's time is set to a scan: a new scan may send the buffer first."""
        if seq == self._seq:
            return
        self._seq = seq
        self._logged.clear()
        self._scans += 1
        if self._scans > STATS_EVERY:
            self.flush(rec)
            self._scans = 1

    def record(self, frame: Frame, mcap_times: bool) -> None:
        scan = frame.scan
        when = (scan.seq, scan.log_time_ns if mcap_times else None, scan.stamp_ns)
        values = [("raw_points", f"{L.STATS_COUNTS}/raw_points", float(len(scan)))]
        values += [(f"t:{k}", f"{L.STATS_TIME}/{k}", float(v)) for k, v in frame.timings_ms.items()]
        values += [(f"c:{k}", f"{L.STATS_COUNTS}/{k}", float(v)) for k, v in frame.counts.items()]
        for key, entity, value in values:
            if key not in self._logged:
                self._logged.add(key)
                self._rows.setdefault(entity, []).append((*when, value))

    def flush(self, rec: rr.RecordingStream) -> None:
        """One `send_columns` per series for the buffered scans."""
        for entity, rows in self._rows.items():
            for mcap in (True, False):  # rows on the MCAP timelines, then rows on the sensor time
                sel = [r for r in rows if (r[1] is not None) == mcap]
                if not sel:
                    continue
                seq, log_ns, stamp_ns, value = (np.array(c) for c in zip(*sel, strict=True))
                stamps = stamp_ns.astype("datetime64[ns]")
                indexes = [rr.TimeColumn(L.SCAN_TIMELINE, sequence=seq)]
                if mcap:
                    indexes.append(rr.TimeColumn(L.MCAP_LOG_TIMELINE, timestamp=log_ns.astype("datetime64[ns]")))
                    indexes.append(rr.TimeColumn(L.MCAP_STAMP_TIMELINE, timestamp=stamps))
                else:
                    indexes.append(rr.TimeColumn(L.SENSOR_TIMELINE, timestamp=stamps))
                rec.send_columns(entity, indexes=indexes, columns=rr.Scalars.columns(scalars=value))
        self._rows.clear()
