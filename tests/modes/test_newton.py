"""modes/newton.py without MPI: the layout of a pair list for Newton's third law across ranks, and
the pack and unpack of the terms that travel back (the exchange itself runs in test_mpi.py)."""
import numpy as np

from dem.forces import PF_F, PF_LEN, PF_TI, PF_TJ
from modes.decomposition import OPPOSITE
from modes.newton import LOCAL, TERMS, cross_layout, pack_sent, resolver_end, unpack_received


def _layout(gids_owned, gids_ghost, ghost_dir, gid_pairs):
    """One rank's view: local ids owned then ghosts; its gid-sorted list of the given gid pairs."""
    gid = np.array(gids_owned + gids_ghost)
    where = {g: k for k, g in enumerate(gid)}
    pairs = sorted(p for p in gid_pairs if p[0] in where and p[1] in where
                   and (where[p[0]] < len(gids_owned) or where[p[1]] < len(gids_owned)))
    pi = np.array([where[a] for a, _ in pairs])
    pj = np.array([where[b] for _, b in pairs])
    perm, sent, received = cross_layout(pi, pj, gid, len(gids_owned), np.array(ghost_dir))
    listed = [(int(gid[pi[k]]), int(gid[pj[k]])) for k in perm]
    ms, mr = int(sent.sum()), int(received.sum())
    return listed[:ms], listed[ms:ms + mr], listed[ms + mr:], sent, received


def test_cross_layout_two_ranks_agree_and_each_pair_is_resolved_once():
    """Rank A owns gids 0-3 and holds 10, 11 as ghosts (owned by B, in direction 3 of A); B owns
    10-12 and holds 1, 3 (from direction OPPOSITE[3]). The cross pairs (1,10), (3,10), (3,11), (1,11)
    are each resolved by exactly one rank: what A sends, B receives in the same order and vice
    versa; the local pairs stay in gid order after the cross ones."""
    pairs = [(0, 1), (1, 10), (1, 11), (2, 3), (3, 10), (3, 11), (10, 11), (11, 12)]
    cross = [(1, 10), (1, 11), (3, 10), (3, 11)]
    a_sent, a_recv, a_local, a_s, a_r = _layout([0, 1, 2, 3], [10, 11], [3, 3], pairs)
    b_sent, b_recv, b_local, b_s, b_r = _layout([10, 11, 12], [1, 3], [OPPOSITE[3]] * 2, pairs)
    assert a_local == [(0, 1), (2, 3)] and b_local == [(10, 11), (11, 12)]
    assert a_sent == b_recv and b_sent == a_recv
    assert sorted(a_sent + b_sent) == cross
    assert a_s[3] == len(a_sent) and a_r[3] == len(a_recv) and a_s.sum() + a_r.sum() == 4
    assert b_s[OPPOSITE[3]] == len(b_sent) and len(a_s) == LOCAL == 26
    # which rank: the i end's owner where resolver_end is 0 (A owns every i end here)
    assert a_sent == [p for p in cross if resolver_end(p[0], p[1]) == 0]


def test_resolver_splits_pairs_evenly_however_numbered():
    """Lattice numbering puts a pair's two gids a fixed stride apart (1 along the numbering's fast
    axis, 100 or 10000 along the others); the owner of the lower gid would take every such pair on
    one side of a border. splitmix64's lowest bit is equidistributed: over 100000 pairs per stride
    the share resolved by the j end is within 0.49-0.51 (6 binomial standard deviations, 0.0016)."""
    g = np.arange(100000)
    for stride in (1, 100, 10000):
        share = resolver_end(g, g + stride).mean()
        assert 0.49 < share < 0.51, (stride, share)


def test_terms_pack_and_unpack_exactly():
    """The pair force, the ghost end's torque (T_j where j is the ghost, T_i where i is) and the
    touching flag of each sent pair arrive bit for bit in the receiver's pair records, the torque
    in its own end's slot; packing also zeroes the owned particles' force and torque sums (and only
    theirs) for the local pairs. Sender: owned 0-3, ghosts 4, 5; receiver: owned 0-1, ghosts 2-6."""
    rng = np.random.default_rng(5)
    pf = rng.normal(size=(5, PF_LEN))
    on = np.array([1, 0, 1, 1, 0], dtype=np.int8)
    pi = np.array([0, 4, 1, 2, 3])   # pair 1: i is the ghost
    pj = np.array([4, 2, 5, 3, 0])
    buf = np.zeros((3, TERMS))
    force = rng.normal(size=(6, 3))
    torque = rng.normal(size=(6, 3))
    ghost_rows = force[4:].copy(), torque[4:].copy()
    pack_sent(pi, pj, pf, on, 3, buf, force, torque, 4)
    assert np.all(force[:4] == 0.0) and np.all(torque[:4] == 0.0)
    assert np.array_equal(force[4:], ghost_rows[0]) and np.array_equal(torque[4:], ghost_rows[1])
    assert np.array_equal(buf[:, 3:6], pf[[0, 1, 2]][:, [6, 7, 8]] * [[1], [0], [1]]
                          + pf[[0, 1, 2]][:, [3, 4, 5]] * [[0], [1], [0]])
    # on the receiving rank the same pairs are (ghost i, owned j), (owned i, ghost j), (ghost i, owned j)
    got = np.full((7, PF_LEN), 9.0)
    got_on = np.zeros(7, dtype=np.int8)
    rpi = np.array([0, 0, 5, 1, 6, 0, 0])
    unpack_received(buf, 2, rpi, 2, got, got_on)
    assert np.array_equal(got[2:5, PF_F:PF_F + 3], pf[:3, PF_F:PF_F + 3])
    assert np.array_equal(got[2, PF_TJ:PF_TJ + 3], pf[0, PF_TJ:PF_TJ + 3]) and np.all(got[2, PF_TI:PF_TI + 3] == 9.0)
    assert np.array_equal(got[3, PF_TI:PF_TI + 3], pf[1, PF_TI:PF_TI + 3]) and np.all(got[3, PF_TJ:PF_TJ + 3] == 9.0)
    assert np.array_equal(got[4, PF_TJ:PF_TJ + 3], pf[2, PF_TJ:PF_TJ + 3]) and np.all(got[4, PF_TI:PF_TI + 3] == 9.0)
    assert np.all(got[[0, 1, 5, 6]] == 9.0)
    assert got_on.tolist() == [0, 0, 1, 0, 1, 0, 0]
