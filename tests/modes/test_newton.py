"""modes/newton.py without MPI: the layout of a pair list for Newton's third law across ranks, and
the pack and unpack of the terms that travel back (the exchange itself runs in test_mpi.py)."""
import numpy as np

from dem.forces import PF_F, PF_LEN, PF_TI, PF_TJ
from dem.state import HIST_LEN
from modes.decomposition import OPPOSITE
from modes.newton import NDIR, TERMS, cross_layout, pack_sent, resolver_end, unpack_received


def _layout(gids_owned, gids_ghost, ghost_dir, gid_pairs):
    """One rank's view: local ids owned then ghosts, its gid-sorted list of the given gid pairs;
    returns the gid pairs it sends and receives and the per-direction counts."""
    gid = np.array(gids_owned + gids_ghost)
    where = {g: k for k, g in enumerate(gid)}
    pairs = sorted(p for p in gid_pairs if p[0] in where and p[1] in where
                   and (where[p[0]] < len(gids_owned) or where[p[1]] < len(gids_owned)))
    pi = np.array([where[a] for a, _ in pairs])
    pj = np.array([where[b] for _, b in pairs])
    sent_idx, sent, recv_idx, received = cross_layout(pi, pj, gid, len(gids_owned), np.array(ghost_dir))
    as_gids = lambda idx: [(int(gid[pi[k]]), int(gid[pj[k]])) for k in idx]
    return as_gids(sent_idx), as_gids(recv_idx), sent, received


def test_cross_layout_two_ranks_agree_and_each_pair_is_resolved_once():
    """Rank A owns gids 0-3 and holds 10, 11 as ghosts (owned by B, in direction 3 of A); B owns
    10-12 and holds 1, 3 (from direction OPPOSITE[3]). The cross pairs (1,10), (1,11), (3,10),
    (3,11) are each resolved by exactly one rank: what A sends, B receives in the same order and
    vice versa; no local pair is listed."""
    pairs = [(0, 1), (1, 10), (1, 11), (2, 3), (3, 10), (3, 11), (10, 11), (11, 12)]
    cross = [(1, 10), (1, 11), (3, 10), (3, 11)]
    a_sent, a_recv, a_s, a_r = _layout([0, 1, 2, 3], [10, 11], [3, 3], pairs)
    b_sent, b_recv, b_s, b_r = _layout([10, 11, 12], [1, 3], [OPPOSITE[3]] * 2, pairs)
    assert a_sent == b_recv and b_sent == a_recv
    assert sorted(a_sent + b_sent) == cross
    assert a_s[3] == len(a_sent) and a_r[3] == len(a_recv) and a_s.sum() + a_r.sum() == 4
    assert b_s[OPPOSITE[3]] == len(b_sent) and b_r[OPPOSITE[3]] == len(b_recv) and len(a_s) == NDIR == 26
    # which rank: the i end's owner where resolver_end is 0 (A owns every i end here)
    assert a_sent == [p for p in cross if resolver_end(p[0], p[1]) == 0]


def test_cross_layout_groups_by_direction_in_list_order():
    """Owned 0-1, ghosts 2 (owner in direction 5), 3 (direction 1), 4 (direction 5); every cross pair
    (i owned, j ghost) resolved here or not by resolver_end; within each direction the list order
    is kept and direction 1's group comes before direction 5's."""
    gid = np.array([7, 9, 20, 30, 40])
    pi = np.array([0, 0, 0, 1, 1, 1, 0])
    pj = np.array([2, 3, 4, 2, 3, 4, 1])
    sent_idx, sent, recv_idx, received = cross_layout(pi, pj, gid, 2, np.array([5, 1, 5]))
    here = [k for k in range(6) if resolver_end(gid[pi[k]], gid[pj[k]]) == 0]
    there = [k for k in range(6) if k not in here]
    by_dir = lambda ks: [k for k in ks if pj[k] == 3] + [k for k in ks if pj[k] != 3]
    assert sent_idx.tolist() == by_dir(here) and recv_idx.tolist() == by_dir(there)
    assert sent[1] + sent[5] == len(here) and received[1] + received[5] == len(there)
    assert sent[1] == sum(pj[k] == 3 for k in here)


