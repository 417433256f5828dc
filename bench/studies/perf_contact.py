"""Micro-benchmark of the ellipsoid narrow phase (dem.contact.ellipsoid.ellipsoid_contact).

Pairs are built with the known-depth construction of the contact-mechanics reference §1.6:
random orientations and normal n, c2 = c1 + Q1 n / h1(n) + Q2 n / h2(n) - delta n, so the
pair overlaps by exactly delta along n (delta < 0 gives a gap of |delta|).  Timing is the
median over repeats of one @njit loop over all pairs, JIT compile excluded (a warm-up call
runs first).  Single thread.
"""
import time

import numpy as np
from numba import njit

from dem.quaternion import quat_to_matrices, random_quaternions

from dem.contact.ellipsoid import (OUT_LEN, OUT_NEWTON_ITERS, OUT_PW_ITERS, OUT_LAM, OUT_NX,
                                   ellipsoid_contact)


def _random_rotations(n, rng):
    """n uniformly random rotation matrices [n, 3, 3]."""
    return quat_to_matrices(random_quaternions(n, rng))


def make_pairs(n_pairs, aspect=(1.0, 0.8, 0.6), rel_depth=1e-3, seed=0, scale=1e-3):
    """Constructed pairs (reference §1.6): dict of c1, rot1, ax1, c2, rot2, ax2 [n, ...],
    normal [n, 3] and depth [n] (delta = rel_depth * smallest semi-axis; < 0 means a gap)."""
    rng = np.random.default_rng(seed)
    ax = scale * np.asarray(aspect, dtype=np.float64)
    ax1 = np.tile(ax, (n_pairs, 1))
    ax2 = np.tile(ax, (n_pairs, 1))
    rot1 = _random_rotations(n_pairs, rng)
    rot2 = _random_rotations(n_pairs, rng)
    nrm = rng.standard_normal((n_pairs, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    c1 = rng.uniform(0.0, 0.02, (n_pairs, 3))
    q1 = np.einsum('nij,nj,nkj->nik', rot1, ax1 ** 2, rot1)
    q2 = np.einsum('nij,nj,nkj->nik', rot2, ax2 ** 2, rot2)
    q1n = np.einsum('nij,nj->ni', q1, nrm)
    q2n = np.einsum('nij,nj->ni', q2, nrm)
    h1 = np.sqrt(np.einsum('ni,ni->n', nrm, q1n))
    h2 = np.sqrt(np.einsum('ni,ni->n', nrm, q2n))
    delta = rel_depth * ax.min() * np.ones(n_pairs)
    c2 = c1 + q1n / h1[:, None] + q2n / h2[:, None] - delta[:, None] * nrm
    return dict(c1=c1, rot1=rot1, ax1=ax1, c2=c2, rot2=rot2, ax2=ax2, normal=nrm, depth=delta)


@njit(cache=True)
def _run(c1, rot1, ax1, c2, rot2, ax2, lam0, n0, out, stats):
    """One pass over all pairs; stats [n, 3] = (hit, PW iterations, Newton evaluations)."""
    hits = 0
    for i in range(c1.shape[0]):
        hit = ellipsoid_contact(c1[i], rot1[i], ax1[i], c2[i], rot2[i], ax2[i],
                                lam0[i], n0[i], out)
        hits += hit
        stats[i, 0] = hit
        if hit:
            stats[i, 1] = out[OUT_PW_ITERS]
            stats[i, 2] = out[OUT_NEWTON_ITERS]
        else:
            stats[i, 1] = 0.0
            stats[i, 2] = 0.0
    return hits


@njit(cache=True)
def _warm_state(c1, rot1, ax1, c2, rot2, ax2, lam_out, n_out, out):
    """Cold solve of every pair, storing lambda* and n* as the next call's warm start."""
    for i in range(c1.shape[0]):
        lam_out[i] = -1.0
        n_out[i, 0] = 0.0
        n_out[i, 1] = 0.0
        n_out[i, 2] = 0.0
        if ellipsoid_contact(c1[i], rot1[i], ax1[i], c2[i], rot2[i], ax2[i],
                             -1.0, n_out[i], out):
            lam_out[i] = out[OUT_LAM]
            n_out[i, 0] = out[OUT_NX]
            n_out[i, 1] = out[OUT_NX + 1]
            n_out[i, 2] = out[OUT_NX + 2]


def _time(p, lam0, n0, repeats):
    n = p["c1"].shape[0]
    out = np.zeros(OUT_LEN)
    stats = np.zeros((n, 3))
    args = (p["c1"], p["rot1"], p["ax1"], p["c2"], p["rot2"], p["ax2"], lam0, n0, out, stats)
    _run(*args)                                        # JIT warm-up (or cache load)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        hits = _run(*args)
        times.append(time.perf_counter() - t0)
    hit = stats[:, 0] > 0
    return dict(us_per_pair=1e6 * float(np.median(times)) / n, pairs=n, hits=int(hits),
                pw_iters_mean=float(stats[hit, 1].mean()) if hit.any() else 0.0,
                pw_iters_max=int(stats[hit, 1].max()) if hit.any() else 0,
                newton_iters_mean=float(stats[hit, 2].mean()) if hit.any() else 0.0,
                newton_iters_max=int(stats[hit, 2].max()) if hit.any() else 0)


def time_ellipsoid_pairs(n_pairs=20000, aspect=(1.0, 0.8, 0.6), rel_depth=1e-3, seed=0,
                         repeats=7):
    """Median us per overlapping pair (cold start: no lambda / normal from a previous step).

    Returns {"us_per_pair", "pairs", "pw_iters_mean", "newton_iters_max", ...} plus
    "separated" (same shapes with a gap of 5 % of the smallest semi-axis) and "warm"
    (same overlapping pairs warm-started from their own converged lambda* and n*), each a
    dict of the same keys.
    """
    p = make_pairs(n_pairs, aspect, rel_depth, seed)
    cold_lam = -np.ones(n_pairs)
    cold_n = np.zeros((n_pairs, 3))
    res = _time(p, cold_lam, cold_n, repeats)
    lam_w = np.empty(n_pairs)
    n_w = np.empty((n_pairs, 3))
    _warm_state(p["c1"], p["rot1"], p["ax1"], p["c2"], p["rot2"], p["ax2"], lam_w, n_w,
                np.zeros(OUT_LEN))
    res["warm"] = _time(p, lam_w, n_w, repeats)
    ps = make_pairs(n_pairs, aspect, -0.05, seed + 1)
    res["separated"] = _time(ps, cold_lam, cold_n, repeats)
    return res


if __name__ == "__main__":
    import json
    print(json.dumps(time_ellipsoid_pairs(), indent=1))
    print(json.dumps(time_ellipsoid_pairs(aspect=(1.0, 0.5, 0.5)), indent=1))
