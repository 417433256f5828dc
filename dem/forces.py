"""Contact forces: per-pair resolution into the pair list, deterministic per-particle finish.

The pair list (dem.pairs, kept between neighbour rebuilds) holds each candidate pair (i, j),
gid[i] < gid[j], once, with its contact history hist [m, HIST_LEN] (tangential spring, contact
radius, PW warm start: dem.state H_*) and on [m] (int8: the pair touched at its last resolution,
so its history is valid). Resolution reads a pair's history and overwrites it in place: a pair
is resolved by exactly one thread, and nothing else reads its record meanwhile. Where pairs are
resolved concurrently (threads) it writes the pair's forces into pf [m, PF_LEN], in pair order (a
sequential stream: scattering them to the two ends' rows was measured 3x dearer on a 10k sphere
bed, the stores missing the cache); one thread over gid-sorted pairs adds them to the two ends
as it goes instead, and stores no per-pair force (resolve_range, deliver = SUM). Threads over
contiguous ranges of the gid-sorted list (deliver = SPLIT) do the same for every particle whose
pairs all lie in one range, and store pf only for the pairs of the others (gat [n_owned] = 1),
which gather: a range's thread is then the only writer of its particles' sums, and each sum
still receives its terms in ascending partner gid.

Determinism (DESIGN.md): particle p then sums its pair contributions in ascending partner gid
(the adjacency of dem.pairs, sorted once per rebuild), then its walls in wall order. The result
is independent of how pairs were found, of the memory order and of which thread computed them,
so every mode is bit-identical to serial.

The loop kernels are compiled without numba's reference counting (_nrt=False): they allocate
nothing, and the counts that inlined helpers taking arrays would add (an atomic increment and
decrement per array per call) were measured to cost as much as the physics (a 10k sphere bed:
resolution 1.9x faster without them). A kernel they call that allocates (the sextic method)
asks for the runtime explicitly (_nrt=True).

The kernels' arrays travel in plain tuples grouped by what they describe, unpacked in each
kernel's first lines (a plain tuple unboxes as fast as separate arguments; a namedtuple was
measured 3x dearer per call, 4 us for 14 arrays, which a 48-particle step cannot afford):

- bodies  (pos, vel [n,3] [m, m/s], quat [n,4], angmom [n,3] [kg m^2/s], mass [n] [kg],
          inertia [n,3] [kg m^2], shape [n], axes [n,3] [m], rbound [n] [m], material [n],
          force, torque [n,3] [N, N m], rot [n,3,3], omega [n,3] [rad/s]): body_arrays
- polys   (poly [n, P_LEN], oorg [n,3], orot [n,3,3], ax6 [n,6]): the octant geometry of a scene
          with poly-ellipsoids (dem.integrate.derive_poly_geometry), empty arrays elsewhere
- law     (estar, gstar [n_mat, n_mat] [Pa], mu, zeta [n_mat, n_mat]): law_tables
- walls   (wall_m [w,3], wall_d [w] [m], estar_w, gstar_w, zeta_w, mu_w [n_mat],
          wall_hist [n, w, HIST_LEN]): wall_arrays
- plist   (pi, pj [m], hist [m, HIST_LEN], on [m] int8, pf [m, PF_LEN]): the pair list
          (dem.pairs.PairList.arrays)
- adj     (adj_start [n_owned+1], adj_items, on, pf, near [n_owned] int8, gat [n_owned] int8 or
          empty): each particle's pairs
          (dem.pairs.PairList.gather_arrays)
- gravity (gx, gy, gz [m/s^2], has_gravity)
"""
import math
import numpy as np
from numba import njit

# ellipsoid contact methods (dem.contact.CONTACT_METHODS): EXACT, PW, SEXTIC, the `method` argument
from dem.contact import EXACT, PW, SEXTIC  # noqa: F401 (the kernels' callers name them here)
from dem.contact.ellipsoid import (OUT_DEPTH, OUT_NX, OUT_XCX, OUT_LEN, solved_geometry)
from dem.contact.hertz_factor import hertz_factor
from dem.contact.law import hertz_mindlin
from dem.contact.sphere import sphere_contact
from dem.integrate import derive_particle, derive_poly_geometry, integrate_particle
from dem.shapes import POLY, SPHERE
from dem.shapes.dispatch import by_shape
from dem.state import H_FT, H_A, H_LAM, H_N

# a pair's forces: pf [m, PF_LEN]
PF_F = 0       # force on j [3] [N] (i gets the exact negation)
PF_TI = 3      # torque on i about its mass centre [3] [N m]
PF_TJ = 6      # torque on j [3] [N m]
PF_LEN = 9
# a cross-border pair's terms under TAKEN: pair force [3] (on j; i takes its negation), torque on the
# owned end [3], touching flag
TERMS = 7

