"""Contact forces: per-pair resolution, deterministic per-particle gather, walls.

Determinism (DESIGN.md): each candidate pair (i, j), gid[i] < gid[j], is resolved once into
per-pair results (force on j, torques on i and j, new history); particle p then sums its pair
contributions in ascending partner gid, then its wall contributions in wall order. The result
is independent of how pairs were found or which thread computed them, so every mode can be
bit-identical to serial.
"""
import math
import numpy as np
from numba import njit

from dem.contact.ellipsoid import (ellipsoid_contact, ellipsoid_wall_contact, OUT_LEN, OUT_DEPTH,
                                   OUT_NX, OUT_NY, OUT_NZ, OUT_XCX, OUT_XCY, OUT_XCZ, OUT_RE,
                                   OUT_KRATIO, OUT_LAM)
from dem.contact.hertz_factor import hertz_factor
from dem.contact.law import hertz_mindlin
from dem.contact.sphere import sphere_contact, sphere_wall_contact
from dem.state import SPHERE, H_FT, H_A, H_LAM, H_N, HIST_LEN

# per-pair result layout: pair_res [m, PR_LEN]
PR_FX = 0      # force on j [3] (i gets the exact negation)
PR_TI = 3      # torque on i [3]
PR_TJ = 6      # torque on j [3]
PR_HIST = 9    # new history record [HIST_LEN]
PR_LEN = 9 + HIST_LEN


@njit(cache=True, inline="always")
def find_history(hist_gid, hist_cnt, p, partner):
    """Slot of partner gid in particle p's contact table, or -1."""
    for s in range(hist_cnt[p]):
        if hist_gid[p, s] == partner:
            return s
    return -1


@njit(cache=True, inline="always")
def apply_law(depth, nx, ny, nz, xcx, xcy, xcz, r_e, kratio,
              c1, v1, w1, c2, v2, w2, mstar, estar, gstar, zeta, mu,
              hist, has_hist, dt, res, lam):
    """Hertz-Mindlin on one resolved contact; writes force/torques/history into res [PR_LEN].

    Body 2 may be a wall (v2 = w2 = 0, c2 unused). The stored tangential spring is rotated into
    the new tangent plane by projection and rescaled to its old magnitude (§3.2 step 1).
    """
    r1x, r1y, r1z = xcx - c1[0], xcy - c1[1], xcz - c1[2]
    r2x, r2y, r2z = xcx - c2[0], xcy - c2[1], xcz - c2[2]
    vrx = v2[0] + (w2[1] * r2z - w2[2] * r2y) - v1[0] - (w1[1] * r1z - w1[2] * r1y)
    vry = v2[1] + (w2[2] * r2x - w2[0] * r2z) - v1[1] - (w1[2] * r1x - w1[0] * r1z)
    vrz = v2[2] + (w2[0] * r2y - w2[1] * r2x) - v1[2] - (w1[0] * r1y - w1[1] * r1x)
    vn = vrx * nx + vry * ny + vrz * nz
    vtx, vty, vtz = vrx - vn * nx, vry - vn * ny, vrz - vn * nz
    ftx = fty = ftz = 0.0
    a_old = 0.0
    if has_hist:
        ox, oy, oz = hist[H_FT], hist[H_FT + 1], hist[H_FT + 2]
        a_old = hist[H_A]
        old2 = ox * ox + oy * oy + oz * oz
        if old2 > 0.0:
            dn = ox * nx + oy * ny + oz * nz
            ftx, fty, ftz = ox - dn * nx, oy - dn * ny, oz - dn * nz
            new2 = ftx * ftx + fty * fty + ftz * ftz
            if new2 > 0.0:
                s = math.sqrt(old2 / new2)
                ftx *= s
                fty *= s
                ftz *= s
    f_h = hertz_factor(kratio) if kratio > 1.0 else 1.0
    fn, tx, ty, tz, sx, sy, sz, a = hertz_mindlin(depth, r_e, f_h, estar, gstar, mstar, zeta, mu,
                                                 vn, vtx, vty, vtz, ftx, fty, ftz, a_old, dt)
    fx = fn * nx + tx
    fy = fn * ny + ty
    fz = fn * nz + tz
    res[PR_FX] = fx
    res[PR_FX + 1] = fy
    res[PR_FX + 2] = fz
    # torque on body 1 from -F at the contact point, on body 2 from +F
    res[PR_TI] = -(r1y * fz - r1z * fy)
    res[PR_TI + 1] = -(r1z * fx - r1x * fz)
    res[PR_TI + 2] = -(r1x * fy - r1y * fx)
    res[PR_TJ] = r2y * fz - r2z * fy
    res[PR_TJ + 1] = r2z * fx - r2x * fz
    res[PR_TJ + 2] = r2x * fy - r2y * fx
    h = PR_HIST
    res[h + H_FT] = sx
    res[h + H_FT + 1] = sy
    res[h + H_FT + 2] = sz
    res[h + H_A] = a
    res[h + H_LAM] = lam
    res[h + H_N] = nx
    res[h + H_N + 1] = ny
    res[h + H_N + 2] = nz


