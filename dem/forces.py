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
from dem.contact.methods import pw_contact, sextic_contact
from dem.contact.polyellipsoid import polyellipsoid_contact, polyellipsoid_wall_contact
from dem.contact.sphere import sphere_contact, sphere_wall_contact
from dem.state import SPHERE, POLY, H_FT, H_A, H_LAM, H_N, HIST_LEN

# per-pair result layout: pair_res [m, PR_LEN]
PR_FX = 0      # force on j [3] (i gets the exact negation)
PR_TI = 3      # torque on i [3]
PR_TJ = 6      # torque on j [3]
PR_HIST = 9    # new history record [HIST_LEN]
PR_LEN = 9 + HIST_LEN

# ellipsoid contact methods (issue 7; dem/contact/methods.py): index = the `method` argument
CONTACT_METHODS = ("exact", "pw", "sextic")
EXACT, PW, SEXTIC = 0, 1, 2
# scene kinds: which pair loop a scene needs (it pays only for the solvers its shapes use)
SPHERES, ELLIPSOIDS, POLYS = 0, 1, 2


def scene_kind(shape, has_poly):
    """SPHERES when every particle is a sphere, POLYS when the scene has poly-ellipsoids, else ELLIPSOIDS."""
    if has_poly:
        return POLYS
    return SPHERES if bool(np.all(shape == SPHERE)) else ELLIPSOIDS


@njit(cache=True, inline="always")
def find_history(hist_start, hist_partner, p, partner):
    """Row of partner gid in owned particle p's contact history (CSR, ascending), or -1."""
    for r in range(hist_start[p], hist_start[p + 1]):
        g = hist_partner[r]
        if g == partner:
            return r
        if g > partner:
            break
    return -1


@njit(cache=True, inline="always")
def contact_force(depth, nx, ny, nz, r_e, kratio, r1x, r1y, r1z, r2x, r2y, r2z, vrx, vry, vrz,
                  mstar, estar, gstar, zeta, mu, ox, oy, oz, a_old, has_hist, dt):
    """Hertz-Mindlin on one resolved contact (all scalars: numba row views cost atomic refcounts).

    n = (nx, ny, nz) unit normal from body 1 to body 2; r1, r2 lever arms from the mass centres
    to the contact point [m]; vr = relative velocity of body 2 w.r.t. body 1 at the contact point
    [m/s]; (ox, oy, oz, a_old) the stored spring [N] and contact radius [m] when has_hist.
    The stored spring is rotated into the new tangent plane by projection and rescaled to its old
    magnitude (contact-mechanics.md §3.2 step 1).
    Returns (F [3] on body 2 (body 1 gets -F), torque on 1 [3], torque on 2 [3], spring [3], a).
    """
    vn = vrx * nx + vry * ny + vrz * nz
    vtx, vty, vtz = vrx - vn * nx, vry - vn * ny, vrz - vn * nz
    ftx = fty = ftz = 0.0
    if not has_hist:
        a_old = 0.0
    else:
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
    # torque on body 1 from -F at the contact point, on body 2 from +F
    return (fx, fy, fz,
            -(r1y * fz - r1z * fy), -(r1z * fx - r1x * fz), -(r1x * fy - r1y * fx),
            r2y * fz - r2z * fy, r2z * fx - r2x * fz, r2x * fy - r2y * fx,
            sx, sy, sz, a)


@njit(cache=True, inline="always")
def _store(res, k, f, nx, ny, nz, lam):
    """Write contact_force's tuple f and the warm-start data into pair record res[k]."""
    res[k, PR_FX] = f[0]
    res[k, PR_FX + 1] = f[1]
    res[k, PR_FX + 2] = f[2]
    res[k, PR_TI] = f[3]
    res[k, PR_TI + 1] = f[4]
    res[k, PR_TI + 2] = f[5]
    res[k, PR_TJ] = f[6]
    res[k, PR_TJ + 1] = f[7]
    res[k, PR_TJ + 2] = f[8]
    h = PR_HIST
    res[k, h + H_FT] = f[9]
    res[k, h + H_FT + 1] = f[10]
    res[k, h + H_FT + 2] = f[11]
    res[k, h + H_A] = f[12]
    res[k, h + H_LAM] = lam
    res[k, h + H_N] = nx
    res[k, h + H_N + 1] = ny
    res[k, h + H_N + 2] = nz