# how a resolution hands on the pair forces (the `deliver` argument): STORE every pair's into pf
# (each particle gathers them), SUM them into the ends' force and torque as it goes (one thread,
# pairs sorted by gid), SPLIT: SUM for the particles with gat[p] == 0, STORE for the pairs that
# touch one with gat[p] == 1 (threads over ranges of the gid-sorted list: modes.parallel); TAKEN:
# SUM, but a pair with a ghost end is not resolved: its terms are already known (MPI with Newton's
# third law: resolved beforehand by this rank or received from the ghost's owner, modes.newton),
# one row each of the `terms` argument in the order the pairs come in the list, and are added to
# the owned end in the pair's place in the sequence; SPLIT_TAKEN: SPLIT with the cross pairs taken
# as TAKEN takes them (hybrid with Newton), their terms stored into pf for an end that gathers
STORE, SUM, SPLIT, TAKEN, SPLIT_TAKEN = 0, 1, 2, 3, 4

# what resolve_range returns, in this order
RESOLVED = ("n_contacts", "ellipsoid_calls", "worst_ratio", "worst_pair", "ratio_sum")
# what finish_range returns, in this order
FINISHED = ("n_wall_contacts", "wall_worst_ratio", "wall_worst_particle", "kinetic_energy", "gravity_work",
            "n_bad", "first_bad", "max_disp2")


def scene_kind(shape, has_poly):
    """The scene's kind, which picks its pair loop and its ghost record (a scene pays only for the
    solvers its shapes use): the most general shape code it holds (the registry orders the codes
    so), at least POLY in a scene with the poly record."""
    kind = int(shape.max()) if len(shape) else SPHERE
    return max(kind, POLY) if has_poly else kind


def body_arrays(state, rot, omega):
    """The bodies group of a State and its derived rot [n,3,3], omega [n,3]."""
    s = state
    return (s.pos, s.vel, s.quat, s.angmom, s.mass, s.inertia, s.shape, s.axes, s.rbound, s.material, s.force,
            s.torque, rot, omega)


def law_tables(materials):
    """The law group of dem.materials.Materials: the pair tables."""
    m = materials
    return m.estar, m.gstar, m.mu, m.zeta


def wall_arrays(wall_m, wall_d, materials, wall_hist):
    """The walls group: planes, the particle-wall law of each material, per-wall history."""
    m = materials
    return wall_m, wall_d, m.estar_w, m.gstar_w, m.zeta_w, m.mu_w, wall_hist


@njit(cache=True, inline="always")
def contact_force(depth, nx, ny, nz, ux, uy, uz, iu2, r_e, kratio, r1x, r1y, r1z, r2x, r2y, r2z, vrx, vry, vrz,
                  mstar, estar, gstar, zeta, mu, ox, oy, oz, a_old, has_hist, dt):
    """Hertz-Mindlin on one resolved contact (all scalars: numba row views cost atomic refcounts).

    n = (nx, ny, nz) unit normal from body 1 to body 2, u = (ux, uy, uz) the same direction as the
    caller found it before normalising, n = u/|u|, iu2 = 1/|u|^2 [1/unit^2] (two spheres: the
    centre line and its inverse squared length; n itself and 1.0 elsewhere); r1, r2 lever arms
    from the mass centres to the contact point [m]; vr = relative velocity of body 2 w.r.t. body 1
    at the contact point [m/s]; (ox, oy, oz, a_old) the stored spring [N] and contact radius [m]
    when has_hist.
    The stored spring o is rotated into the new tangent plane by projection and rescaled to its
    old magnitude (contact-mechanics.md §3.2 step 1), in terms of u:
        F_s = s (o - c u),  c = (o.u) iu2,  s^2 = |o|^2 / (|o|^2 - c (o.u))
    (|o - (o.n) n|^2 = |o|^2 - (o.n)^2). Written on u rather than n, the rotation does not wait for
    the root and division that make n, a chain that set the time of a sphere contact (the settled
    bed of `bench peer lammps`, resolution alone: 15 % faster with the rotation's root and
    division left out, 9-10 % faster on u than on n).
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
            du = ox * ux + oy * uy + oz * uz
            c = du * iu2
            ftx, fty, ftz = ox - c * ux, oy - c * uy, oz - c * uz
            new2 = old2 - c * du  # |o - c u|^2
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
def _store_spring(hist, k, f):
    """Write the spring and contact radius of contact_force's tuple f to hist[k] (a pair's list row,
    or a particle's row of one wall)."""
    hist[k, H_FT] = f[9]
    hist[k, H_FT + 1] = f[10]
    hist[k, H_FT + 2] = f[11]
    hist[k, H_A] = f[12]


