"""The sums of the pair loop (dem.forces resolve_range): one thread summing as it resolves (SUM;
TAKEN, with the cross-border pairs' terms taken in their place) must give exactly the bits of
adding each touching pair's forces, in list order, to its owned ends: force[i] -= F, torque[i] +=
T_i, force[j] += F, torque[j] += T_j (DESIGN.md, Determinism: the gather of the thread schemes
does the same additions in the same order). These tests hold the sphere loop to that per-pair
reference on a sorted list, on a list in another order (rows broken and revisited), and under
TAKEN, where a term lands on the first end or on the second."""
import numpy as np
import pytest

from bench.run.prepare import load_prepared
from dem.forces import PF_F, PF_TI, PF_TJ, STORE, SUM, TAKEN, resolve_range
from dem.timestep import choose_time_step
from modes.serial import SerialMode


def _packed_spheres():
    """A stepped serial mode on 300 packed spheres: its pair list (sorted by gid), arrays and law."""
    sc = load_prepared("packed", particles=300, shape="sphere")
    mode = SerialMode().setup(sc, dt=choose_time_step(sc).dt)
    for _ in range(3):
        mode.step()
    return mode


def _resolve(mode, order, deliver, n_owned, terms, swap=None):
    """resolve_range over the list's pairs in `order` (swap [len(order)] bool: those pairs with
    their ends exchanged), on copies of the history; returns the list used (pi, pj, hist, on, pf),
    RESOLVED and the owned force and torque."""
    pi, pj, hist, on, pf = mode.plist
    a, b = pi[order].copy(), pj[order].copy()
    if swap is not None:
        a[swap], b[swap] = b[swap], a[swap].copy()
    m = len(order)
    plist = (a, b, hist[order].copy(), on[order].copy(), np.zeros((m, pf.shape[1])))
    s = mode.state
    s.force[:] = 0.0
    s.torque[:] = 0.0
    res = resolve_range(mode.kind, mode.method, 0, m, plist, mode.bodies, mode.polys, mode.law, mode.dt, deliver,
                        n_owned, np.zeros(s.n_owned, dtype=np.int8), terms, mode.out, mode.n0)
    return plist, res, s.force[:n_owned].copy(), s.torque[:n_owned].copy()


def _reference(plist, n_owned, n, terms=None):
    """Each touching pair's stored forces (STORE's pf) added in list order to its owned ends, and
    under TAKEN each cross pair's term row added to its owned end (modes.newton TERMS: F [3],
    torque on the owned end [3], touching flag)."""
    pi, pj, _, on, pf = plist
    force = np.zeros((n, 3))
    torque = np.zeros((n, 3))
    c = 0
    for k in range(len(pi)):
        i, j = pi[k], pj[k]
        if terms is not None and (i >= n_owned or j >= n_owned):
            if terms[c, 6] != 0.0:
                if i < n_owned:
                    force[i] -= terms[c, 0:3]
                    torque[i] += terms[c, 3:6]
                else:
                    force[j] += terms[c, 0:3]
                    torque[j] += terms[c, 3:6]
            c += 1
            continue
        if not on[k]:
            continue
        if i < n_owned:
            force[i] -= pf[k, PF_F:PF_F + 3]
            torque[i] += pf[k, PF_TI:PF_TI + 3]
        if j < n_owned:
            force[j] += pf[k, PF_F:PF_F + 3]
            torque[j] += pf[k, PF_TJ:PF_TJ + 3]
    return force[:n_owned], torque[:n_owned]


@pytest.mark.parametrize("shuffled", [False, True])
def test_sphere_sums_equal_the_per_pair_additions(shuffled):
    """SUM over 300 packed spheres' list (about 700 pairs), in its own gid order and shuffled: the
    owned force and torque equal the per-pair additions of STORE's forces in that order, bit for
    bit, and both resolutions count the same contacts."""
    mode = _packed_spheres()
    m, n = mode.pairs.m, mode.state.n
    order = np.random.default_rng(3).permutation(m) if shuffled else np.arange(m)
    stored, res_store, _, _ = _resolve(mode, order, STORE, n, mode.no_terms)
    summed, res_sum, force, torque = _resolve(mode, order, SUM, n, mode.no_terms)
    ref_f, ref_t = _reference(stored, n, n)
    assert res_sum[0] == res_store[0] > 100
    assert np.array_equal(summed[3], stored[3]) and np.array_equal(summed[2], stored[2])
    assert np.array_equal(force, ref_f) and np.array_equal(torque, ref_t) and np.abs(ref_f).sum() > 0


def test_sphere_sums_take_cross_terms_on_either_end():
    """TAKEN with the last 60 of 300 spheres as ghosts: every pair with a ghost end adds its term
    row instead of being resolved, to its first end where that one is owned (carried across the
    row) and to its second where the first is the ghost (half the cross pairs have their ends
    exchanged, as a rank's list holds them where the ghost has the lower gid); half the terms
    touching. The owned force and torque equal the per-pair reference in list order, bit for bit."""
    mode = _packed_spheres()
    m, n = mode.pairs.m, mode.state.n
    n_owned = n - 60
    pi, pj = mode.plist[0][:m], mode.plist[1][:m]
    cross = (pi >= n_owned) | (pj >= n_owned)
    both = (pi >= n_owned) & (pj >= n_owned)
    keep = np.flatnonzero(~both)  # no rank's list holds a ghost-ghost pair
    rng = np.random.default_rng(5)
    c = int(cross[keep].sum())
    terms = rng.standard_normal((c, 7))
    terms[:, 6] = rng.integers(0, 2, c)
    swap = cross[keep] & (rng.random(len(keep)) < 0.5)
    stored, _, _, _ = _resolve(mode, keep, STORE, n_owned, mode.no_terms, swap)
    first = stored[0][cross[keep]]
    assert (first < n_owned).any() and (first >= n_owned).any()
    _, _, force, torque = _resolve(mode, keep, TAKEN, n_owned, terms, swap)
    ref_f, ref_t = _reference(stored, n_owned, n, terms)
    assert np.array_equal(force, ref_f) and np.array_equal(torque, ref_t) and np.abs(ref_f).sum() > 0