@njit(cache=True)
def resolve_pairs_range(k0, k1, pi, pj, pos, vel, omega, rot, axes, shape, mass, material, gid,
                        n_owned, hist_gid, hist_cnt, hist_val, estar, gstar, mu, zeta, dt,
                        active, pair_res, depth_ratio):
    """Resolve candidate pairs k0..k1-1: geometry (closed form for two spheres, PW + Newton
    otherwise), then the contact law. Writes active [m] (1 = touching), pair_res [m, PR_LEN],
    depth_ratio [m] (depth over the smaller minimum semi-axis).
    Returns the number of ellipsoid-solver calls (0 for a scene of spheres).
    History is read from the owned end of the pair (both ends hold identical copies)."""
    out = np.zeros(OUT_LEN)
    n0 = np.zeros(3)
    ecalls = 0
    for k in range(k0, k1):
        i = pi[k]
        j = pj[k]
        c1 = pos[i]
        c2 = pos[j]
        lam = 0.0
        if shape[i] == SPHERE and shape[j] == SPHERE:
            hit, depth, nx, ny, nz, xcx, xcy, xcz, r_e = sphere_contact(c1, axes[i, 0], c2, axes[j, 0])
            if not hit:
                active[k] = 0
                continue
            kratio = 1.0
            own = i if i < n_owned else j
            slot = find_history(hist_gid, hist_cnt, own, gid[j] if own == i else gid[i])
        else:
            own = i if i < n_owned else j
            slot = find_history(hist_gid, hist_cnt, own, gid[j] if own == i else gid[i])
            lam0 = -1.0
            n0[0] = n0[1] = n0[2] = 0.0
            if slot >= 0:
                # history normal is stored in the canonical (i -> j) direction on both ends
                lam0 = hist_val[own, slot, H_LAM]
                n0[0] = hist_val[own, slot, H_N]
                n0[1] = hist_val[own, slot, H_N + 1]
                n0[2] = hist_val[own, slot, H_N + 2]
            ecalls += 1
            if ellipsoid_contact(c1, rot[i], axes[i], c2, rot[j], axes[j], lam0, n0, out) == 0:
                active[k] = 0
                continue
            depth = out[OUT_DEPTH]
            nx, ny, nz = out[OUT_NX], out[OUT_NY], out[OUT_NZ]
            xcx, xcy, xcz = out[OUT_XCX], out[OUT_XCY], out[OUT_XCZ]
            r_e = out[OUT_RE]
            kratio = out[OUT_KRATIO]
            lam = out[OUT_LAM]
        active[k] = 1
        mi = mass[i]
        mj = mass[j]
        a = material[i]
        b = material[j]
        apply_law(depth, nx, ny, nz, xcx, xcy, xcz, r_e, kratio,
                  c1, vel[i], omega[i], c2, vel[j], omega[j], mi * mj / (mi + mj),
                  estar[a, b], gstar[a, b], zeta[a, b], mu[a, b],
                  hist_val[own, max(slot, 0)], slot >= 0, dt, pair_res[k], lam)
        ai = min(axes[i, 0], min(axes[i, 1], axes[i, 2]))
        aj = min(axes[j, 0], min(axes[j, 1], axes[j, 2]))
        depth_ratio[k] = depth / min(ai, aj)
    return ecalls


@njit(cache=True)
def build_adjacency(pi, pj, active, gid, n_owned):
    """CSR of each owned particle's touching pairs, sorted by ascending partner gid.

    Returns (start [n_owned+1], items [nnz] pair index). Rows are filled in pair order and then
    insertion-sorted by partner gid (rows are short), so the order never depends on how the
    pair list was produced.
    """
    start = np.zeros(n_owned + 1, dtype=np.int64)
    m = pi.shape[0]
    for k in range(m):
        if active[k]:
            if pi[k] < n_owned:
                start[pi[k] + 1] += 1
            if pj[k] < n_owned:
                start[pj[k] + 1] += 1
    for p in range(n_owned):
        start[p + 1] += start[p]
    fill = start[:-1].copy()
    items = np.empty(start[n_owned], dtype=np.int64)
    keys = np.empty(start[n_owned], dtype=np.int64)
    for k in range(m):
        if active[k]:
            i = pi[k]
            j = pj[k]
            if i < n_owned:
                items[fill[i]] = k
                keys[fill[i]] = gid[j]
                fill[i] += 1
            if j < n_owned:
                items[fill[j]] = k
                keys[fill[j]] = gid[i]
                fill[j] += 1
    for p in range(n_owned):
        for u in range(start[p] + 1, start[p + 1]):
            kk = keys[u]
            it = items[u]
            v = u - 1
            while v >= start[p] and keys[v] > kk:
                keys[v + 1] = keys[v]
                items[v + 1] = items[v]
                v -= 1
            keys[v + 1] = kk
            items[v + 1] = it
    return start, items