@njit(cache=True, inline="always")
def contact_law(geo, r1x, r1y, r1z, r2x, r2y, r2z, vrx, vry, vrz, mstar, estar, gstar, zeta, mu, hist, k, has_hist,
                dt):
    """The one contact law of pairs and walls: contact_force on the resolved geometry geo (a contact
    record: depth [m], unit normal from body 1 to body 2 [3], the normal unnormalised u [3] and iu2 =
    1/|u|^2 (contact_force), contact point [3] [m], R_e [m], kappa ratio, PW lambda), lever arms
    r1, r2 [m], relative velocity vr [m/s], reduced mass mstar [kg] and the material's E*, G* [Pa],
    zeta, mu; the stored spring and contact radius are read from hist[k] (valid when has_hist) and
    the new ones written back. Returns contact_force's tuple."""
    depth, nx, ny, nz, ux, uy, uz, iu2, _, _, _, r_e, kratio, _ = geo
    f = contact_force(depth, nx, ny, nz, ux, uy, uz, iu2, r_e, kratio, r1x, r1y, r1z, r2x, r2y, r2z, vrx, vry, vrz,
                      mstar, estar, gstar, zeta, mu, hist[k, H_FT], hist[k, H_FT + 1], hist[k, H_FT + 2], hist[k, H_A],
                      has_hist, dt)
    _store_spring(hist, k, f)
    return f


@njit(cache=True, inline="always")
def _deliver(k, i, j, f, sums):
    """Hand the forces of touching pair k (contact_force's tuple f) on: sums = (deliver, pf,
    force, torque, n_owned, gat). SUM (one thread, pairs in gid order: see resolve_range) adds
    them to the owned ends, force[i] -= F, torque[i] += T_i, force[j] += F, torque[j] += T_j, and
    writes nothing per pair; STORE writes them to pf[k] for the gather (finish_range); SPLIT adds
    them to the owned ends with gat == 0 and stores them when an owned end has gat == 1; TAKEN sums
    as SUM does, SPLIT_TAKEN as SPLIT."""
    deliver, pf, force, torque, n_owned, gat = sums
    if deliver == SUM or deliver == TAKEN:
        sum_i, sum_j, store = i < n_owned, j < n_owned, False
    elif deliver == SPLIT or deliver == SPLIT_TAKEN:
        gi = i < n_owned and gat[i] != 0
        gj = j < n_owned and gat[j] != 0
        sum_i, sum_j, store = i < n_owned and not gi, j < n_owned and not gj, gi or gj
    else:
        sum_i, sum_j, store = False, False, True
    if sum_i:
        force[i, 0] -= f[0]
        force[i, 1] -= f[1]
        force[i, 2] -= f[2]
        torque[i, 0] += f[3]
        torque[i, 1] += f[4]
        torque[i, 2] += f[5]
    if sum_j:
        force[j, 0] += f[0]
        force[j, 1] += f[1]
        force[j, 2] += f[2]
        torque[j, 0] += f[6]
        torque[j, 1] += f[7]
        torque[j, 2] += f[8]
    if not store:
        return
    pf[k, PF_F] = f[0]
    pf[k, PF_F + 1] = f[1]
    pf[k, PF_F + 2] = f[2]
    pf[k, PF_TI] = f[3]
    pf[k, PF_TI + 1] = f[4]
    pf[k, PF_TI + 2] = f[5]
    pf[k, PF_TJ] = f[6]
    pf[k, PF_TJ + 1] = f[7]
    pf[k, PF_TJ + 2] = f[8]


@njit(cache=True, inline="always")
def _take_terms(c, k, i, j, terms, on, sums):
    """TAKEN, SPLIT_TAKEN: deliver row c of terms [cross pairs, 7] = (pair force [3] [N], torque on
    the owned end [3] [N m], touching flag; modes.newton.TERMS) of the cross-border pair k = (i, j)
    to its owned end as SUM or SPLIT would have delivered it when resolving it: added to its force
    and torque, or, under SPLIT_TAKEN for an end that gathers (gat == 1), written to pf[k] and
    on[k] for the gather (nothing when it does not touch); returns -1 (the pair is counted where
    it was resolved)."""
    deliver, pf, force, torque, n_owned, gat = sums
    p = i if i < n_owned else j
    if deliver == SPLIT_TAKEN and gat[p] != 0:
        on[k] = 1 if terms[c, 6] != 0.0 else 0
        t = PF_TI if p == i else PF_TJ
        for d in range(3):
            pf[k, PF_F + d] = terms[c, d]
            pf[k, t + d] = terms[c, 3 + d]
        return -1.0
    if terms[c, 6] == 0.0:
        return -1.0
    if p == i:
        force[i, 0] -= terms[c, 0]
        force[i, 1] -= terms[c, 1]
        force[i, 2] -= terms[c, 2]
    else:
        force[j, 0] += terms[c, 0]
        force[j, 1] += terms[c, 1]
        force[j, 2] += terms[c, 2]
    torque[p, 0] += terms[c, 3]
    torque[p, 1] += terms[c, 4]
    torque[p, 2] += terms[c, 5]
    return -1.0