@njit(cache=True, inline="always")
def pair_law(i, j, depth, nx, ny, nz, xcx, xcy, xcz, r_e, kratio, pos, vel, omega, mass, material,
             estar, gstar, zeta, mu, hist_val, slot, dt, lam, res, k):
    """contact_force for particles i -> j, inputs read by index, result stored in res[k]."""
    r1x, r1y, r1z = xcx - pos[i, 0], xcy - pos[i, 1], xcz - pos[i, 2]
    r2x, r2y, r2z = xcx - pos[j, 0], xcy - pos[j, 1], xcz - pos[j, 2]
    vrx = (vel[j, 0] + (omega[j, 1] * r2z - omega[j, 2] * r2y)
           - vel[i, 0] - (omega[i, 1] * r1z - omega[i, 2] * r1y))
    vry = (vel[j, 1] + (omega[j, 2] * r2x - omega[j, 0] * r2z)
           - vel[i, 1] - (omega[i, 2] * r1x - omega[i, 0] * r1z))
    vrz = (vel[j, 2] + (omega[j, 0] * r2y - omega[j, 1] * r2x)
           - vel[i, 2] - (omega[i, 0] * r1y - omega[i, 1] * r1x))
    mi = mass[i]
    mj = mass[j]
    a = material[i]
    b = material[j]
    s = max(slot, 0)
    f = contact_force(depth, nx, ny, nz, r_e, kratio, r1x, r1y, r1z, r2x, r2y, r2z, vrx, vry, vrz,
                      mi * mj / (mi + mj), estar[a, b], gstar[a, b], zeta[a, b], mu[a, b],
                      hist_val[s, H_FT], hist_val[s, H_FT + 1], hist_val[s, H_FT + 2], hist_val[s, H_A],
                      slot >= 0, dt)
    _store(res, k, f, nx, ny, nz, lam)


@njit(cache=True, inline="always")
def _sphere_pair(k, i, j, pos, vel, omega, axes, mass, material, gid, n_owned, hist_start, hist_partner,
                 hist_val, estar, gstar, mu, zeta, dt, active, pair_res, depth_ratio):
    """Closed-form sphere-sphere contact and law for candidate pair k = (i, j)."""
    hit, depth, nx, ny, nz, xcx, xcy, xcz, r_e = sphere_contact(
        pos[i, 0], pos[i, 1], pos[i, 2], axes[i, 0], pos[j, 0], pos[j, 1], pos[j, 2], axes[j, 0])
    if not hit:
        active[k] = 0
        return
    own = i if i < n_owned else j
    slot = find_history(hist_start, hist_partner, own, gid[j] if own == i else gid[i])
    active[k] = 1
    pair_law(i, j, depth, nx, ny, nz, xcx, xcy, xcz, r_e, 1.0, pos, vel, omega, mass, material,
             estar, gstar, zeta, mu, hist_val, slot, dt, 0.0, pair_res, k)
    depth_ratio[k] = depth / min(axes[i, 0], axes[j, 0])


@njit(cache=True)
def resolve_sphere_pairs_range(k0, k1, pi, pj, pos, vel, omega, axes, mass, material, gid, n_owned,
                               hist_start, hist_partner, hist_val, estar, gstar, mu, zeta, dt,
                               active, pair_res, depth_ratio):
    """resolve_pairs_range for a scene of spheres only: the loop holds no ellipsoid solver, so
    a sphere scene neither runs nor carries it (its loop body stays small). Returns 0 solver calls."""
    for k in range(k0, k1):
        _sphere_pair(k, pi[k], pj[k], pos, vel, omega, axes, mass, material, gid, n_owned, hist_start,
                     hist_partner, hist_val, estar, gstar, mu, zeta, dt, active, pair_res, depth_ratio)
    return 0


@njit(cache=True, inline="always")
def _warm_start(hist_val, slot, n0):
    """Stored PW lambda (or -1) of a pair's history row slot, its normal into n0 [3]."""
    if slot < 0:
        n0[0] = n0[1] = n0[2] = 0.0
        return -1.0
    # the stored normal points i -> j (canonical order) on both ends
    n0[0] = hist_val[slot, H_N]
    n0[1] = hist_val[slot, H_N + 1]
    n0[2] = hist_val[slot, H_N + 2]
    return hist_val[slot, H_LAM]


