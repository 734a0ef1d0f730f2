"""A rosbag2 written so that an interrupted run can be resumed, and OUT only ever appears complete.

rosbags can only create a bag, never append to one, and a half-written MCAP or sqlite3 file is not reliably
readable. So the output goes to ``OUT.partial/``::

    job.json                      what the run was started with; a resume must match it
    segments/000000000000-000000000042/   a closed, complete bag holding the output of input messages [0, 42)
    segments/open/                the segment being written; a resume deletes it
    merge/<OUT name>/             the final bag while it is assembled from the segments

A segment is closed at least every ``segment_seconds`` (and on any exception, when the last input message was
written whole), so a crash loses at most that much work. :meth:`ResumableBagWriter.finish` copies the segments'
raw messages into one bag, renames it to OUT and removes OUT.partial.

Every bag is written in rosbag2 format version 8, which every distribution since Humble reads: version 9 writes a
topic's QoS as a YAML list where Humble expects a string, and Humble's parser gives up on the whole metadata.yaml. A
topic is declared as rosbag2 declares it (`_Writer.declare`), a type without a definition included.
"""

from __future__ import annotations

import json
import re
import shutil
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, ClassVar

from rosbags.interfaces import Connection, ConnectionExtRosbag2, MessageDefinition, MessageDefinitionFormat
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.rosbag2.metadata import dump_qos_v8
from rosbags.rosbag2.storage_mcap import McapWriter, Schema, write_schema
from rosbags.rosbag2.storage_sqlite3 import Sqlite3Writer

from ..errors import BagError
from .bags import ENCODINGS, TopicSpec

__all__ = ["PARTIAL_SUFFIX", "SEGMENT_SECONDS", "ResumableBagWriter", "partial_path"]

PARTIAL_SUFFIX = ".partial"
#: Default seconds of work between closed segments: what a crash can cost.
SEGMENT_SECONDS = 30.0
#: rosbag2 format version written: the newest that Humble reads (see the module docstring).
BAG_VERSION = 8
_PLUGINS = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}
_FORMATS = {encoding: format_ for format_, encoding in ENCODINGS.items()}
_JOB = "job.json"
_OPEN = "open"
_SEGMENT = re.compile(r"^(\d{12})-(\d{12})$")
#: ((topic, message type), timestamp in ns, CDR bytes) of one output message; the key is a `TopicSpec.key`.
Output = tuple[tuple[str, str], int, bytes | memoryview]


def partial_path(out: Path) -> Path:
    """Where the output of `out` is written until it is complete."""
    return out.with_name(out.name + PARTIAL_SUFFIX)


def _is_bag(path: Path) -> bool:
    return path.is_dir() and (path / "metadata.yaml").is_file()


class _Sqlite3Writer(Sqlite3Writer):
    """rosbags' sqlite3 storage; a type without a definition gets no message_definitions row.

    rosbag2 writes a row of encoding '' for it, which rosbags (0.11.9) cannot read; without a row, rosbags reads no
    definition and rosbag2 too (its bags before Iron have no such table at all).
    """

    def add_msgtype(self, connection: Connection) -> None:
        if connection.msgdef.format != MessageDefinitionFormat.NONE:
            super().add_msgtype(connection)


class _McapWriter(McapWriter):
    """rosbags' MCAP storage; a type without a definition gets rosbag2's schema for it: encoding '', no data."""

    def add_msgtype(self, connection: Connection) -> None:
        if connection.msgdef.format != MessageDefinitionFormat.NONE:
            super().add_msgtype(connection)
            return
        self.schemas.append(Schema(len(self.schemas) + 1, connection.msgtype, "", ""))
        write_schema(self.chunk.bio, self.schemas[-1])


class _Writer(Writer):
    """rosbags' writer, declaring topics as rosbag2 does, which `Writer.add_connection` cannot: it gives every type a
    definition (an empty one becomes a ros2msg definition of a type without fields) and requires a type hash."""

    STORAGE_PLUGINS: ClassVar = {StoragePlugin.SQLITE3: _Sqlite3Writer, StoragePlugin.MCAP: _McapWriter}

    def declare(self, spec: TopicSpec) -> Connection:
        """Add `spec`'s topic with its definition (or none) and its type hash (or '')."""
        assert self.storage is not None, "declare() before open()"
        connection = Connection(
            id=len(self.connections) + 1,
            topic=spec.topic,
            msgtype=spec.msgtype,
            msgdef=MessageDefinition(_FORMATS[spec.encoding], spec.msgdef),
            digest=spec.digest,
            msgcount=0,
            ext=ConnectionExtRosbag2(spec.serialization_format, list(spec.qos)),
            owner=self,
        )
        if spec.msgtype not in self.added_types:
            self.storage.add_msgtype(connection)
            self.added_types.add(spec.msgtype)
        self.storage.add_connection(connection, dump_qos_v8(list(spec.qos)))
        self.connections.append(connection)
        self.counts[connection.id] = 0
        return connection


