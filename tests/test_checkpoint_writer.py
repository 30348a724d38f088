"""The edge's checkpoints written off the slot thread: what lands is the map as the slot left
it, a newer checkpoint of a device replaces an unwritten older one, what follows a checkpoint
runs only once it is on disk, and a failed write is told to the slot thread."""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import edge_mapper.checkpoint_writer as checkpoint_writer
from edge_mapper.checkpoint_writer import CheckpointFailed, CheckpointWriter
from twinslam.slam.back_end.keyframe_map import write_checkpoint

WAIT_S = 30.0


@pytest.fixture
def writer() -> Iterator[CheckpointWriter]:
    w = CheckpointWriter()
    yield w
    w.close()


def _read(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def test_the_checkpoint_is_the_map_as_it_was_submitted(tmp_path: Path,
                                                       writer: CheckpointWriter) -> None:
    path = tmp_path / "edge.npz"
    version = np.array([3])
    told: list[Mapping[str, np.ndarray]] = []
    writer.submit(path, {"version": version}, told.append)
    version[0] = 4                           # the slot thread goes on changing its map
    writer.wait(path)
    assert _read(path)["version"].tolist() == [3]
    assert len(told) == 1 and told[0]["version"].tolist() == [3]
    assert not path.with_name(path.name + ".tmp").exists()


def test_a_newer_checkpoint_replaces_an_unwritten_older_one_and_both_follow_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, writer: CheckpointWriter) -> None:
    """While the writer is busy with one device, another device's two slots submit: only the
    newer is written, and what was to follow the older runs after the newer landed."""
    busy, release = tmp_path / "ar1.npz", threading.Event()
    started = threading.Event()

    def slow_for_busy(path: Path, arrays: Mapping[str, Any]) -> None:
        if path == busy:
            started.set()
            assert release.wait(WAIT_S)
        write_checkpoint(path, arrays)

    monkeypatch.setattr(checkpoint_writer, "write_checkpoint", slow_for_busy)
    writer.submit(busy, {"version": np.array(1)})
    assert started.wait(WAIT_S)
    path = tmp_path / "ar2.npz"
    told: list[tuple[str, int]] = []
    writer.submit(path, {"version": np.array(7)},
                  lambda written: told.append(("older", int(written["version"]))))
    writer.submit(path, {"version": np.array(8)},
                  lambda written: told.append(("newer", int(written["version"]))))
    assert not path.exists() and told == []
    release.set()
    writer.wait(path)
    assert int(_read(path)["version"]) == 8
    assert told == [("older", 8), ("newer", 8)]
    assert writer.replaced == 1 and writer.written == 2


def test_a_failed_write_is_raised_at_the_next_checkpoint_and_its_follow_up_waits(
        tmp_path: Path, writer: CheckpointWriter) -> None:
    """The disk's error reaches the slot thread (where a failed write raised before); the
    archive's files the failed checkpoint would have released go once a later one lands."""
    path = tmp_path / "gone" / "edge.npz"            # its folder does not exist
    told: list[int] = []
    writer.submit(path, {"version": np.array(1)}, lambda w: told.append(int(w["version"])))
    with pytest.raises(CheckpointFailed, match="not written"):
        writer.wait(path)
    writer.wait(path)                                 # told once
    path.parent.mkdir()
    writer.submit(path, {"version": np.array(2)}, lambda w: told.append(10 + int(w["version"])))
    writer.wait(path)
    assert told == [2, 12] and int(_read(path)["version"]) == 2
    writer.submit(tmp_path / "missing" / "x.npz", {"version": np.array(3)})
    with pytest.raises(CheckpointFailed):
        writer.wait(tmp_path / "missing" / "x.npz")


def test_what_must_be_on_disk_first_is_written_first_and_a_failure_holds_the_checkpoint(
        tmp_path: Path, writer: CheckpointWriter) -> None:
    """The archive's owed files land before the checkpoint that no longer holds their
    keyframes in its map; where they cannot, that checkpoint is not written (a restart from
    it would find the keyframes nowhere) and the slot thread is told."""
    path = tmp_path / "edge.npz"
    order: list[str] = []

    def first() -> None:
        order.append("archive files" if not path.exists() else "late")

    writer.submit(path, {"version": np.array(1)}, lambda w: order.append("after"), first)
    writer.wait(path)
    assert order == ["archive files", "after"] and int(_read(path)["version"]) == 1

    def failing() -> None:
        raise OSError("disk full")

    writer.submit(path, {"version": np.array(2)}, before=failing)
    with pytest.raises(CheckpointFailed, match="disk full"):
        writer.wait(path)
    assert int(_read(path)["version"]) == 1           # the older map stays


def test_closing_writes_what_was_submitted(tmp_path: Path) -> None:
    writer = CheckpointWriter()
    paths = [tmp_path / f"ar{i}.npz" for i in range(5)]
    for i, path in enumerate(paths):
        writer.submit(path, {"version": np.array(i)})
    writer.close()
    assert [int(_read(p)["version"]) for p in paths] == list(range(5))
    with pytest.raises(RuntimeError, match="closed"):
        writer.submit(paths[0], {"version": np.array(9)})


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux's thread names")
def test_the_writer_thread_shows_its_name_where_top_and_ps_list_threads(
        writer: CheckpointWriter) -> None:
    tid = writer._thread.native_id
    assert tid is not None
    comm = Path(f"/proc/self/task/{tid}/comm")
    deadline = time.monotonic() + WAIT_S        # the thread names itself as it starts
    while comm.read_text().strip() != "checkpoints" and time.monotonic() < deadline:
        time.sleep(0.01)
    assert comm.read_text().strip() == "checkpoints"
