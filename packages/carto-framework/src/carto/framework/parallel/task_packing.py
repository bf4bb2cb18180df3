"""Tile tasks sent to a cluster with their large arrays apart, each array once.

The tasks of a stage share large arrays: both sensors' line tables (a few MB each for a whole
scene), the starting DEM, the fused DEM of a strip (80 MB) that every ortho-image band is
made on. Sent as they are, every task carries its own copy of them: the scheduler holds the
pickled tasks of the whole stage (in the command's own process for a local cluster), so the
command's memory grew with the number of tiles, by 0.5 to 1.5 GB for a whole scene's
full-resolution iterations (issue 33).

:func:`pack_tasks` pickles each task with every array of at least :data:`SHARED_ARRAY_BYTES`
replaced by a key (pickle's persistent ids); the engine sends each of those arrays once, as a
task of its own (:func:`shared_array`, which the cluster makes again if the worker that held
it dies), and runs :func:`run_packed` on the workers, which unpickles each task around the
worker's copy of its arrays.
A task that cannot be pickled so (a closure that only ``cloudpickle`` knows) is packed by
``cloudpickle`` the same way. Arrays are shared by identity: the same array object in two
tasks is sent once; an equal copy is sent again. Each task still gets its own copy of an
array that was writeable (it may write into it, as into the copy a whole pickle gave it); a
read-only array (a DEM's heights) is shared by the tasks of a worker, read-only.
"""

from __future__ import annotations

import functools
import io
import pickle
from collections.abc import Callable, Sequence
from typing import Any

import attrs
import numpy as np

__all__ = [
    "SHARED_ARRAY_BYTES",
    "PackedTasks",
    "pack_tasks",
    "run_packed",
    "shared_array",
    "unpack_task",
]

SHARED_ARRAY_BYTES = 256 * 1024
"""Arrays of at least this size travel apart from the tasks, once per stage and worker."""


@attrs.frozen
class PackedTasks:
    """Tasks pickled without their large arrays.

    Attributes:
        blobs: each task pickled, its large arrays as persistent ids.
        keys: for each task, the keys of the arrays it needs (in ``arrays``).
        arrays: the large arrays by key.
    """

    blobs: tuple[bytes, ...]
    keys: tuple[tuple[str, ...], ...]
    arrays: dict[str, np.ndarray]


class _ArrayKeys:
    """What both picklers below add: large arrays replaced by keys (pickle's persistent
    ids), shared across tasks by identity."""

    def __init__(self, file: Any, arrays: dict[str, Any], ids: dict[int, str]) -> None:
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)  # type: ignore[call-arg]
        self.arrays, self.ids, self.used = arrays, ids, set()

    def persistent_id(self, obj: Any) -> str | None:
        if type(obj) is not np.ndarray or obj.nbytes < SHARED_ARRAY_BYTES:
            return None
        key = self.ids.get(id(obj))
        if key is None:  # kept in ``arrays``: its id stays its own while packing
            mode = "rw" if obj.flags.writeable else "ro"
            key = self.ids[id(obj)] = f"array-{len(self.ids)}-{mode}"
            self.arrays[key] = obj
        self.used.add(key)
        return key


class _Packer(_ArrayKeys, pickle.Pickler):
    pass


def _pack_one(task: Any, arrays: dict[str, Any], ids: dict[int, str]) -> tuple[bytes, set[str]]:
    buffer = io.BytesIO()
    packer: _ArrayKeys = _Packer(buffer, arrays, ids)
    try:
        packer.dump(task)  # type: ignore[attr-defined]
    except (pickle.PicklingError, AttributeError, TypeError):  # a closure: cloudpickle's
        buffer = io.BytesIO()
        packer = _cloud_packer()(buffer, arrays, ids)
        packer.dump(task)  # type: ignore[attr-defined]
    return buffer.getvalue(), packer.used


@functools.cache
def _cloud_packer() -> type[_ArrayKeys]:
    """:class:`_Packer` on ``cloudpickle`` (imported when a task needs it)."""
    import cloudpickle

    class _CloudPacker(_ArrayKeys, cloudpickle.Pickler):  # type: ignore[misc]
        pass

    return _CloudPacker


def pack_tasks(tasks: Sequence[Callable[[], Any]]) -> PackedTasks:
    """``tasks`` pickled with their arrays of :data:`SHARED_ARRAY_BYTES` or more apart
    (see the module docstring)."""
    arrays: dict[str, Any] = {}
    ids: dict[int, str] = {}
    blobs, keys = [], []
    for task in tasks:
        blob, used = _pack_one(task, arrays, ids)
        blobs.append(blob)
        keys.append(tuple(sorted(used)))
    return PackedTasks(tuple(blobs), tuple(keys), arrays)


class _Unpacker(pickle.Unpickler):
    def __init__(self, file: Any, arrays: dict[str, Any]) -> None:
        super().__init__(file)
        self.arrays = arrays

    def persistent_load(self, pid: Any) -> Any:
        array = self.arrays[pid]
        if pid.endswith("-rw"):
            return np.array(array)  # the task's own copy, as it had when pickled whole
        view = array.view()  # read-only when packed: shared by the worker's tasks
        view.flags.writeable = False
        return view


def unpack_task(blob: bytes, keys: Sequence[str], arrays: Sequence[Any]) -> Callable[[], Any]:
    """The task pickled in ``blob`` (:func:`pack_tasks`) around ``arrays``, the arrays of
    ``keys`` in that order (on a worker: its copies of the shared arrays)."""
    return _Unpacker(io.BytesIO(blob), dict(zip(keys, arrays, strict=True))).load()  # type: ignore[no-any-return]


def shared_array(array: Any) -> Any:
    """``array``: the task that gives the workers a shared array (made again where a worker
    that held it died)."""
    return array


def run_packed(blob: bytes, keys: Sequence[str], *arrays: Any) -> Any:
    """Run the task packed in ``blob`` (what a worker runs; dask gives it the shared
    arrays in place of their futures)."""
    return unpack_task(blob, keys, arrays)()