def test_resolver_splits_pairs_evenly_however_numbered():
    """Lattice numbering puts a pair's two gids a fixed stride apart (1 along the numbering's fast
    axis, 100 or 10000 along the others); the owner of the lower gid would take every such pair on
    one side of a border. splitmix64's lowest bit is equidistributed: over 100000 pairs per stride
    the share resolved by the j end is within 0.49-0.51 (6 binomial standard deviations, 0.0016)."""
    g = np.arange(100000)
    for stride in (1, 100, 10000):
        share = resolver_end(g, g + stride).mean()
        assert 0.49 < share < 0.51, (stride, share)


def _splitmix_bit(a, b):
    """splitmix64's finalizer (Steele, Lea & Flood 2014) of a 2^32 + b in Python integers mod 2^64:
    the reference for resolver_end, whose kernel wraps uint64 arithmetic."""
    mask = (1 << 64) - 1
    x = ((a << 32) ^ b) & mask
    x = (x + 0x9E3779B97F4A7C15) & mask
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & mask
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & mask
    return (x ^ (x >> 31)) & 1


def test_resolver_end_is_splitmix64(rng):
    """resolver_end on 2000 gid pairs up to 2^31 (and a few at the ends of the range) equals the
    lowest bit of splitmix64 computed in Python's unbounded integers, so both ranks of any pair
    agree with the documented rule."""
    a = rng.integers(0, 2**31, 2000)
    b = rng.integers(0, 2**31, 2000)
    a[:3], b[:3] = [0, 2**31 - 1, 5], [1, 2**31 - 2, 5]
    got = resolver_end(a, b)
    assert got.tolist() == [_splitmix_bit(int(x), int(y)) for x, y in zip(a, b)]
    assert resolver_end(7, 9) == _splitmix_bit(7, 9)


def test_terms_pack_and_unpack_exactly():
    """The pair force, the ghost end's torque (T_j where j is the ghost, T_i where i is) and the
    touching flag of each sent pair arrive bit for bit in the receiver's terms (the torque being
    that of its own end), and the sender's in-order pass gets the pair force and its own end's
    torque; only the rows named are written. Sender: owned 0-3, ghosts 4, 5; its sent list holds
    3 pairs whose terms are rows 2, 0, 3 of its 4 cross pairs; the receiver's are rows 1, 2, 0."""
    rng = np.random.default_rng(5)
    spf = rng.normal(size=(3, PF_LEN))
    son = np.array([1, 0, 1], dtype=np.int8)
    spj = np.array([5, 2, 4])   # sent pairs 0 and 2: j is the ghost; sent pair 1: i is
    spi = np.array([3, 4, 0])
    sent = (spi, spj, np.zeros((3, HIST_LEN)), son, spf)
    buf = np.zeros((3, TERMS))
    terms = np.full((4, TERMS), 7.0)
    pack_sent(sent, np.array([2, 0, 3]), 4, buf, terms)
    assert np.array_equal(buf[:, :3], spf[:, PF_F:PF_F + 3]) and buf[:, 6].tolist() == [1.0, 0.0, 1.0]
    assert np.array_equal(buf[0, 3:6], spf[0, PF_TJ:PF_TJ + 3]) and np.array_equal(buf[1, 3:6], spf[1, PF_TI:PF_TI + 3])
    assert np.array_equal(buf[2, 3:6], spf[2, PF_TJ:PF_TJ + 3])
    assert np.array_equal(terms[[2, 0, 3], :3], spf[:, PF_F:PF_F + 3]) and terms[[2, 0, 3], 6].tolist() == [1, 0, 1]
    assert (np.array_equal(terms[2, 3:6], spf[0, PF_TI:PF_TI + 3])
            and np.array_equal(terms[0, 3:6], spf[1, PF_TJ:PF_TJ + 3]))
    assert np.array_equal(terms[3, 3:6], spf[2, PF_TI:PF_TI + 3]) and np.all(terms[1] == 7.0)
    got = np.full((4, TERMS), 9.0)
    unpack_received(buf, np.array([1, 2, 0]), got)
    assert np.array_equal(got[[1, 2, 0]], buf) and np.all(got[3] == 9.0)


class _Cart:
    """The two calls count_checksum makes of a communicator."""

    def __init__(self, rank, size):
        self.rank, self.size = rank, size

    def Get_rank(self):
        return self.rank

    def Get_size(self):
        return self.size


