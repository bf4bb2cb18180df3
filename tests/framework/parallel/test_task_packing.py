"""Tasks packed with their large arrays apart: each array once however many tasks share it,
every task unpacked equal to the task pickled whole, with its own copy of the arrays."""

from __future__ import annotations

import functools
import pickle

import numpy as np

from carto.framework.parallel.task_packing import SHARED_ARRAY_BYTES, pack_tasks, unpack_task


def total(table: dict[str, np.ndarray], k: int) -> float:
    """Writes into its arrays (as a task may into its own copy), then sums them."""
    for a in table.values():
        a += k
    return float(sum(a.sum() for a in table.values()))


def _unpacked(packed, k):
    keys = packed.keys[k]
    return unpack_task(packed.blobs[k], keys, [packed.arrays[key] for key in keys])


def test_an_array_shared_by_every_task_is_packed_once():
    big = np.arange(SHARED_ARRAY_BYTES // 8 * 3, dtype=float)
    small = np.ones(10)
    tasks = [
        functools.partial(total, {"big": big, "small": small, "own": big * k}, k) for k in range(4)
    ]
    packed = pack_tasks(tasks)
    # the shared array once, each task's own large array once, the small one inside the tasks
    assert len(packed.arrays) == 1 + 4
    assert sum(len(b) for b in packed.blobs) < big.nbytes
    assert all(len(keys) == 2 for keys in packed.keys)
    whole = [pickle.loads(pickle.dumps(t))() for t in tasks]
    assert [_unpacked(packed, k)() for k in range(4)] == whole
    # each task wrote into its own copies: the packed arrays are as they were
    assert np.array_equal(packed.arrays[packed.keys[0][0]], np.arange(big.size, dtype=float))


def test_a_read_only_array_is_shared_by_the_tasks_read_only():
    heights = np.zeros(SHARED_ARRAY_BYTES // 8)
    heights.flags.writeable = False
    packed = pack_tasks([functools.partial(np.sum, heights)] * 2)
    (key,) = packed.arrays
    first, second = (_unpacked(packed, k) for k in range(2))
    assert first.args[0].base is second.args[0].base is packed.arrays[key]
    assert not first.args[0].flags.writeable
    assert first() == 0.0


def test_a_closure_is_packed_with_cloudpickle():
    big = np.full(SHARED_ARRAY_BYTES, 2, np.uint8)
    tasks = [lambda k=k: int(big.sum()) + k for k in range(2)]
    packed = pack_tasks(tasks)
    assert len(packed.arrays) == 1
    assert [_unpacked(packed, k)() for k in range(2)] == [2 * big.size, 2 * big.size + 1]
