"""Exact discrete Fréchet distance between two N-D polylines (an anti-diagonal numpy DP)."""
from __future__ import annotations

from typing import Any

import numpy as np
from numpy.lib.stride_tricks import as_strided
from scipy.spatial.distance import cdist

# Above this many pairwise distances (200 MB of float64) the Fréchet DP computes each anti-diagonal's
# distances on the fly instead of holding the full matrix: O(n + m) memory, about 4-5x slower.
_MAX_MATRIX_ELEMENTS = 25_000_000


def _as_curve(curve: Any, name: str) -> np.ndarray:
    try:
        arr = np.asarray(curve, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} must be a numeric array of points, (n, d) or (n,): {e}") from e
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise ValueError(f"{name} must be (n, d) or (n,), got an array with shape {arr.shape}")
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{name} is empty (shape {arr.shape}): a curve needs at least one point of dimension >= 1")
    if not np.all(np.isfinite(arr)):
        bad = int(np.argwhere(~np.isfinite(arr))[0, 0])
        raise ValueError(f"{name} contains NaN or inf (first at point {bad})")
    return arr


def frechet_distance(P: Any, Q: Any) -> float:
    """Exact discrete Fréchet distance between polylines ``P`` (n, d) and ``Q`` (m, d).

    ``n != m`` is allowed; 1-D inputs are read as (n, 1). The point-to-point metric is Euclidean.
    Symmetric, 0 for identical curves, and ``>= max(|P[0]-Q[0]|, |P[-1]-Q[-1]|)``.

    Algorithm: the usual O(n*m) coupling DP
    ``ca[i, j] = max(d[i, j], min(ca[i-1, j], ca[i, j-1], ca[i-1, j-1]))``, swept one anti-diagonal at a
    time so each sweep step is three in-place numpy calls over a whole diagonal. Exactness is kept
    because the DP only ever selects (max/min) among the pairwise distances, never combines them.

    :raises ValueError: empty curve, ndim > 2, different point dimensions, NaN or inf.
    """
    p = _as_curve(P, "P")
    q = _as_curve(Q, "Q")
    if p.shape[1] != q.shape[1]:
        raise ValueError(f"P and Q have points of different dimension: {p.shape[1]} vs {q.shape[1]}")
    # The distance is symmetric, so put the shorter curve on the diagonal axis: shorter buffers.
    if len(p) > len(q):
        p, q = q, p
    if len(p) * len(q) > _MAX_MATRIX_ELEMENTS:
        return _frechet_low_memory(p, q)
    return _frechet_matrix(p, q)


def _frechet_matrix(p: np.ndarray, q: np.ndarray) -> float:
    """Wavefront DP over the full (n, m) matrix of squared distances, n <= m."""
    # Squared distances: sqrt is monotone, so it commutes with the DP's max/min; one sqrt at the end
    # instead of n*m (cdist's sqeuclidean is ~2.5x faster than euclidean).
    d = cdist(p, q, "sqeuclidean")
    n, m = d.shape
    it = d.itemsize
    # Anti-diagonal k of a C-contiguous (n, m) array, cells (i, k - i), lives at flat offsets
    # k + i*(m - 1): a strided view gives every diagonal as a row without copying anything.
    # Rows k in [0, n+m-2], columns i in [0, n-1] reach flat offsets up to n*m - 1, so the view stays
    # inside the buffer (cells with k - i outside [0, m) alias other cells and are never read).
    diag = as_strided(d, shape=(n + m - 1, n), strides=(it, (m - 1) * it), writeable=False)

    # Three rotating diagonal buffers indexed by i + 1; index 0 is a permanent +inf guard for i = -1.
    # Cells a diagonal never writes stay +inf, and the index bounds below guarantee that the only
    # unwritten cells ever read are exactly the out-of-grid predecessors (j = -1 or i = -1).
    bufs = [np.full(n + 1, np.inf) for _ in range(3)]
    bufs[1][1] = d[0, 0]
    a, b, c = 0, 1, 2  # diagonal k-2, k-1, k
    tmp = np.empty(n)
    minimum, maximum = np.minimum, np.maximum

    # Phase 1, k < n: the diagonal grows, i in [0, k].
    for k in range(1, n):
        p2, p1, cur = bufs[a], bufs[b], bufs[c]
        t = tmp[: k + 1]
        minimum(p1[1 : k + 2], p1[: k + 1], out=t)  # (i, j-1) and (i-1, j)
        minimum(t, p2[: k + 1], out=t)  # (i-1, j-1)
        maximum(t, diag[k, : k + 1], out=cur[1 : k + 2])
        a, b, c = b, c, a
    # Phase 2, n <= k < m: full-length diagonals, i in [0, n-1]; the slices never change.
    views = [(buf[1:], buf[:-1]) for buf in bufs]
    for k in range(n, m):
        minimum(views[b][0], views[b][1], out=tmp)
        minimum(tmp, views[a][1], out=tmp)
        maximum(tmp, diag[k], out=views[c][0])
        a, b, c = b, c, a
    # Phase 3, k >= m: the diagonal shrinks, i in [k-m+1, n-1].
    for k in range(m, n + m - 1):
        lo = k - m + 1
        p2, p1, cur = bufs[a], bufs[b], bufs[c]
        t = tmp[lo:]
        minimum(p1[lo + 1 :], p1[lo:n], out=t)
        minimum(t, p2[lo:n], out=t)
        maximum(t, diag[k, lo:], out=cur[lo + 1 :])
        a, b, c = b, c, a
    return float(np.sqrt(bufs[b][n]))


def _frechet_low_memory(p: np.ndarray, q: np.ndarray) -> float:
    """Same DP, distances of each anti-diagonal computed when needed (n <= m); O(n + m) memory."""
    n, m = len(p), len(q)
    bufs = [np.full(n + 1, np.inf) for _ in range(3)]
    diff = p[0] - q[0]
    bufs[1][1] = float(diff @ diff)
    a, b, c = 0, 1, 2
    tmp = np.empty(n)
    for k in range(1, n + m - 1):
        lo = max(0, k - m + 1)
        hi = min(k, n - 1)
        t = tmp[lo : hi + 1]
        p2, p1, cur = bufs[a], bufs[b], bufs[c]
        np.minimum(p1[lo + 1 : hi + 2], p1[lo : hi + 1], out=t)
        np.minimum(t, p2[lo : hi + 1], out=t)
        # j = k - i runs from k - lo down to k - hi as i goes up: a reversed contiguous slice of q.
        qs = q[k - hi : k - lo + 1][::-1]
        delta = p[lo : hi + 1] - qs
        np.maximum(t, np.einsum("ij,ij->i", delta, delta), out=cur[lo + 1 : hi + 2])
        a, b, c = b, c, a
    return float(np.sqrt(bufs[b][n]))