def _checksum(rank, size, slots):
    from modes.newton import NewtonPlan
    plan = NewtonPlan.__new__(NewtonPlan)
    plan.cart = _Cart(rank, size)
    plan.slots = [(k, r, ns, nr, 0, 0) for k, r, ns, nr in slots]
    plan.checksum = None
    return plan.count_checksum()


def test_count_checksum_is_zero_exactly_when_every_link_agrees():
    """Three ranks in a row (0 - 1 - 2): each link's pairs sent by one end and expected by the
    other. Summed over the ranks the checksum is 0 when every count agrees, and not 0 when one
    rank expects one pair more than its neighbour sends, or when two links are off by one in
    opposite senses (the links' weights 1 + a P + b differ)."""
    neighbours = {0: [(13, 1)], 1: [(12, 0), (13, 2)], 2: [(12, 1)]}  # rank: [(direction, rank)]
    sent = {(0, 1): 5, (1, 0): 7, (1, 2): 0, (2, 1): 11}                # (a, b): pairs a sends b

    def total(expected):  # expected[(a, b)]: the pairs b expects from a
        return sum(_checksum(a, 3, [(k, b, sent[(a, b)], expected[(b, a)]) for k, b in nbrs])
                   for a, nbrs in neighbours.items())

    assert total(sent) == 0.0
    assert total({**sent, (0, 1): 6}) != 0.0             # rank 1 expects 6 from rank 0, which sends 5
    assert total({**sent, (0, 1): 6, (2, 1): 10}) != 0.0  # +1 on one link, -1 on another


def test_a_plan_adopts_the_next_list_only_with_the_same_counts_per_direction():
    """NewtonPlan.adopt (a relist at --skin 0 with a halo skin): a layout (cross_plan's arrays)
    that sends and expects as many pairs in every direction as the plan is taken in place, the
    plan's message buffers (bound to its persistent requests) and pair-force rows kept, its index
    arrays and sent list replaced, its terms' rows zeroed as a new plan's, and its exchange
    marked as not yet made (the history it would put back is the old list's); a layout whose
    counts differ in any direction is refused and leaves the plan as it was (the caller makes a
    new plan)."""
    from dem.forces import PF_LEN, TERMS
    from dem.state import HIST_LEN
    from modes.newton import NDIR, NewtonPlan, cross_plan

    def layout(pairs, n_owned, ghost_dir):
        pi = np.array([p[0] for p in pairs], dtype=np.int64)
        pj = np.array([p[1] for p in pairs], dtype=np.int64)
        m = len(pairs)
        return cross_plan(pi, pj, np.zeros((m, HIST_LEN)), np.zeros(m, dtype=np.int8),
                          np.arange(10, dtype=np.int64), n_owned, ghost_dir)

    gdir = np.full(4, 13, dtype=np.int64)          # every ghost (local 6..9) owned in direction 13
    first = layout([(0, 6), (1, 7), (2, 3), (4, 8)], 6, gdir)
    plan = NewtonPlan.__new__(NewtonPlan)
    (plan.sent_idx, plan.sent, plan.received_idx, plan.received, plan.cross, plan.pos_sent, plan.pos_recv,
     spi, spj, shist, son) = first
    pf = np.zeros((len(plan.sent_idx), PF_LEN))
    plan.list = (spi, spj, shist, son, pf)
    plan.terms = np.ones((len(plan.cross), TERMS))   # the last list's terms, left from its exchange
    plan.exchanged = True
    assert plan.sent.shape == (NDIR,) and plan.sent.sum() + plan.received.sum() == 3   # 3 cross pairs

    # the same cross pairs among other local ones (the resolver's hash of the gids splits them as
    # before): their places in the list move, the counts per direction do not
    same = layout([(0, 1), (0, 6), (1, 7), (3, 5), (4, 8)], 6, gdir)
    assert np.array_equal(same[1], first[1]) and np.array_equal(same[3], first[3])
    assert not np.array_equal(same[4], first[4])
    assert plan.adopt(same)
    assert plan.list[4] is pf and plan.cross is same[4] and plan.sent_idx is same[0] and not plan.exchanged
    assert plan.terms.shape == (len(same[4]), TERMS) and not plan.terms.any()

    fewer = layout([(0, 6), (2, 3)], 6, gdir)        # one cross pair: the counts differ
    kept = plan.sent_idx
    assert not plan.adopt(fewer)
    assert plan.sent_idx is kept