@njit(cache=True, inline="always")
def _solved_pair(hit, k, i, j, out, amin_i, amin_j, pos, vel, omega, mass, material, estar, gstar, zeta, mu,
                 hist_val, slot, dt, active, pair_res, depth_ratio):
    """After a solver filled out [OUT_LEN] (hit = 1) or found no contact: mark pair k, apply the law,
    and record the depth over the smaller of the smallest semi-axes amin_i, amin_j [m]."""
    if hit == 0:
        active[k] = 0
        return
    depth = out[OUT_DEPTH]
    active[k] = 1
    pair_law(i, j, depth, out[OUT_NX], out[OUT_NY], out[OUT_NZ], out[OUT_XCX], out[OUT_XCY],
             out[OUT_XCZ], out[OUT_RE], out[OUT_KRATIO], pos, vel, omega, mass, material,
             estar, gstar, zeta, mu, hist_val, slot, dt, out[OUT_LAM], pair_res, k)
    depth_ratio[k] = depth / min(amin_i, amin_j)


@njit(cache=True, inline="always")
def _ellipsoid_pair(k, i, j, pos, vel, omega, rot, axes, mass, material, gid, n_owned, hist_start,
                    hist_partner, hist_val, estar, gstar, mu, zeta, dt, method, active, pair_res,
                    depth_ratio, out, n0):
    """Ellipsoid (or sphere-ellipsoid) pair k = (i, j) by CONTACT_METHODS[method], then the law."""
    own = i if i < n_owned else j
    slot = find_history(hist_start, hist_partner, own, gid[j] if own == i else gid[i])
    lam0 = _warm_start(hist_val, slot, n0)
    if method == EXACT:
        hit = ellipsoid_contact(pos[i], rot[i], axes[i], pos[j], rot[j], axes[j], lam0, n0, out)
    elif method == PW:
        hit = pw_contact(pos[i], rot[i], axes[i], pos[j], rot[j], axes[j], lam0, n0, out)
    else:
        hit = sextic_contact(pos[i], rot[i], axes[i], pos[j], rot[j], axes[j], lam0, n0, out)
    ai = min(axes[i, 0], min(axes[i, 1], axes[i, 2]))
    aj = min(axes[j, 0], min(axes[j, 1], axes[j, 2]))
    _solved_pair(hit, k, i, j, out, ai, aj, pos, vel, omega, mass, material, estar, gstar, zeta, mu, hist_val,
                 slot, dt, active, pair_res, depth_ratio)


@njit(cache=True, inline="always")
def _ellipsoid_or_sphere_pair(k, i, j, pos, vel, omega, rot, axes, shape, mass, material, gid, n_owned,
                              hist_start, hist_partner, hist_val, estar, gstar, mu, zeta, dt, method, active,
                              pair_res, depth_ratio, out, n0):
    """Pair k = (i, j) without a poly-ellipsoid: closed form for two spheres, else the ellipsoid
    method. Returns the solver calls it made (0 or 1)."""
    if shape[i] == SPHERE and shape[j] == SPHERE:
        _sphere_pair(k, i, j, pos, vel, omega, axes, mass, material, gid, n_owned, hist_start,
                     hist_partner, hist_val, estar, gstar, mu, zeta, dt, active, pair_res, depth_ratio)
        return 0
    _ellipsoid_pair(k, i, j, pos, vel, omega, rot, axes, mass, material, gid, n_owned, hist_start,
                    hist_partner, hist_val, estar, gstar, mu, zeta, dt, method, active, pair_res,
                    depth_ratio, out, n0)
    return 1


@njit(cache=True)
def resolve_pairs_range(k0, k1, pi, pj, pos, vel, omega, rot, axes, shape, mass, material, gid,
                        n_owned, hist_start, hist_partner, hist_val, estar, gstar, mu, zeta, dt,
                        method, active, pair_res, depth_ratio):
    """Resolve candidate pairs k0..k1-1 of a scene of ellipsoids (and spheres): geometry (closed
    form for two spheres; otherwise the ellipsoid method CONTACT_METHODS[method]: EXACT = PW +
    Newton on S^2, PW = Perram-Wertheim depth only, SEXTIC = Yan 2010), then the contact law.
    Writes active [m] (1 = touching), pair_res [m, PR_LEN], depth_ratio [m] (depth over the
    smaller minimum semi-axis). Returns the number of ellipsoid-solver calls.
    History is read from the owned end of the pair (both ends hold identical copies)."""
    out = np.zeros(OUT_LEN)
    n0 = np.zeros(3)
    ecalls = 0
    for k in range(k0, k1):
        ecalls += _ellipsoid_or_sphere_pair(k, pi[k], pj[k], pos, vel, omega, rot, axes, shape, mass, material, gid,
                                            n_owned, hist_start, hist_partner, hist_val, estar, gstar, mu, zeta,
                                            dt, method, active, pair_res, depth_ratio, out, n0)
    return ecalls