@njit(cache=True, inline="always")
def pair_law(k, i, j, geo, bodies, law, plist, dt, sums):
    """contact_law for particles i -> j of pair k, on the resolved geometry geo (contact_law's
    record); the old history is read from and the new one written to hist[k] (it is valid when
    on[k] == 1), with the warm start of the pair's next resolution (PW lambda, normal); the forces
    handed on by _deliver (sums)."""
    pos, vel, _, _, mass, _, _, _, _, material, _, _, _, omega = bodies
    estar, gstar, mu, zeta = law
    _, _, hist, on, _ = plist
    nx, ny, nz, xcx, xcy, xcz, lam = geo[1], geo[2], geo[3], geo[8], geo[9], geo[10], geo[13]
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
    f = contact_law(geo, r1x, r1y, r1z, r2x, r2y, r2z, vrx, vry, vrz, mi * mj / (mi + mj), estar[a, b], gstar[a, b],
                    zeta[a, b], mu[a, b], hist, k, on[k] == 1, dt)
    hist[k, H_LAM] = lam
    hist[k, H_N] = nx
    hist[k, H_N + 1] = ny
    hist[k, H_N + 2] = nz
    _deliver(k, i, j, f, sums)


@njit(cache=True, inline="always")
def _warm_start(hist, k, has_hist, n0):
    """Stored PW lambda (or -1) of pair k's history, its normal into n0 [3]."""
    if not has_hist:
        n0[0] = n0[1] = n0[2] = 0.0
        return -1.0
    # the stored normal points i -> j (canonical order)
    n0[0] = hist[k, H_N]
    n0[1] = hist[k, H_N + 1]
    n0[2] = hist[k, H_N + 2]
    return hist[k, H_LAM]


@njit(cache=True, inline="always")
def _apart(i, j, pos, rbound):
    """True when the bounding spheres of i and j do not overlap: the candidate search's own test
    (dem.neighbor.scan_rows), so a pair kept only by the skin never reaches a solver."""
    dx = pos[j, 0] - pos[i, 0]
    dy = pos[j, 1] - pos[i, 1]
    dz = pos[j, 2] - pos[i, 2]
    rr = rbound[i] + rbound[j]
    return not (dx * dx + dy * dy + dz * dz < rr * rr)


@njit(cache=True, inline="always")
def _sphere_pair(k, i, j, bodies, law, plist, dt, sums):
    """Closed-form sphere-sphere contact and law for pair k = (i, j); returns the depth ratio (depth
    over the smaller radius) or -1 when apart."""
    pos = bodies[0]
    axes = bodies[7]
    on = plist[3]
    hit, depth, nx, ny, nz, xcx, xcy, xcz, r_e = sphere_contact(
        pos[i, 0], pos[i, 1], pos[i, 2], axes[i, 0], pos[j, 0], pos[j, 1], pos[j, 2], axes[j, 0])
    if not hit:
        on[k] = 0
        return -1.0
    # the centre line u as sphere_contact found it, n = u/|u|, for the spring's rotation: its
    # reciprocal square length does not wait for n's root and division
    ux, uy, uz = pos[j, 0] - pos[i, 0], pos[j, 1] - pos[i, 1], pos[j, 2] - pos[i, 2]
    u2 = ux * ux + uy * uy + uz * uz
    if u2 == 0.0:  # coincident centres: sphere_contact's fixed normal
        ux, uy, uz, iu2 = nx, ny, nz, 1.0
    else:
        iu2 = 1.0 / u2
    pair_law(k, i, j, (depth, nx, ny, nz, ux, uy, uz, iu2, xcx, xcy, xcz, r_e, 1.0, 0.0), bodies, law, plist, dt,
             sums)
    on[k] = 1
    return depth / min(axes[i, 0], axes[j, 0])


@njit(cache=True, inline="always")
def _solved_pair(hit, k, i, j, out, amin_i, amin_j, bodies, law, plist, dt, sums):
    """After a solver filled out [OUT_LEN] (hit = 1) or found no contact: apply the law to pair k and
    return the depth over the smaller of the smallest semi-axes amin_i, amin_j [m] (-1 when apart)."""
    on = plist[3]
    if hit == 0:
        on[k] = 0
        return -1.0
    geo = solved_geometry(out)
    pair_law(k, i, j, geo, bodies, law, plist, dt, sums)
    on[k] = 1
    return geo[0] / min(amin_i, amin_j)


pair_geometry = by_shape(
    "pair_geometry", "i, j, pos, rot, axes, shape, method, polys, lam0, n0, out", "max(shape[i], shape[j])",
    """The contact geometry of the pair (i, j): the kernel of the pair's most general shape (the
    codes are ordered so, each shape's kernels handling the shapes before it), built from the
    registered shapes (dem.shapes.dispatch): two spheres in closed form (dem.shapes.sphere), an
    ellipsoid by the method CONTACT_METHODS[method] (warm start lam0, n0 [3]; lam0 < 0 and n0 = 0:
    none) (dem.shapes.ellipsoid), a poly-ellipsoid on either side by the octant active set on the
    octant geometry of polys (dem.shapes.polyellipsoid). The one shape dispatch of a pair, used by
    the step (resolve_range) and by `bench contacts` (pair_contacts). Fills out [OUT_LEN] (OUT_*
    layout: depth, normal from i to j, contact points, R_e, kappa ratio, lambda) on contact.
    Returns (hit, smallest semi-axis of i, of j [m], 1 when a solver ran).""")


