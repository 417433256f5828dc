"""Thread schemes as numba loops: who takes which outer particle rows of contact detection.

The paper's five OpenMP schemes (Yan & Regueiro §4.2, Table 1), over the outer particle loop
of contact detection (neighbour estimate + contact resolution) for all-pairs and link-cell:
- partition: thread t takes the contiguous rows [t n/T, (t+1) n/T);
- frogleap:  thread t takes rows t, t+T, t+2T, ...;
- headtail:  thread t takes the row pairs (k, n-1-k) for k = t, t+T, ... (balances a triangle);
- static:    numba prange, default (static) chunking, over blocks of STATIC_BLOCK rows (and then
             of pairs): numba hands each thread one contiguous run of blocks, so static is the
             partition distributed by the runtime instead of by hand;
- dynamic:   rows (and then candidate pairs) handed out at run time in small chunks from a
             shared atomic counter, so it is really dynamic on the default omp layer too
             (numba's prange chunk size only balances on tbb).
A thread resolves the contacts it found (the paper's loop: for each i, find and resolve its
pairs), except dynamic, which also hands out the pair resolution in chunks, and static, which
pranges over the pairs. Every other per-particle loop (gather, walls, integration) is split in
T contiguous blocks. Results never depend on the scheme (DESIGN.md, Determinism): pairs are
resolved independently and gathered per particle in ascending partner id.

Busy time per thread is read from the CPU cycle counter around each thread's share of a phase
(the scheduling level, not inside the physics) and converted to seconds by `cycles_per_second`.
"""
import time

import numpy as np
from llvmlite import ir
from numba import get_thread_id, njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

from dem.forces import (SPHERES, POLYS, gather_range, resolve_pairs_range, resolve_poly_pairs_range,
                        resolve_sphere_pairs_range, wall_range)
from dem.integrate import derive_geometry_range, derive_range, integrate_range
from dem.neighbor import HALF_SHELL, scan_rows

SCHEMES = ("partition", "frogleap", "headtail", "static", "dynamic")
STATIC = 3
DYNAMIC = 4
STATIC_BLOCK = 64     # rows or pairs per prange iteration of the static scheme
DYNAMIC_ROWS = 16     # rows per dynamic hand-out
DYNAMIC_PAIRS = 64    # candidate pairs per dynamic hand-out


@intrinsic
def cycle_counter(typingctx):
    """CPU cycle counter (llvm.readcyclecounter): int64 cycles."""
    sig = types.int64()

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.IntType(64), [])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.readcyclecounter")
        return builder.call(fn, [])
    return sig, codegen


@intrinsic
def fetch_add(typingctx, arr, idx, val):
    """Atomic arr[idx] += val returning the old value (int64 arrays), sequentially consistent."""
    sig = types.int64(arr, idx, val)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [args[1]])
        return builder.atomic_rmw("add", ptr, args[2], "seq_cst")
    return sig, codegen


@njit(cache=True)
def _read_cycles():
    return cycle_counter()


def cycles_per_second(duration=0.02):
    """Calibrate the cycle counter against perf_counter (once per process)."""
    _read_cycles()
    t0, c0 = time.perf_counter(), _read_cycles()
    while time.perf_counter() - t0 < duration:
        pass
    return (_read_cycles() - c0) / (time.perf_counter() - t0)


