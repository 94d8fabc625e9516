"""The cost of calling ukdyn's forward dynamics from Python, against the C++ call itself
(docs/python.md, "The fast path"). Not a test: it prints a table of median times per call.

    PYTHONPATH=build/release/python /usr/bin/python3 bench/python_binding.py [SCENARIO]

Rows:
  forward(t, q, qd)              the allocating call: a ForwardResult of 9 new arrays and C
  forward(q, qd, out=data)       into a reusable Data (views of the C++ buffers), no allocation
  forward_qdd(q, qd, out, data)  qdd only, into a preallocated array
  forward_batch per row (k)      k rows in one call, divided by k
  forward_qdd batch per row (k)  k rows, qdd only, divided by k: the C++ loop plus a copy of n
                                 numbers per row, i.e. about the cost of the C++ forward() call
The C++ call alone is measured by `make bench` (bench/bench_ukdyn.cpp, BM_forward: the same
ukdyn::forward() on the same model); the last row is its stand-in measured from here.
"""
import statistics
import sys
import timeit

import numpy as np

import ukdyn


def per_call(stmt, number, repeat=7):
    times = timeit.repeat(stmt, number=number, repeat=repeat)
    return statistics.median(times) / number


def main():
    path = sys.argv[1] if len(sys.argv) > 1 else "scenarios/paper.yaml"
    sc = ukdyn.load_scenario(path)
    n = sc.dof
    q, qd, tau = sc.q0.copy(), sc.qd0.copy(), np.zeros(n)
    d = sc.make_data()
    out = np.empty(n)
    k = 1000
    Q = np.tile(q, (k, 1))  # the same state k times: the C++ work of the single calls
    QD = np.tile(qd, (k, 1))
    OUT = np.empty((k, n))
    rows = [
        ("forward(t, q, qd)", lambda: sc.forward(0.0, q, qd, tau), 20000, 1),
        ("forward(q, qd, out=data)", lambda: sc.forward(q, qd, t=0.0, tau=tau, out=d), 50000, 1),
        ("forward(q, qd, data, 0.0, tau) positional", lambda: sc.forward(q, qd, d, 0.0, tau), 50000,
         1),
        ("forward_qdd(q, qd, out=, data=)",
         lambda: sc.forward_qdd(q, qd, t=0.0, tau=tau, out=out, data=d), 50000, 1),
        ("forward_qdd(q, qd, 0.0, tau, out, data)",
         lambda: sc.forward_qdd(q, qd, 0.0, tau, out, d), 50000, 1),
        ("forward_batch, per row (k=%d)" % k, lambda: sc.forward_batch(Q, QD, t=0.0), 20, k),
        ("forward_qdd batch, per row (k=%d)" % k,
         lambda: sc.forward_qdd(Q, QD, t=0.0, out=OUT, data=d), 50, k),
    ]
    print("scenario %s: n = %d coordinates, m = %d rows" % (path, n, sc.rows))
    print("%-44s %12s" % ("call", "per call"))
    base = None
    results = []
    for name, f, number, per in rows:
        t = per_call(f, number) / per
        results.append((name, t))
    base = results[-1][1]
    for name, t in results:
        print("%-44s %9.3f us  (%5.1fx the batched C++ loop)" % (name, t * 1e6, t / base))


if __name__ == "__main__":
    main()
