"""`aftershock view MISSION.mcap [RECORDING.rrd]`: a log and its recording, opened as one recording in Rerun.

The recording holds what the log does not (poses, labels, map, stats); the raw scans come from the log
itself, read by Rerun's own MCAP import, so both share the `message_log_time` and `ros2_timestamp`
timelines and the log's clouds hang off the estimated pose. The recording must have been made from this
log: its recording id carries the log's fingerprint. Viewers listen on 127.0.0.1 unless `--bind` says
otherwise; `--save` writes the two together into one .rrd instead of opening a viewer.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Final

import typer

from aftershock.pipeline.errors import InputError

APPLICATION_ID: Final = "aftershock"


def check_log(log: Path) -> None:
    """A readable MCAP file, else InputError."""
    from aftershock.sources.mcap_source import is_mcap

    if not log.exists():
        raise InputError("no such file", log)
    if not log.is_file():
        raise InputError("not a file (view takes an MCAP log)", log)
    try:
        ok = is_mcap(log)
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror})", log) from None
    if not ok:
        raise InputError("not an MCAP file (it does not start with the MCAP magic bytes)", log)


def recording_id_of(recording: Path) -> str:
    """The recording id of the first recording in an .rrd, else InputError."""
    from rerun.chunk import RrdReader

    if not recording.is_file():
        raise InputError("no such file" if not recording.exists() else "not a file", recording)
    try:
        stores = RrdReader(recording).recordings()
    except (ValueError, OSError, RuntimeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"not a Rerun recording ({first})", recording) from None
    if not stores:
        raise InputError("not a Rerun recording (no recording in the file)", recording)
    return str(stores[0].recording_id)


def check_pair(log: Path, recording: Path) -> str:
    """The recording's id, when it was made from this log; InputError otherwise."""
    from aftershock.sinks.rerun_sink import log_id_of
    from aftershock.sources.mcap_source import fingerprint

    rid = recording_id_of(recording)
    made_from = log_id_of(rid)
    if made_from is None:
        raise InputError("not a recording `aftershock run` made from an MCAP log", recording)
    if made_from != fingerprint(log):
        raise InputError(f"a recording of another log, not of {log.name}", recording)
    return rid


def view(
    log: Path = typer.Argument(..., help="The mission's MCAP log."),
    recording: Path | None = typer.Argument(None, help="Its recording from `aftershock run --save`."),
    web: bool = typer.Option(False, "--web", help="Serve the web viewer instead of opening the native one."),
    bind: str = typer.Option("127.0.0.1", "--bind", help="Address the viewer listens on."),
    port: int | None = typer.Option(None, "--port", help="gRPC port of the viewer (default: a free one)."),
    topic: str | None = typer.Option(None, "--topic", help="Point-cloud topic (default: the only one)."),
    save: Path | None = typer.Option(None, "--save", help="Write log and recording into one .rrd instead."),
    force: bool = typer.Option(False, "--force", help="Overwrite --save's file."),
) -> None:
    """Open a log and its recording together, lined up on the log's timelines."""
    from aftershock import sources
    from aftershock.pipeline.outputs import check_output, commit, part_path
    from aftershock.sinks.rerun_sink import recording_id_for

    check_log(log)
    rid = check_pair(log, recording) if recording is not None else None
    desc = sources.describe(log, topic)
    inputs = [log] + ([recording] if recording is not None else [])
    out = check_output(save, force, inputs) if save is not None else None  # never one of what it reads

    import rerun as rr
    from rerun.chunk import McapReader, RrdReader

    from aftershock.sinks import rerun_blueprint as L
    from aftershock.sinks.rerun_viewer import start_viewer

    rec = rr.RecordingStream(APPLICATION_ID, recording_id=rid or recording_id_for(desc.log_id))
    rr.set_log_time_enabled(False, recording=rec)
    blueprint = L.default_blueprint(log_topic=desc.topic if desc.raw_in_log else None)
    viewer = None
    if out is not None:  # written beside and renamed when complete: an interrupted view leaves no half file
        rec.set_sinks(rr.FileSink(str(part_path(out))), default_blueprint=blueprint)
    else:
        viewer = start_viewer(web=web, bind=bind, port=port)
        rec.set_sinks(rr.GrpcSink(viewer.grpc_url), default_blueprint=blueprint)
    if recording is not None:
        rec.send_chunks(RrdReader(recording).stream())
    rec.send_chunks(McapReader(log).stream())
    rec.flush()
    if out is not None:
        rec.disconnect()
        commit(part_path(out), out)
        print(f"wrote {out}: {log.name}" + (f" with {recording.name}" if recording else ""))
        return
    assert viewer is not None
    if viewer.web_url is None:
        rec.disconnect()
        print(f"opened in the Rerun viewer ({viewer.grpc_url})")
        return
    print(f"open {viewer.web_url} in a browser; Ctrl-C stops the viewer", flush=True)
    try:
        assert viewer.process is not None
        viewer.process.wait()
    except KeyboardInterrupt:
        print("aftershock: viewer stopped", file=sys.stderr)
    finally:
        rec.disconnect()
        if viewer.process is not None and viewer.process.poll() is None:
            viewer.process.terminate()
            viewer.process.wait(timeout=10)