@njit(cache=True)
def resolve_poly_pairs_range(k0, k1, pi, pj, pos, vel, omega, rot, axes, shape, mass, material, gid,
                             n_owned, hist_start, hist_partner, hist_val, estar, gstar, mu, zeta, dt,
                             method, active, pair_res, depth_ratio, oorg, orot, ax6):
    """resolve_pairs_range for a scene with poly-ellipsoids: a pair with a poly-ellipsoid goes to
    the octant active-set solver (polyellipsoid_contact; the other body as a poly-ellipsoid with
    equal halves) on the octant geometry oorg [n,3], orot [n,3,3], ax6 [n,6]
    (derive_geometry_range); lever arms and velocities refer to the mass centres pos. Other
    pairs as in resolve_pairs_range. Returns the number of solver calls."""
    out = np.zeros(OUT_LEN)
    n0 = np.zeros(3)
    ecalls = 0
    for k in range(k0, k1):
        i = pi[k]
        j = pj[k]
        if shape[i] != POLY and shape[j] != POLY:
            ecalls += _ellipsoid_or_sphere_pair(k, i, j, pos, vel, omega, rot, axes, shape, mass, material, gid,
                                                n_owned, hist_start, hist_partner, hist_val, estar, gstar, mu,
                                                zeta, dt, method, active, pair_res, depth_ratio, out, n0)
            continue
        ecalls += 1
        own = i if i < n_owned else j
        slot = find_history(hist_start, hist_partner, own, gid[j] if own == i else gid[i])
        _warm_start(hist_val, slot, n0)
        hit = polyellipsoid_contact(oorg[i], orot[i], ax6[i], oorg[j], orot[j], ax6[j], n0, out)
        ai = ax6[i, 0]
        aj = ax6[j, 0]
        for c in range(1, 6):
            ai = min(ai, ax6[i, c])
            aj = min(aj, ax6[j, c])
        _solved_pair(hit, k, i, j, out, ai, aj, pos, vel, omega, mass, material, estar, gstar, zeta, mu,
                     hist_val, slot, dt, active, pair_res, depth_ratio)
    return ecalls


