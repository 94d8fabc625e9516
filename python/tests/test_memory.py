"""Memory stays flat: 10^5 forward() calls (with and without a Python force) and repeated runs
whose buffers are released with their last view (RSS from /proc/self/statm)."""
import os

import numpy as np
import pytest

import ukdyn
from conftest import scenario_path

PAGE = os.sysconf("SC_PAGE_SIZE")


def rss_bytes():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * PAGE


@pytest.fixture(scope="module")
def paper():
    return ukdyn.load_scenario(scenario_path("paper.yaml"))


def forward_loop(sc, count, forces=()):
    q, qd = sc.q0, np.linspace(-0.1, 0.1, sc.dof)
    tau = np.zeros(sc.dof)
    for k in range(count):
        r = sc.forward(1e-6 * k, q, qd, tau, forces)
    return r


def test_forward_1e5_calls_memory_flat(paper):
    forward_loop(paper, 2_000)  # warm up: the allocator's pools, numpy's caches
    before = rss_bytes()
    r = forward_loop(paper, 100_000)
    grown = rss_bytes() - before
    print("RSS growth over 1e5 forward() calls: %d bytes" % grown)
    assert r.finite
    # A leak of one n-vector (96 bytes) per call would be 9.6 MB; the meter sees one that size.
    assert grown < 1 << 20, grown
    before = rss_bytes()
    kept = [np.empty(paper.dof) for _ in range(100_000)]
    assert rss_bytes() - before > 4 << 20, "RSS does not show a leak of 1e5 arrays"
    del kept


def test_forward_with_python_force_memory_flat(paper):
    f = np.full(paper.dof, 0.5)
    forces = [lambda t, q, qd: f]
    forward_loop(paper, 500, forces)
    before = rss_bytes()
    forward_loop(paper, 5_000, forces)
    grown = rss_bytes() - before
    print("RSS growth over 5e3 forward() calls with a Python force: %d bytes" % grown)
    assert grown < 1 << 20, grown


def test_run_buffers_released(paper):
    paper.t_end = 0.5
    for _ in range(3):
        paper.simulate()
    before = rss_bytes()
    size = 0
    for _ in range(10):
        run = paper.simulate()
        size = run.data.nbytes
        column = run["theta1"]
        del run
        assert column.size > 0
        del column
    grown = rss_bytes() - before
    print("RSS growth over 10 runs of %d bytes each: %d bytes" % (size, grown))
    assert grown < 10 * size, (grown, size)