@njit(cache=True)
def pair_contacts(pi, pj, pos, rot, axes, shape, method, polys, rows):
    """The contacts of candidate pairs (pi[k], pj[k]) without history (no warm start), through
    pair_geometry: rows [m, 8] = (hit, depth [m], normal i -> j [3], contact point [3] [m])."""
    out = np.zeros(OUT_LEN)
    n0 = np.zeros(3)
    for k in range(pi.shape[0]):
        n0[0] = n0[1] = n0[2] = 0.0
        hit, _, _, _ = pair_geometry(pi[k], pj[k], pos, rot, axes, shape, method, polys, -1.0, n0, out)
        rows[k, 0] = hit
        if hit:
            rows[k, 1] = out[OUT_DEPTH]
            for c in range(3):
                rows[k, 2 + c] = out[OUT_NX + c]
                rows[k, 5 + c] = out[OUT_XCX + c]


@njit(cache=True, _nrt=False)
def _resolve_spheres(k0, k1, plist, bodies, law, dt, deliver, n_owned, gat, terms):
    """The sphere loop: no solver in it, so a sphere scene neither runs nor carries one."""
    pi, pj, _, on, pf = plist
    taking = deliver == TAKEN or deliver == SPLIT_TAKEN
    sums = (deliver, pf, bodies[10], bodies[11], n_owned, gat)
    nc = 0
    worst = 0.0
    worst_k = -1
    rsum = 0.0
    c = 0
    for k in range(k0, k1):
        i = pi[k]
        j = pj[k]
        if taking and (i >= n_owned or j >= n_owned):
            r = _take_terms(c, k, i, j, terms, on, sums)
            c += 1
        else:
            r = _sphere_pair(k, i, j, bodies, law, plist, dt, sums)
        if r >= 0.0:
            nc += 1
            rsum += r
            if r > worst:
                worst = r
                worst_k = k
    return nc, 0, worst, worst_k, rsum


@njit(cache=True, _nrt=False)
def _resolve_ellipsoids(k0, k1, plist, bodies, polys, law, dt, method, deliver, n_owned, gat, terms, out, n0):
    """The loop of a scene with ellipsoids (and poly-ellipsoids): closed form for
    two spheres, the bounding-sphere test, then the solver of the pair's shapes."""
    pi, pj, hist, on, pf = plist
    pos, _, _, _, _, _, shape, axes, rbound, _, force, torque, rot, _ = bodies
    sums = (deliver, pf, force, torque, n_owned, gat)
    taking = deliver == TAKEN or deliver == SPLIT_TAKEN
    nc = 0
    calls = 0
    worst = 0.0
    worst_k = -1
    rsum = 0.0
    c = 0
    for k in range(k0, k1):
        i = pi[k]
        j = pj[k]
        if taking and (i >= n_owned or j >= n_owned):
            r = _take_terms(c, k, i, j, terms, on, sums)
            c += 1
        elif shape[i] == SPHERE and shape[j] == SPHERE:
            r = _sphere_pair(k, i, j, bodies, law, plist, dt, sums)
        elif _apart(i, j, pos, rbound):
            on[k] = 0
            r = -1.0
        else:
            lam0 = _warm_start(hist, k, on[k] == 1, n0)
            hit, ai, aj, solver = pair_geometry(i, j, pos, rot, axes, shape, method, polys, lam0, n0, out)
            calls += solver
            r = _solved_pair(hit, k, i, j, out, ai, aj, bodies, law, plist, dt, sums)
        if r >= 0.0:
            nc += 1
            rsum += r
            if r > worst:
                worst = r
                worst_k = k
    return nc, calls, worst, worst_k, rsum