def _open_writer(path: Path, storage: str, topics: Sequence[TopicSpec]) -> tuple[Writer, dict[tuple[str, str], Any]]:
    """A new bag at `path` with every topic declared (in the same order in every segment and in the result)."""
    writer = _Writer(path, version=BAG_VERSION, storage_plugin=_PLUGINS[storage])
    writer.open()
    return writer, {spec.key: writer.declare(spec) for spec in topics}


class ResumableBagWriter:
    """Output messages grouped by the input message they come from; see the module docstring for the layout.

    Use as a context manager around the processing loop, call :meth:`write` once per input message with index
    :attr:`done`, :attr:`done` + 1, ..., then :meth:`finish`.
    """

    def __init__(
        self,
        out: Path,
        storage: str,
        topics: Sequence[TopicSpec],
        job: Mapping[str, Any],
        *,
        overwrite: bool = False,
        resume: bool = False,
        segment_seconds: float = SEGMENT_SECONDS,
    ) -> None:
        if storage not in _PLUGINS:
            raise BagError(f"unknown storage {storage!r} (use {', '.join(_PLUGINS)})")
        self.out, self.partial = Path(out), partial_path(Path(out))
        self.storage, self.topics, self.segment_seconds = storage, list(topics), segment_seconds
        self._overwrite = overwrite
        self._check_out()
        #: Index of the first input message whose output is not yet in a closed segment.
        self.done = self._start(dict(job), resume)
        self.resumed_at = self.done
        self._segment: tuple[Writer, dict[tuple[str, str], Any]] | None = None
        self._first = self._opened = 0
        self._writing = False

    # -- start ------------------------------------------------------------------------------------------------------

    def _check_out(self) -> None:
        if not self.out.parent.is_dir():
            raise BagError(f"{self.out}: directory {self.out.parent} does not exist")
        if not (self.out.exists() or self.out.is_symlink()):
            return
        if not self._overwrite:
            raise BagError(f"{self.out} already exists; pass --overwrite to replace it")
        if self.out.is_symlink():  # replacing it at the end would fail after all the work, or follow the link
            raise BagError(f"{self.out} is a symbolic link; not replacing it (give the real directory)")
        if not (_is_bag(self.out) or (self.out.is_dir() and not any(self.out.iterdir()))):
            raise BagError(f"{self.out} exists and is not a rosbag2 directory; not replacing it")

    def _start(self, job: dict[str, Any], resume: bool) -> int:
        """Fresh OUT.partial, or the index to resume at after checking that `job` is the one it was started with."""
        if self.partial.exists() and not (self.partial / _JOB).is_file() and any(self.partial.iterdir()):
            raise BagError(f"{self.partial} exists and was not written by this command; move it away")
        if self.partial.exists() and resume:
            self._check_job(job)
            shutil.rmtree(self.partial / "segments" / _OPEN, ignore_errors=True)
            shutil.rmtree(self.partial / "merge", ignore_errors=True)
            (self.partial / "segments").mkdir(exist_ok=True)
            segments = self._segments()
            return segments[-1][1] if segments else 0
        if self.partial.exists() and not self._overwrite:
            raise BagError(
                f"{self.partial} holds an unfinished run; pass --resume to continue it or --overwrite to start again"
            )
        shutil.rmtree(self.partial, ignore_errors=True)
        fresh = self.partial.with_name(self.partial.name + ".new")  # OUT.partial appears whole, with its job.json
        shutil.rmtree(fresh, ignore_errors=True)
        fresh.mkdir()
        (fresh / _JOB).write_text(json.dumps(job, indent=1, sort_keys=True) + "\n")
        (fresh / "segments").mkdir()
        fresh.rename(self.partial)
        return 0

    def _check_job(self, job: dict[str, Any]) -> None:
        try:
            started = json.loads((self.partial / _JOB).read_text())
        except (OSError, ValueError) as error:
            raise BagError(f"{self.partial / _JOB}: unreadable ({error}); pass --overwrite to start again") from None
        for key in sorted(set(job) | set(started)):
            if job.get(key) != started.get(key):
                raise BagError(
                    f"{self.partial} was started with {key} = {started.get(key)!r}, not {job.get(key)!r}; resume "
                    "with the same input and options, or pass --overwrite to start again"
                )

    def _segments(self) -> list[tuple[int, int, Path]]:
        """Closed segments in input order; they must tile [0, done) without a gap."""
        found = []
        for path in (self.partial / "segments").iterdir():
            match = _SEGMENT.match(path.name)
            if match and _is_bag(path):
                found.append((int(match[1]), int(match[2]), path))
        found.sort()
        end = 0
        for first, stop, path in found:
            if first != end:
                raise BagError(f"{path}: segments of {self.partial} leave a gap at message {end}; pass --overwrite")
            end = stop
        return found

    # -- writing ----------------------------------------------------------------------------------------------------

    def write(self, index: int, outputs: Iterable[Output]) -> None:
        """Record everything input message `index` produced (possibly nothing); closes the segment when it is due."""
        if index != self.done:
            raise ValueError(f"input message {index} written out of order; {self.done} is next")
        if self._segment is None:
            self._segment = _open_writer(self._segment_path(_OPEN), self.storage, self.topics)
            self._first, self._opened = index, time.monotonic()
        writer, connections = self._segment
        self._writing = True
        for key, timestamp, raw in outputs:
            writer.write(connections[key], timestamp, raw)
        self._writing = False
        self.done = index + 1
        if time.monotonic() - self._opened >= self.segment_seconds:
            self._close_segment()

    def _segment_path(self, name: str) -> Path:
        return self.partial / "segments" / name

    def _close_segment(self) -> None:
        """Close the open segment and give it the name of the input range it covers."""
        if self._segment is None:
            return
        writer, _ = self._segment
        self._segment = None
        writer.close()
        self._segment_path(_OPEN).rename(self._segment_path(f"{self._first:012d}-{self.done:012d}"))

    def _abort_segment(self) -> None:
        if self._segment is not None:
            self._segment[0].abort()
            self._segment = None
        shutil.rmtree(self._segment_path(_OPEN), ignore_errors=True)

    def __enter__(self) -> ResumableBagWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None, tb: TracebackType | None) -> None:
        """Keep the work done (on an exception too): the open segment is closed unless a message was half written.

        A run that stops before any work was kept leaves nothing behind, so a bad option costs no --resume.
        """
        if self._writing:
            self._abort_segment()
        else:
            self._close_segment()
        if self.partial.is_dir() and not self._segments():
            shutil.rmtree(self.partial)

    # -- finishing --------------------------------------------------------------------------------------------------

    def finish(self, progress: Callable[[int], None] | None = None, total: Callable[[int], None] | None = None) -> Path:
        """Merge the segments into OUT (replacing an old OUT only now), remove OUT.partial; return OUT.

        `total(n)` is told the number of messages to copy, `progress(n)` how many were copied since its last call.
        """
        self._close_segment()
        segments = self._segments()
        target = self.partial / "merge" / self.out.name
        shutil.rmtree(target.parent, ignore_errors=True)
        target.parent.mkdir()
        readers = [Reader(path) for _, _, path in segments]
        for reader in readers:
            reader.open()
        try:
            if total is not None:
                total(sum(reader.message_count for reader in readers))
            self._merge(readers, target, progress)
        finally:
            for reader in readers:
                reader.close()
        if self.out.exists():  # checked in _check_out: --overwrite, and a bag or an empty directory
            shutil.rmtree(self.out)
        target.rename(self.out)
        shutil.rmtree(self.partial)
        return self.out

    def _merge(self, readers: Sequence[Reader], target: Path, progress: Callable[[int], None] | None) -> None:
        writer, connections = _open_writer(target, self.storage, self.topics)
        try:
            for reader in readers:
                for connection, timestamp, raw in reader.messages():
                    writer.write(connections[connection.topic, connection.msgtype], timestamp, raw)
                    if progress is not None:
                        progress(1)
        except BaseException:
            writer.abort()
            raise
        writer.close()