def scheme_rows(scheme, n, threads):
    """Rows of each thread for the explicit schemes: (row_start [T+1], rows [n]).

    Thread t scans rows[row_start[t]:row_start[t+1]]; static and dynamic need no list
    (identity order, assigned by prange or the atomic counter)."""
    t_count = threads
    if scheme in ("static", "dynamic"):
        per = [np.arange(n)] + [np.zeros(0, dtype=np.int64)] * (t_count - 1)
    elif scheme == "partition":
        bounds = [(t * n) // t_count for t in range(t_count + 1)]
        per = [np.arange(bounds[t], bounds[t + 1]) for t in range(t_count)]
    elif scheme == "frogleap":
        per = [np.arange(t, n, t_count) for t in range(t_count)]
    elif scheme == "headtail":
        half = (n + 1) // 2
        per = []
        for t in range(t_count):
            k = np.arange(t, half, t_count)
            tail = n - 1 - k
            both = np.stack([k, tail], axis=1).ravel()
            per.append(both[np.concatenate([[True], both[1:] != both[:-1]])] if len(both) else both)
    else:
        raise ValueError(f"unknown scheme {scheme!r} ({', '.join(SCHEMES)})")
    row_start = np.zeros(t_count + 1, dtype=np.int64)
    row_start[1:] = np.cumsum([len(p) for p in per])
    return row_start, np.concatenate(per).astype(np.int64)


@njit(parallel=True, cache=True)
def scan_threads(code, threads, row_start, rows, scell, dims, cell_start, cell_items, spos, srb, sgid,
                 n_owned, pi_t, pj_t, counts, tests, busy):
    """Neighbour scan under a scheme into per-thread buffers pi_t, pj_t [T, cap]; counts [T],
    tests [T] (pair tests made) and busy [T] (cycles) per thread."""
    n = scell.shape[0]
    counts[:] = 0
    tests[:] = 0
    busy[:] = 0
    if code == STATIC:
        for b in prange((n + STATIC_BLOCK - 1) // STATIC_BLOCK):
            t = get_thread_id()
            c0 = cycle_counter()
            c, w = scan_rows(rows, b * STATIC_BLOCK, min(n, (b + 1) * STATIC_BLOCK), scell, dims, cell_start,
                             cell_items, HALF_SHELL, spos, srb, sgid, n_owned, pi_t[t], pj_t[t], counts[t])
            counts[t] = c
            tests[t] += w
            busy[t] += cycle_counter() - c0
    elif code == DYNAMIC:
        counter = np.zeros(1, dtype=np.int64)
        for t in prange(threads):
            c0 = cycle_counter()
            c = 0
            w = 0
            while True:
                s = fetch_add(counter, 0, DYNAMIC_ROWS)
                if s >= n:
                    break
                c, dw = scan_rows(rows, s, min(n, s + DYNAMIC_ROWS), scell, dims, cell_start, cell_items, HALF_SHELL,
                                  spos, srb, sgid, n_owned, pi_t[t], pj_t[t], c)
                w += dw
            counts[t] = c
            tests[t] = w
            busy[t] = cycle_counter() - c0
    else:
        for t in prange(threads):
            c0 = cycle_counter()
            c, w = scan_rows(rows, row_start[t], row_start[t + 1], scell, dims, cell_start, cell_items,
                             HALF_SHELL, spos, srb, sgid, n_owned, pi_t[t], pj_t[t], 0)
            counts[t] = c
            tests[t] = w
            busy[t] = cycle_counter() - c0


@njit(parallel=True, cache=True)
def compact_pairs(threads, pi_t, pj_t, offsets, pi, pj):
    """Concatenate the per-thread pair buffers in thread order into pi, pj [sum counts]."""
    for t in prange(threads):
        o = offsets[t]
        for k in range(offsets[t + 1] - o):
            pi[o + k] = pi_t[t, k]
            pj[o + k] = pj_t[t, k]


@njit(cache=True)
def _resolve_chunk(k0, k1, kind, pi, pj, pos, vel, omega, rot, axes, shape, mass, material, gid, n_owned,
                   hist_start, hist_partner, hist_val, estar, gstar, mu, zeta, dt, method, active, pair_res,
                   depth_ratio, oorg, orot, ax6):
    """Resolve pairs k0..k1-1 with the loop of the scene kind (dem.forces: SPHERES, ELLIPSOIDS,
    POLYS); returns solver calls."""
    if kind == POLYS:
        return resolve_poly_pairs_range(k0, k1, pi, pj, pos, vel, omega, rot, axes, shape, mass, material, gid,
                                        n_owned, hist_start, hist_partner, hist_val, estar, gstar, mu, zeta, dt,
                                        method, active, pair_res, depth_ratio, oorg, orot, ax6)
    if kind == SPHERES:
        return resolve_sphere_pairs_range(k0, k1, pi, pj, pos, vel, omega, axes, mass, material, gid, n_owned,
                                          hist_start, hist_partner, hist_val, estar, gstar, mu, zeta, dt,
                                          active, pair_res, depth_ratio)
    return resolve_pairs_range(k0, k1, pi, pj, pos, vel, omega, rot, axes, shape, mass, material, gid, n_owned,
                               hist_start, hist_partner, hist_val, estar, gstar, mu, zeta, dt, method, active,
                               pair_res, depth_ratio)


@njit(parallel=True, cache=True)
def resolve_threads(code, threads, offsets, kind, pi, pj, pos, vel, omega, rot, axes, shape, mass,
                    material, gid, n_owned, hist_start, hist_partner, hist_val, estar, gstar, mu, zeta,
                    dt, method, active, pair_res, depth_ratio, oorg, orot, ax6, busy):
    """Contact resolution of the candidate pairs under a scheme; returns ellipsoid-solver calls.

    Explicit schemes: thread t resolves the pairs it found, offsets[t]..offsets[t+1]; static:
    prange over blocks of STATIC_BLOCK pairs; dynamic: chunks of DYNAMIC_PAIRS from an atomic
    counter."""
    m = offsets[threads]
    ecalls = np.zeros(threads, dtype=np.int64)
    if code == STATIC:
        for b in prange((m + STATIC_BLOCK - 1) // STATIC_BLOCK):
            t = get_thread_id()
            c0 = cycle_counter()
            k = b * STATIC_BLOCK
            k1 = min(m, k + STATIC_BLOCK)
            ecalls[t] += _resolve_chunk(k, k1, kind, pi, pj, pos, vel, omega, rot, axes, shape, mass, material,
                                        gid, n_owned, hist_start, hist_partner, hist_val, estar, gstar, mu, zeta,
                                        dt, method, active, pair_res, depth_ratio, oorg, orot, ax6)
            busy[t] += cycle_counter() - c0
        return ecalls.sum()
    counter = np.zeros(1, dtype=np.int64)
    for t in prange(threads):
        c0 = cycle_counter()
        k0 = offsets[t]
        k1 = offsets[t + 1]
        while True:
            if code == DYNAMIC:
                k0 = fetch_add(counter, 0, DYNAMIC_PAIRS)
                if k0 >= m:
                    break
                k1 = min(m, k0 + DYNAMIC_PAIRS)
            ecalls[t] += _resolve_chunk(k0, k1, kind, pi, pj, pos, vel, omega, rot, axes, shape, mass, material,
                                        gid, n_owned, hist_start, hist_partner, hist_val, estar, gstar, mu, zeta,
                                        dt, method, active, pair_res, depth_ratio, oorg, orot, ax6)
            if code != DYNAMIC:
                break
        busy[t] += cycle_counter() - c0
    return ecalls.sum()


@njit(parallel=True, cache=True)
def derive_threads(threads, n, quat, angmom, inertia, shape, rot, omega, poly_scene, pos, axes, poly, orot, oorg,
                   ax6):
    for t in prange(threads):
        lo = (t * n) // threads
        hi = ((t + 1) * n) // threads
        derive_range(lo, hi, quat, angmom, inertia, shape, rot, omega)
        if poly_scene:
            derive_geometry_range(lo, hi, pos, rot, axes, shape, poly, orot, oorg, ax6)


@njit(parallel=True, cache=True)
def gather_threads(threads, n, adj_start, adj_items, pi, pj, pair_res, force, torque, new_hist_val):
    for t in prange(threads):
        gather_range((t * n) // threads, ((t + 1) * n) // threads, adj_start, adj_items, pi, pj, pair_res,
                     force, torque, new_hist_val)


@njit(parallel=True, cache=True)
def wall_threads(threads, n, wall_m, wall_d, pos, vel, omega, rot, axes, rbound, shape, mass, material,
                 estar_w, gstar_w, zeta_w, mu_w, wall_hist, dt, force, torque, oorg, orot, ax6):
    touching = np.zeros(threads, dtype=np.int64)
    worst = np.zeros(threads)
    worst_p = np.zeros(threads, dtype=np.int64)
    for t in prange(threads):
        c, w, wp = wall_range((t * n) // threads, ((t + 1) * n) // threads, wall_m, wall_d, pos, vel, omega, rot, axes,
                          rbound, shape, mass, material, estar_w, gstar_w, zeta_w, mu_w, wall_hist, dt, force, torque,
                          oorg, orot, ax6)
        touching[t] = c
        worst[t] = w
        worst_p[t] = wp
    k = np.argmax(worst)
    return touching.sum(), worst[k], worst_p[k]


@njit(parallel=True, cache=True)
def integrate_threads(threads, n, pos, vel, quat, angmom, mass, inertia, shape, force, torque,
                      gx, gy, gz, has_gravity, dt):
    for t in prange(threads):
        integrate_range((t * n) // threads, ((t + 1) * n) // threads, pos, vel, quat, angmom, mass, inertia,
                        shape, force, torque, gx, gy, gz, has_gravity, dt)
