"""Checkpoints written off the slot thread: the slot gathers a device's map into arrays, one
thread of the edge process writes them to disk.

One thread of an edge serves the slots of every device it carries (:mod:`edge_mapper.node`);
writing a checkpoint file on it — ``numpy.savez``, ``fsync``, the rename — held it ~20 ms a
device-slot on this VM's disk (``bench.edge_work`` over the 7-Scenes walk and back: the
checkpoint step 26–29 ms median on the slot thread, 7–11 ms with the writer, 2026-12-02), and
a slower disk (a network volume, an SD card) holds it longer: every device's slot waits
behind one device's ``fsync``. The writer takes those file operations, which release the
interpreter, onto a thread of its own (``checkpoint_in_background:=true``; off by default,
for the promise below).

What a checkpoint promises stays: a file is the map as one finished slot left it (the arrays are
gathered, copied, on the slot thread), written whole or not at all (a temporary name, then
renamed); what it follows afterwards (the archive's files of the keyframes the map took back,
:meth:`~twinslam.slam.back_end.keyframe_archive.KeyFrameArchive.release`) runs only once it is
on disk. What changes is when it lands: shortly after the slot's map update went out, instead of
before — so the default edge, which promises that a map its device got survives it, writes on
the slot thread (``tests/test_edge_node.py`` kills an edge right after an update and restarts
it: on a loaded machine the background write had not landed). An edge killed in between resumes
from the checkpoint before it and goes on from the map version its device holds, as with
``checkpoint_every`` above 1 (:meth:`~edge_mapper.edge_core.EdgeMapperCore.catch_up_version`). A
device's newer checkpoint submitted before its older one was written replaces it: the older is
not written at all.

What must be on disk before a checkpoint goes with it (``before``: the archive's files of the
keyframes it no longer holds in its map, :meth:`~twinslam.slam.back_end.keyframe_archive.
KeyFrameArchive.write_owed`): the writer runs it first, on its thread, and writes the checkpoint
only where it succeeded — a restart never reads a map without a keyframe whose archive file is
missing. A replaced checkpoint's ``before`` runs with its replacement's.

A write that fails is not retried by the writer: the device's next checkpoint (its next
submission) raises it on the slot thread, where a failed write raised before, and the edge
stops serving that device as it would have then; what was to follow the failed write follows
the next that lands.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from twinslam.slam.back_end.keyframe_map import write_checkpoint
from twinslam.thread_names import name_this_thread


class CheckpointFailed(OSError):
    """A device's checkpoint that could not be written (raised at its next submission)."""


#: what follows a checkpoint once it is on disk, told the arrays written (a newer checkpoint's,
#: where it replaced the one submitted with this)
Then = Callable[[Mapping[str, np.ndarray]], None]
#: what must be on disk before a checkpoint is written (raises where it could not be)
First = Callable[[], object]


@dataclass
class _Pending:
    arrays: Mapping[str, np.ndarray]
    after: list[Then] = field(default_factory=list)
    before: list[First] = field(default_factory=list)


class CheckpointWriter:
    """One thread writing checkpoint files submitted by the slot thread, newest per file."""

    def __init__(self) -> None:
        self._lock = threading.Condition()
        self._pending: dict[Path, _Pending] = {}
        self._writing: Path | None = None
        self._failed: dict[Path, BaseException] = {}
        #: what follows a write that failed: run after the path's next write that lands
        self._owed: dict[Path, list[Then]] = {}
        self._closed = False
        self.written = 0                     #: checkpoints on disk
        self.replaced = 0                    #: submitted, replaced by a newer one unwritten
        self._thread = threading.Thread(target=self._run, name="checkpoints",
                                        daemon=True)
        self._thread.start()

    def submit(self, path: Path, arrays: Mapping[str, np.ndarray],
               after: Then | None = None, before: First | None = None) -> None:
        """Write ``arrays`` to ``path`` (copied now: the caller's map goes on changing), then
        call ``after`` with the arrays written — once ``before`` (called first, on the
        writer's thread) returned. Raises :class:`CheckpointFailed` when the last write to
        ``path`` failed."""
        path = Path(path)
        copied = {name: np.array(value, copy=True) for name, value in arrays.items()}
        with self._lock:
            if self._closed:
                raise RuntimeError("the checkpoint writer is closed")
            self._raise_failure(path)
            older = self._pending.get(path)
            follow = [*(older.after if older is not None else []),
                      *([after] if after is not None else [])]
            first = [*(older.before if older is not None else []),
                     *([before] if before is not None else [])]
            if older is not None:
                self.replaced += 1
            self._pending[path] = _Pending(copied, follow, first)
            self._lock.notify_all()

    def wait(self, path: Path) -> None:
        """Until ``path``'s submitted checkpoint is on disk (or its write failed: raised)."""
        path = Path(path)
        with self._lock:
            self._lock.wait_for(lambda: path not in self._pending and self._writing != path)
            self._raise_failure(path)

    def close(self) -> None:
        """Write what was submitted, then end the thread (a failed write is not raised here:
        :meth:`wait` each path whose failure matters)."""
        with self._lock:
            self._closed = True
            self._lock.notify_all()
        self._thread.join()

    def _raise_failure(self, path: Path) -> None:
        failure = self._failed.pop(path, None)
        if failure is not None:
            raise CheckpointFailed(f"{path}: the last checkpoint was not written: "
                                   f"{failure}") from failure

    def _run(self) -> None:
        name_this_thread()                          # "checkpoints" in top -H and ps -L
        while True:
            with self._lock:
                self._lock.wait_for(lambda: self._pending or self._closed)
                if not self._pending:
                    return                            # closed, nothing left to write
                path = next(iter(self._pending))
                job = self._pending.pop(path)
                self._writing = path
            failure: Exception | None = None
            follow: list[Then] = []
            try:
                for first in job.before:
                    first()
                write_checkpoint(path, job.arrays)
            except Exception as exc:                  # the disk's error, for the slot thread
                failure = exc
            with self._lock:
                if failure is None:
                    self.written += 1
                    follow = [*self._owed.pop(path, []), *job.after]
                else:
                    self._owed.setdefault(path, []).extend(job.after)
            for then in follow:
                try:
                    then(job.arrays)
                except Exception as exc:              # e.g. an archive file not deleted
                    failure = exc
            with self._lock:
                if failure is not None:
                    self._failed[path] = failure
                self._writing = None
                self._lock.notify_all()