@njit(cache=True, _nrt=False)
def resolve_range(kind, method, k0, k1, plist, bodies, polys, law, dt, deliver, n_owned, gat, terms, out, n0):
    """Resolve pairs k0..k1-1 of the pair list plist: geometry (closed form for two spheres;
    otherwise the ellipsoid method CONTACT_METHODS[method]: EXACT = PW + Newton on S^2, PW =
    Perram-Wertheim depth only, SEXTIC = Yan 2010; poly-ellipsoids by the octant active set on
    polys), then the contact law (law tables, time step dt [s]). Updates hist [m, HIST_LEN] and
    on [m] in place (on[k] = 1: touching; its history is valid) and writes the forces of the
    touching pairs into pf [m, PF_LEN] (deliver = STORE); SUM (one thread, pairs in ascending (gid_i, gid_j):
    dem.pairs.PairList.set(by_gid=True)) instead sums them into the bodies' force, torque [n, 3] of
    the owned particles 0..n_owned-1 as it goes (zeroed first), as LAMMPS does: in that order each
    particle receives its contributions in ascending partner gid, the order of the gather
    (finish_range), so both strategies give the same bits; it spares pf and the gather's second
    pass over the pairs. Threads whose pairs are resolved concurrently in any order STORE; threads over
    contiguous ranges of the sorted list SPLIT (see _deliver: gat [n_owned] int8 marks the particles
    with pairs in two ranges; the caller zeroes the others' force and torque). TAKEN (MPI with
    Newton's third law) is SUM with the pairs that have a ghost end not resolved but added from
    terms [c, 7], one row per such pair in list order, row 0 the first at or after k0
    (modes.newton: resolved beforehand by this rank, STORE, or received); SPLIT_TAKEN (hybrid with
    Newton) is SPLIT with them taken so (_take_terms); other modes pass an empty terms. kind (SPHERE,
    ELLIPSOID, POLY) picks the loop, so a scene pays only for the solvers its shapes use. out
    [OUT_LEN], n0 [3] are scratch. Returns RESOLVED: (contacts, solver calls, largest depth ratio
    = depth over the smaller minimum semi-axis, its pair or -1, sum of the depth ratios)."""
    if deliver == SUM or deliver == TAKEN:
        force, torque = bodies[10], bodies[11]
        for p in range(n_owned):
            for c in range(3):
                force[p, c] = 0.0
                torque[p, c] = 0.0
    if kind == SPHERE:
        return _resolve_spheres(k0, k1, plist, bodies, law, dt, deliver, n_owned, gat, terms)
    return _resolve_ellipsoids(k0, k1, plist, bodies, polys, law, dt, method, deliver, n_owned, gat, terms, out, n0)


wall_geometry = by_shape(
    "wall_geometry", "p, w, wall_m, wall_d, pos, rot, axes, shape, polys, out", "shape[p]",
    """The contact geometry of particle p with wall plane w (m.x = d, m the unit normal into the
    domain): the kernel of p's shape, built from the registered shapes (dem.shapes.dispatch): the
    one shape dispatch of a wall contact, as pair_geometry is a pair's. Body 1 is the particle,
    body 2 the wall: the normal from particle into wall is -m. A sphere in closed form; an
    ellipsoid by its support along -m; a poly-ellipsoid by that of its octant facing the wall, on
    the octant geometry of polys. out [OUT_LEN] is scratch. Returns (hit, contact_law's record,
    smallest semi-axis of p [m]).""")


@njit(cache=True, _nrt=False)
def _wall_particle(p, walls, bodies, polys, dt, out, fx, fy, fz, tx, ty, tz):
    """Planar-wall contacts of particle p (walls in fixed order) added to its force (fx, fy, fz) and
    torque (tx, ty, tz): wall_geometry, then the pairs' contact_law with the wall as a fixed body 2
    (no velocity, reduced mass the particle's), its spring and contact radius in the particle's
    per-wall history. Called only for a particle within reach of a wall, and not inlined: the wall
    solvers would crowd the per-particle loop. Returns (force [3], torque [3], wall contacts,
    largest depth ratio = depth over the smallest semi-axis)."""
    wall_m, wall_d, estar_w, gstar_w, zeta_w, mu_w, wall_hist = walls
    pos, vel, _, _, mass, _, shape, axes, rbound, material, _, _, rot, omega = bodies
    hist = wall_hist[p]
    worst = 0.0
    touching = 0
    for w in range(wall_m.shape[0]):
        dist = wall_m[w, 0] * pos[p, 0] + wall_m[w, 1] * pos[p, 1] + wall_m[w, 2] * pos[p, 2] - wall_d[w]
        if dist >= rbound[p]:
            hist[w, H_A] = 0.0
            continue
        hit, geo, amin = wall_geometry(p, w, wall_m, wall_d, pos, rot, axes, shape, polys, out)
        if not hit:
            hist[w, H_A] = 0.0
            continue
        r1x, r1y, r1z = geo[8] - pos[p, 0], geo[9] - pos[p, 1], geo[10] - pos[p, 2]
        vrx = -vel[p, 0] - (omega[p, 1] * r1z - omega[p, 2] * r1y)
        vry = -vel[p, 1] - (omega[p, 2] * r1x - omega[p, 0] * r1z)
        vrz = -vel[p, 2] - (omega[p, 0] * r1y - omega[p, 1] * r1x)
        a = material[p]
        f = contact_law(geo, r1x, r1y, r1z, 0.0, 0.0, 0.0, vrx, vry, vrz, mass[p], estar_w[a], gstar_w[a], zeta_w[a],
                        mu_w[a], hist, w, hist[w, H_A] > 0.0, dt)
        fx -= f[0]
        fy -= f[1]
        fz -= f[2]
        tx += f[3]
        ty += f[4]
        tz += f[5]
        worst = max(worst, geo[0] / amin)
        touching += 1
    return fx, fy, fz, tx, ty, tz, touching, worst


