"""Freed heap memory given back to the system between stages, measured by the kernel's count
of this process's resident pages (``/proc/self/statm``), in a fresh interpreter (the test
process's own heap history would blur the figures)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from carto.framework.parallel import process_memory

pytestmark = pytest.mark.skipif(
    process_memory._trim() is None, reason="glibc's malloc_trim only (Linux with glibc)"
)

_PROBE = """
import json, numpy as np
from carto.framework.parallel.process_memory import release_free_memory, resident_mb
big = np.ones(20_000_000 // 8); del big  # a freed 20 MB block raises glibc's mmap threshold
arrays, keep = [], []
for _ in range(300):  # 300 arrays of 1 MB from the heap, a small live one after each
    arrays.append(np.ones(1_000_000 // 8))
    keep.append(np.ones(64))
before = resident_mb()
del arrays  # freed, but held by the live small ones around them
freed = resident_mb()
done = release_free_memory("test")
print(json.dumps({"before": before, "freed": freed, "after": resident_mb(), "done": done}))
"""


def test_released_memory_leaves_the_process():
    # glibc's own settings (a local cluster's nannies may leave MALLOC_TRIM_THRESHOLD_ in
    # the environment of the process that started them)
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    out = subprocess.run(
        [sys.executable, "-c", _PROBE], capture_output=True, text=True, check=True, env=env
    ).stdout
    mb = json.loads(out.splitlines()[-1])
    assert mb["done"]
    # glibc kept the 300 MB freed between live blocks; the release gives most of it back
    assert mb["before"] - mb["freed"] < 100
    assert mb["freed"] - mb["after"] > 200


def test_resident_memory_is_the_kernels_figure():
    with open("/proc/self/status") as f:
        vm_rss_kb = next(int(line.split()[1]) for line in f if line.startswith("VmRSS:"))
    assert process_memory.resident_mb() == pytest.approx(vm_rss_kb / 1e3, rel=0.05)
