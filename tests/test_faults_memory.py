"""Memory has a bound you can name: a tiny log cannot make a command take gigabytes.

Every compressed block (MCAP chunks, ROS 1 bag chunks) inflates into at most what it declares and at most what one
block may take on this machine (`pipeline.limits.block_cap_bytes`); past that it is skipped or ends the read with a
warning, like any damaged block. Each case runs the real command line in a child process under an address-space
limit (RLIMIT_AS, as `prlimit --as` sets it) and checks the child's own peak RSS, from wait4.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from faults_data import hall_clouds, strip_summary, write_log
from faults_hostile import GiB, cli_measured, mcap_chunk_bomb, ros1_bz2_bomb

BOUND_MB = 600  # what info and run take on these logs is ~100-250 MB; the bombs would take 3 GiB and more


@pytest.fixture(scope="module")
def small_chunks(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """12 hall scans in zstd chunks of ~175 KB (4 scans each)."""
    return write_log(tmp_path_factory.mktemp("mem") / "log.mcap", 12, chunk_size=150_000)


@pytest.mark.parametrize("indexed", [True, False])
def test_a_chunk_that_inflates_to_3_gib_is_skipped_in_bounded_memory(
    indexed: bool, small_chunks: Path, tmp_path: Path
) -> None:
    """The second chunk's zstd frame (98 KB) holds 3 GiB and says so in its frame header; the chunk record declares
    the size of the messages it was meant to hold. Read through the index and, without a summary, as a stream."""
    log = mcap_chunk_bomb(small_chunks, tmp_path / "bomb.mcap", 1, inflates_to=3 * GiB, declares=None)
    if not indexed:
        log = strip_summary(log, tmp_path / "stream.mcap")
    done = cli_measured(["info", str(log)], address_space=3 * GiB, timeout=90)
    assert done.returncode == 0, done.stderr
    assert "refused: it inflates to more than" in done.stderr and "its messages are skipped" in done.stderr
    assert "Traceback" not in done.stderr
    assert "/points (sensor_msgs/msg/PointCloud2): 8 scans" in done.stdout  # the other two chunks are read
    assert done.peak_rss_mb < BOUND_MB


def test_chunks_declaring_more_than_one_block_may_take_are_skipped_unread(small_chunks: Path, tmp_path: Path) -> None:
    """The second chunk's header claims 3 GiB, the third's 32 TiB (the issue's MemoryError); their bytes are fine."""
    log = mcap_chunk_bomb(small_chunks, tmp_path / "claims.mcap", 1, inflates_to=None, declares=3 * GiB)
    log = mcap_chunk_bomb(log, tmp_path / "claims.mcap", 2, inflates_to=None, declares=32 << 40)
    done = cli_measured(["info", str(log)], address_space=3 * GiB, timeout=90)
    assert done.returncode == 0, done.stderr
    for declares in (3 * GiB, 32 << 40):
        assert f"it declares {declares} uncompressed bytes, more than the" in done.stderr, done.stderr
    assert ": 4 scans" in done.stdout and "MemoryError" not in done.stderr
    assert done.peak_rss_mb < BOUND_MB


def test_run_on_a_bombed_log_finishes_its_outputs_in_bounded_memory(small_chunks: Path, tmp_path: Path) -> None:
    log = mcap_chunk_bomb(small_chunks, tmp_path / "bomb.mcap", 1, inflates_to=3 * GiB, declares=None)
    export = tmp_path / "exp"
    args = ["run", str(log), "--labeller", "region-growing", "--export", str(export), "-q"]
    done = cli_measured(args, address_space=8 * GiB, timeout=150)
    assert done.returncode == 0, done.stderr
    assert "the chunk at byte" in done.stderr and "refused" in done.stderr
    assert (export / "map.ply").stat().st_size > 1000
    assert done.peak_rss_mb < BOUND_MB


def test_a_ros1_bag_whose_bz2_chunk_inflates_to_3_gib_is_bounded(tmp_path: Path) -> None:
    """A bag of 6 one-message bz2 chunks; the second holds 3 GiB of zeros in 2.4 KB (the issue's 78 KB bag took
    3.2 GB). The read stops there with the damage named, and what precedes it is counted."""
    clouds, _ = hall_clouds(6, 2000)
    bag = ros1_bz2_bomb(tmp_path / "bomb.bag", clouds, bomb_chunk=1, gib=3)
    assert bag.stat().st_size < 200_000
    done = cli_measured(["info", str(bag)], address_space=3 * GiB, timeout=90)
    assert done.returncode == 0, done.stderr
    assert "inflates to more than the" in done.stderr and "Traceback" not in done.stderr
    assert ": 1 scans" in done.stdout
    assert done.peak_rss_mb < BOUND_MB