@njit(cache=True)
def build_adjacency(pi, pj, active, gid, n_owned):
    """CSR of each owned particle's touching pairs, sorted by ascending partner gid.

    Returns (start [n_owned+1], items [nnz] pair index, keys [nnz] partner gid). Rows are filled
    in pair order and then
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
    return start, items, keys


@njit(cache=True)
def gather_range(p0, p1, adj_start, adj_items, pi, pj, pair_res, force, torque, new_hist_val):
    """Sum the pair forces/torques of particles p0..p1-1 in ascending partner gid and write
    their new contact history new_hist_val [nnz, HIST_LEN] (rows aligned with the adjacency)."""
    for p in range(p0, p1):
        fx = fy = fz = 0.0
        tx = ty = tz = 0.0
        for u in range(adj_start[p], adj_start[p + 1]):
            k = adj_items[u]
            if pi[k] == p:
                fx -= pair_res[k, PR_FX]
                fy -= pair_res[k, PR_FX + 1]
                fz -= pair_res[k, PR_FX + 2]
                tx += pair_res[k, PR_TI]
                ty += pair_res[k, PR_TI + 1]
                tz += pair_res[k, PR_TI + 2]
            else:
                fx += pair_res[k, PR_FX]
                fy += pair_res[k, PR_FX + 1]
                fz += pair_res[k, PR_FX + 2]
                tx += pair_res[k, PR_TJ]
                ty += pair_res[k, PR_TJ + 1]
                tz += pair_res[k, PR_TJ + 2]
            for h in range(HIST_LEN):
                new_hist_val[u, h] = pair_res[k, PR_HIST + h]
        force[p, 0] = fx
        force[p, 1] = fy
        force[p, 2] = fz
        torque[p, 0] = tx
        torque[p, 1] = ty
        torque[p, 2] = tz


@njit(cache=True)
def wall_range(p0, p1, wall_m, wall_d, pos, vel, omega, rot, axes, rbound, shape, mass, material,
               estar_w, gstar_w, zeta_w, mu_w, wall_hist, dt, force, torque, oorg, orot, ax6):
    """Add planar-wall contacts of particles p0..p1-1 (walls in fixed order), updating each
    particle's per-wall history. Wall planes: m.x = d with m the unit normal into the domain.
    Body 1 is the particle, body 2 the (fixed) wall; the normal from particle into wall is -m.
    Poly-ellipsoids use their octant geometry oorg, orot, ax6 (derive_geometry_range; empty
    arrays in a scene without them).
    Returns (number of wall contacts, largest depth ratio = depth over the smallest semi-axis,
    local index of the particle with it or -1)."""
    out = np.zeros(OUT_LEN)
    worst = 0.0
    worst_p = -1
    touching = 0
    for p in range(p0, p1):
        for w in range(wall_m.shape[0]):
            mx, my, mz = wall_m[w, 0], wall_m[w, 1], wall_m[w, 2]
            dist = mx * pos[p, 0] + my * pos[p, 1] + mz * pos[p, 2] - wall_d[w]
            if dist >= rbound[p]:
                wall_hist[p, w, H_A] = 0.0
                continue
            if shape[p] == SPHERE:
                hit, depth, xcx, xcy, xcz, r_e = sphere_wall_contact(pos[p, 0], pos[p, 1], pos[p, 2], axes[p, 0],
                                                                     mx, my, mz, wall_d[w])
                kratio = 1.0
            elif shape[p] == POLY:
                hit = polyellipsoid_wall_contact(oorg[p], orot[p], ax6[p], wall_m[w], wall_d[w], out) == 1
                depth = out[OUT_DEPTH]
                xcx, xcy, xcz = out[OUT_XCX], out[OUT_XCY], out[OUT_XCZ]
                r_e = out[OUT_RE]
                kratio = out[OUT_KRATIO]
            else:
                hit = ellipsoid_wall_contact(pos[p], rot[p], axes[p], wall_m[w], wall_d[w], out) == 1
                depth = out[OUT_DEPTH]
                xcx, xcy, xcz = out[OUT_XCX], out[OUT_XCY], out[OUT_XCZ]
                r_e = out[OUT_RE]
                kratio = out[OUT_KRATIO]
            if not hit:
                wall_hist[p, w, H_A] = 0.0
                continue
            r1x, r1y, r1z = xcx - pos[p, 0], xcy - pos[p, 1], xcz - pos[p, 2]
            vrx = -vel[p, 0] - (omega[p, 1] * r1z - omega[p, 2] * r1y)
            vry = -vel[p, 1] - (omega[p, 2] * r1x - omega[p, 0] * r1z)
            vrz = -vel[p, 2] - (omega[p, 0] * r1y - omega[p, 1] * r1x)
            a = material[p]
            f = contact_force(depth, -mx, -my, -mz, r_e, kratio, r1x, r1y, r1z, 0.0, 0.0, 0.0, vrx, vry, vrz,
                              mass[p], estar_w[a], gstar_w[a], zeta_w[a], mu_w[a],
                              wall_hist[p, w, H_FT], wall_hist[p, w, H_FT + 1], wall_hist[p, w, H_FT + 2],
                              wall_hist[p, w, H_A], wall_hist[p, w, H_A] > 0.0, dt)
            force[p, 0] -= f[0]
            force[p, 1] -= f[1]
            force[p, 2] -= f[2]
            torque[p, 0] += f[3]
            torque[p, 1] += f[4]
            torque[p, 2] += f[5]
            wall_hist[p, w, H_FT] = f[9]
            wall_hist[p, w, H_FT + 1] = f[10]
            wall_hist[p, w, H_FT + 2] = f[11]
            wall_hist[p, w, H_A] = f[12]
            amin = min(axes[p, 0], min(axes[p, 1], axes[p, 2]))
            if shape[p] == POLY:
                for c in range(6):
                    amin = min(amin, ax6[p, c])
            ratio = depth / amin
            if ratio > worst:
                worst = ratio
                worst_p = p
            touching += 1
    return touching, worst, worst_p