@njit(cache=True, inline="always")
def _wall_pass_due(p, walls, pos, rbound):
    """Whether particle p of the wall list needs _wall_particle this step: some wall plane is closer
    than its bounding radius, or some wall history is still open (the pass would close it). A
    pass that is not due would change nothing, and a call passes the groups by value."""
    wall_m, wall_d, _, _, _, _, wall_hist = walls
    for w in range(wall_m.shape[0]):
        if (wall_m[w, 0] * pos[p, 0] + wall_m[w, 1] * pos[p, 1] + wall_m[w, 2] * pos[p, 2] - wall_d[w] < rbound[p]
                or wall_hist[p, w, H_A] != 0.0):
            return True
    return False


@njit(cache=True, inline="always")
def _gather(p, adj_start, adj_items, on, pf):
    """Force and torque on particle p from its touching pairs, summed in ascending partner gid
    (adj_items = 2 k + (1 if p is pair k's j end)). Branch-free: a pair that does not touch adds
    +-0.0, which leaves a sum that starts at +0.0 unchanged, and the end selects the sign of the
    force and which torque (a branch on either mispredicts at random: measured 2x on a sphere bed)."""
    fx = fy = fz = 0.0
    tx = ty = tz = 0.0
    for u in range(adj_start[p], adj_start[p + 1]):
        e = adj_items[u]
        k = e >> 1
        j_end = e & 1
        w = float(on[k])
        sf = w * (2.0 * j_end - 1.0)     # +1 at the j end, -1 at the i end, 0 when apart
        c = PF_TI + 3 * j_end
        fx += sf * pf[k, PF_F]
        fy += sf * pf[k, PF_F + 1]
        fz += sf * pf[k, PF_F + 2]
        tx += w * pf[k, c]
        ty += w * pf[k, c + 1]
        tz += w * pf[k, c + 2]
    return fx, fy, fz, tx, ty, tz


@njit(cache=True, _nrt=False)
def wall_candidates(n_owned, pos, reach, wall_m, wall_d, wall_hist, near, was):
    """The wall list of a neighbour rebuild: near[p] = 1 for the owned particles within reach[p] (the
    bounding radius plus half the skin [m]) of some wall plane, 0 for the others, whose wall
    history ends here: they cannot touch a wall before the next rebuild. was [n_owned] int8: the
    last rebuild's list of the same particles, or empty where there is none (a first list, or
    the particles were stored anew since). Returns the count of the list.

    Only a particle on the last list can hold an open wall history (H_A != 0): the wall pass
    (finish_range) reads and writes the histories of listed particles only, and each list closes
    those of every particle it leaves out. So where was is given, only the particles it lists and
    this one does not are closed; the others' histories are not read. Closing every unlisted
    particle's wrote a cache line per particle and wall (wall_hist [n, walls, HIST_LEN])."""
    return wall_candidates_range(0, n_owned, pos, reach, wall_m, wall_d, wall_hist, near, was)


@njit(cache=True)
def wall_candidates_range(p0, p1, pos, reach, wall_m, wall_d, wall_hist, near, was):
    """wall_candidates for the owned particles p0..p1-1 (threads take blocks of them:
    modes.parallel.wall_threads); returns their count on the list."""
    every = was.shape[0] == 0
    count = 0
    for p in range(p0, p1):
        hit = 0
        for w in range(wall_m.shape[0]):
            if wall_m[w, 0] * pos[p, 0] + wall_m[w, 1] * pos[p, 1] + wall_m[w, 2] * pos[p, 2] - wall_d[w] < reach[p]:
                hit = 1
        near[p] = hit
        count += hit
        if hit == 0 and (every or was[p] != 0):
            for w in range(wall_m.shape[0]):
                wall_hist[p, w, H_A] = 0.0
    return count


@njit(cache=True, inline="always")
def _put(p, force, torque, fx, fy, fz, tx, ty, tz):
    force[p, 0] = fx
    force[p, 1] = fy
    force[p, 2] = fz
    torque[p, 0] = tx
    torque[p, 1] = ty
    torque[p, 2] = tz


@njit(cache=True, inline="always")
def _guard_terms(p, pos, vel, mass, omega, angmom, gx, gy, gz, dt, ref):
    """Particle p's share of the guard's sums: (kinetic energy m |v|^2/2 + omega.L/2 [J], gravity
    work dt m v.g [J], 1 if its position or velocity is not finite, squared displacement since
    ref[p] [m^2])."""
    vx, vy, vz = vel[p, 0], vel[p, 1], vel[p, 2]
    m = mass[p]
    ke = 0.5 * m * (vx * vx + vy * vy + vz * vz) + 0.5 * (
        omega[p, 0] * angmom[p, 0] + omega[p, 1] * angmom[p, 1] + omega[p, 2] * angmom[p, 2])
    wg = dt * m * (vx * gx + vy * gy + vz * gz)
    x, y, z = pos[p, 0], pos[p, 1], pos[p, 2]
    bad = 0 if (math.isfinite(x) and math.isfinite(y) and math.isfinite(z) and math.isfinite(vx)
                and math.isfinite(vy) and math.isfinite(vz)) else 1
    dx, dy, dz = x - ref[p, 0], y - ref[p, 1], z - ref[p, 2]
    return ke, wg, bad, dx * dx + dy * dy + dz * dz