@njit(cache=True)
def gather_range(p0, p1, adj_start, adj_items, pi, pj, gid, pair_res, force, torque,
                 hist_gid, hist_val, hist_cnt):
    """Sum pair forces/torques of particles p0..p1-1 in ascending partner gid and rewrite their
    contact tables. Returns the largest row length (the caller widens the tables if it exceeds
    their width and gathers again)."""
    width = hist_gid.shape[1]
    longest = 0
    for p in range(p0, p1):
        fx = fy = fz = 0.0
        tx = ty = tz = 0.0
        s0 = adj_start[p]
        cnt = adj_start[p + 1] - s0
        longest = max(longest, cnt)
        for u in range(cnt):
            k = adj_items[s0 + u]
            r = pair_res[k]
            if pi[k] == p:
                fx -= r[PR_FX]
                fy -= r[PR_FX + 1]
                fz -= r[PR_FX + 2]
                tx += r[PR_TI]
                ty += r[PR_TI + 1]
                tz += r[PR_TI + 2]
                partner = gid[pj[k]]
            else:
                fx += r[PR_FX]
                fy += r[PR_FX + 1]
                fz += r[PR_FX + 2]
                tx += r[PR_TJ]
                ty += r[PR_TJ + 1]
                tz += r[PR_TJ + 2]
                partner = gid[pi[k]]
            if u < width:
                hist_gid[p, u] = partner
                for h in range(HIST_LEN):
                    hist_val[p, u, h] = r[PR_HIST + h]
        for u in range(min(cnt, width), min(hist_cnt[p], width)):
            hist_gid[p, u] = -1
        hist_cnt[p] = min(cnt, width)
        force[p, 0] = fx
        force[p, 1] = fy
        force[p, 2] = fz
        torque[p, 0] = tx
        torque[p, 1] = ty
        torque[p, 2] = tz
    return longest


@njit(cache=True)
def wall_range(p0, p1, wall_m, wall_d, pos, vel, omega, rot, axes, shape, mass, material,
               estar_w, gstar_w, zeta_w, mu_w, wall_hist, dt, force, torque):
    """Add planar-wall contacts of particles p0..p1-1 (walls in fixed order), updating each
    particle's per-wall history. Wall planes: m.x = d with m the unit normal into the domain.
    Returns (number of wall contacts, largest depth ratio = depth over the smallest semi-axis)."""
    out = np.zeros(OUT_LEN)
    res = np.zeros(PR_LEN)
    zero3 = np.zeros(3)
    worst = 0.0
    touching = 0
    for p in range(p0, p1):
        c = pos[p]
        for w in range(wall_m.shape[0]):
            mx, my, mz = wall_m[w, 0], wall_m[w, 1], wall_m[w, 2]
            dist = mx * c[0] + my * c[1] + mz * c[2] - wall_d[w]
            hist = wall_hist[p, w]
            if dist >= axes[p].max():
                hist[H_A] = 0.0
                continue
            if shape[p] == SPHERE:
                hit, depth, xcx, xcy, xcz, r_e = sphere_wall_contact(c, axes[p, 0], mx, my, mz, wall_d[w])
                if not hit:
                    hist[H_A] = 0.0
                    continue
                kratio = 1.0
            else:
                if ellipsoid_wall_contact(c, rot[p], axes[p], wall_m[w], wall_d[w], out) == 0:
                    hist[H_A] = 0.0
                    continue
                depth = out[OUT_DEPTH]
                xcx, xcy, xcz = out[OUT_XCX], out[OUT_XCY], out[OUT_XCZ]
                r_e = out[OUT_RE]
                kratio = out[OUT_KRATIO]
            a = material[p]
            # body 1 = particle, body 2 = wall; normal from particle into the wall is -m
            apply_law(depth, -mx, -my, -mz, xcx, xcy, xcz, r_e, kratio,
                      c, vel[p], omega[p], c, zero3, zero3, mass[p],
                      estar_w[a], gstar_w[a], zeta_w[a], mu_w[a], hist, hist[H_A] > 0.0, dt, res, 0.0)
            force[p, 0] -= res[PR_FX]
            force[p, 1] -= res[PR_FX + 1]
            force[p, 2] -= res[PR_FX + 2]
            torque[p, 0] += res[PR_TI]
            torque[p, 1] += res[PR_TI + 1]
            torque[p, 2] += res[PR_TI + 2]
            for h in range(HIST_LEN):
                hist[h] = res[PR_HIST + h]
            worst = max(worst, depth / axes[p].min())
            touching += 1
    return touching, worst
