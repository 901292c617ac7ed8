"""Speed of sb3_cmzdril.metrics.frechet_distance against plain discrete-Fréchet implementations.

Compares, on two random walks of n = m points (default 1000, d = 2):

* ``frechet_distance`` (anti-diagonal sweep, in-place numpy, squared distances);
* a pure-Python double-loop DP over Python lists, with the distance matrix precomputed by numpy
  (the *fastest* pure-Python form, so the speed-up quoted is a conservative one);
* the textbook double loop computing each distance inside the loop (``math.dist``);
* a naive numpy wavefront (fancy indexing into an (n+1, m+1) table per anti-diagonal);
* ``similaritymeasures.frechet_dist`` if it is importable (not a dependency; not installed for you).

Checks that all values agree and prints timings (best of ``--repeats``); the last line is
``speedup_vs_python_loop: <x>x`` against the list-based Python loop. Usage::

    python benchmarks/speed/frechet.py [--n 1000] [--dim 2] [--repeats 5] [--seed 0]
"""
from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable

import numpy as np
from scipy.spatial.distance import cdist

from sb3_cmzdril.metrics import frechet_distance


def python_loop_lists(P: np.ndarray, Q: np.ndarray) -> float:
    """Double-loop DP over Python lists; distances precomputed by numpy (fast pure-Python baseline)."""
    d = cdist(P, Q).tolist()
    n, m = len(d), len(d[0])
    prev = [math.inf] * m
    for i in range(n):
        row = d[i]
        cur = [0.0] * m
        for j in range(m):
            if i == 0 and j == 0:
                best = -math.inf
            elif i == 0:
                best = cur[j - 1]
            elif j == 0:
                best = prev[0]
            else:
                best = min(prev[j], prev[j - 1], cur[j - 1])
            cur[j] = max(best, row[j])
        prev = cur
    return prev[-1]


def python_loop_textbook(P: np.ndarray, Q: np.ndarray) -> float:
    """Textbook double loop: distance computed per pair inside the loop."""
    p, q = P.tolist(), Q.tolist()
    n, m = len(p), len(q)
    ca = [[math.inf] * m for _ in range(n)]
    for i in range(n):
        for j in range(m):
            dist = math.dist(p[i], q[j])
            if i == 0 and j == 0:
                ca[i][j] = dist
            elif i == 0:
                ca[i][j] = max(ca[i][j - 1], dist)
            elif j == 0:
                ca[i][j] = max(ca[i - 1][j], dist)
            else:
                ca[i][j] = max(min(ca[i - 1][j], ca[i - 1][j - 1], ca[i][j - 1]), dist)
    return ca[-1][-1]


def naive_wavefront(P: np.ndarray, Q: np.ndarray) -> float:
    """Anti-diagonal numpy DP the straightforward way: fancy indexing and fresh arrays per diagonal."""
    d = cdist(P, Q)
    n, m = d.shape
    ca = np.full((n + 1, m + 1), np.inf)  # row/column 0: the out-of-grid border
    ca[0, 0] = 0.0  # lets cell (0, 0) take d[0, 0] through the diagonal predecessor
    for k in range(n + m - 1):
        i = np.arange(max(0, k - m + 1), min(k, n - 1) + 1)
        j = k - i
        best = np.minimum(np.minimum(ca[i, j + 1], ca[i + 1, j]), ca[i, j])
        ca[i + 1, j + 1] = np.maximum(best, d[i, j])
    return float(ca[n, m])


def best_time(fn: Callable[[], float], repeats: int) -> tuple[float, float]:
    """(best wall time in seconds, value) over ``repeats`` calls."""
    best, value = math.inf, math.nan
    for _ in range(repeats):
        start = time.perf_counter()
        value = fn()
        best = min(best, time.perf_counter() - start)
    return best, value


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1000, help="points per curve (n = m)")
    parser.add_argument("--dim", type=int, default=2, help="point dimension")
    parser.add_argument("--repeats", type=int, default=5, help="timing repeats of the numpy versions (best is kept)")
    parser.add_argument("--loop-repeats", type=int, default=2, help="timing repeats of the pure-Python loops")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    rng = np.random.default_rng(args.seed)
    P = np.cumsum(rng.normal(size=(args.n, args.dim)), axis=0)
    Q = np.cumsum(rng.normal(size=(args.n, args.dim)), axis=0)
    print(
        f"random walks: n = m = {args.n}, d = {args.dim}, seed {args.seed}; "
        f"best of {args.repeats} (loops: {args.loop_repeats})"
    )

    ours_t, ours = best_time(lambda: frechet_distance(P, Q), args.repeats)
    results = [("frechet_distance (ours)", ours_t, ours)]
    loop_t, loop = best_time(lambda: python_loop_lists(P, Q), args.loop_repeats)
    results.append(("python loop, lists", loop_t, loop))
    text_t, text = best_time(lambda: python_loop_textbook(P, Q), args.loop_repeats)
    results.append(("python loop, textbook", text_t, text))
    naive_t, naive = best_time(lambda: naive_wavefront(P, Q), args.repeats)
    results.append(("naive numpy wavefront", naive_t, naive))
    try:
        import similaritymeasures  # type: ignore[import-not-found]
    except ImportError:
        print("similaritymeasures: not installed, skipped")
    else:
        sm_t, sm = best_time(lambda: float(similaritymeasures.frechet_dist(P, Q)), args.loop_repeats)
        results.append(("similaritymeasures.frechet_dist", sm_t, sm))

    for name, seconds, value in results:
        print(
            f"{name:34s} {seconds * 1e3:10.2f} ms   value {value!r:20s} diff {value - ours:+.1e}   "
            f"({seconds / ours_t:6.1f}x ours)"
        )
    # The DP only selects among distances, never adds them, so the result is one pairwise distance:
    # bit-identical wherever the same distance formula is used (cdist); math.dist rounds its last bit
    # differently for some pairs, hence the tolerance.
    worst = max(abs(value - ours) for _, _, value in results)
    if worst > 1e-12 * max(1.0, abs(ours)):
        raise SystemExit(f"values disagree: largest difference {worst:.3g}")
    print(f"values agree (largest difference {worst:.2g}; ours == python loop, lists: {ours == loop})")
    print(f"speedup_vs_python_loop: {loop_t / ours_t:.1f}x")


if __name__ == "__main__":
    main()