@njit(cache=True, inline="always")
def _fold(acc, p, touching, worst, ke, wg, bad, d2):
    """Add particle p's results to the running FINISHED tuple acc."""
    n_wall, wall_worst, wall_p, ke_sum, wg_sum, n_bad, first_bad, disp2 = acc
    if worst > wall_worst:
        wall_worst = worst
        wall_p = p
    if bad and first_bad < 0:
        first_bad = p
    return (n_wall + touching, wall_worst, wall_p, ke_sum + ke, wg_sum + wg, n_bad + bad, first_bad,
            max(disp2, d2))


@njit(cache=True, inline="always")
def _finish_particle(p, spheres, gathered, adj, bodies, walls, polys, gravity, dt, poly_scene, ref, out, acc):
    """finish_range's work for particle p, folded into the running FINISHED tuple acc."""
    adj_start, adj_items, on, pf, near, gat = adj
    pos, vel, quat, angmom, mass, inertia, shape, axes, _, _, force, torque, rot, omega = bodies
    poly, oorg, orot, ax6 = polys
    gx, gy, gz, _ = gravity
    if gathered == SUM or (gathered == SPLIT and gat[p] == 0):
        fx, fy, fz = force[p, 0], force[p, 1], force[p, 2]
        tx, ty, tz = torque[p, 0], torque[p, 1], torque[p, 2]
    else:
        fx, fy, fz, tx, ty, tz = _gather(p, adj_start, adj_items, on, pf)
    touching, worst = 0, 0.0
    if near[p] and _wall_pass_due(p, walls, pos, bodies[8]):
        fx, fy, fz, tx, ty, tz, touching, worst = _wall_particle(p, walls, bodies, polys, dt, out,
                                                                 fx, fy, fz, tx, ty, tz)
    _put(p, force, torque, fx, fy, fz, tx, ty, tz)
    integrate_particle(p, bodies, gravity, dt, spheres)
    derive_particle(p, quat, angmom, inertia, shape, rot, omega, False, spheres)
    if poly_scene:
        derive_poly_geometry(p, pos, rot, axes, shape, poly, orot, oorg, ax6)
    ke, wg, bad, d2 = _guard_terms(p, pos, vel, mass, omega, angmom, gx, gy, gz, dt, ref)
    return _fold(acc, p, touching, worst, ke, wg, bad, d2)


@njit(cache=True, _nrt=False)
def finish_range(p0, p1, spheres, gathered, adj, bodies, walls, polys, gravity, dt, poly_scene, ref, out):
    """The rest of the step for owned particles p0..p1-1, one particle at a time:
    1. gather: sum the forces and torques of particle p's touching pairs in ascending partner gid
       (adj: adjacency adj_start [n_owned+1], adj_items = 2 k + (1 if p is pair k's j end)), or,
       or take force[p], torque[p] as resolve_range left them: gathered is the resolution's deliver
       (STORE: gather all; SUM: take all; SPLIT: gather those with gat[p] == 1, take the others);
    2. walls in wall order for the particles of the wall list near [n_owned] (wall_candidates, at
       each rebuild), giving force[p], torque[p];
    3. integration (dem.integrate: leapfrog, symplectic rotation, gravity [m/s^2] when it has one);
    4. the derived rotation matrix rot[p] and world angular velocity omega[p] of the new
       orientation (and the octant geometry of a poly-ellipsoid when poly_scene), so the next
       step's resolution finds them ready;
    5. the stability guard's sums: kinetic energy sum m |v|^2/2 + omega.L/2 [J], gravity work
       dt sum m v.g [J], non-finite positions or velocities, and the largest squared displacement
       since the reference positions ref [n_owned, 3] [m^2] (the neighbour list's rebuild test).
    spheres: a scene of spheres only (its loop is compiled without the ellipsoid rotation, which
    would otherwise crowd it: measured 2x on a sphere bed). out [OUT_LEN] is scratch
    (nothing is allocated). Returns FINISHED: (wall contacts, largest wall depth ratio, its
    particle or -1, kinetic energy, gravity work, number of non-finite particles, the first of
    them or -1, largest squared displacement)."""
    # the loop is written twice only so that `spheres` is a literal in each
    acc = (0, 0.0, -1, 0.0, 0.0, 0, -1, 0.0)
    if spheres:
        for p in range(p0, p1):
            acc = _finish_particle(p, True, gathered, adj, bodies, walls, polys, gravity, dt, False, ref, out, acc)
    else:
        for p in range(p0, p1):
            acc = _finish_particle(p, False, gathered, adj, bodies, walls, polys, gravity, dt, poly_scene, ref, out,
                                   acc)
    return acc
