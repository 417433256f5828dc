"""Newton's third law across ranks: a pair that crosses a block border is resolved once (MPI).

Without it each of the two ranks that hold a cross-border pair resolves it, from identical
inputs, and keeps only its own end's terms (LAMMPS `newton off`): on 12k packed ellipsoids on 2
blocks that is 2.8 % more pairs than serial, the ranks' only extra computation. With it (LAMMPS
`newton on`, its reverse communication) one of the two ranks resolves the pair, in its canonical
order (i the lower gid, as everywhere), and sends the other end's terms to that end's owner:
the pair force [3] [N] (the i end takes its negation), the torque on that end [3] [N m] and the
touching flag, 7 doubles (56 bytes) a pair, one message per neighbour, over persistent requests
fixed at the rebuild, like the forward exchange of the ghosts (modes.halo).

Which rank resolves: the owner of the i end where a hash of the pair's two gids (splitmix64,
resolver_end) is even, of the j end where it is odd. Both ranks compute it from the gids alone.
The simpler rule, the owner of the lower gid, gave rank 0 of a 12k packed bed on 2 blocks 1270
cross pairs against rank 1's 670 (a scene built in lattice order numbers the particles along
the axis the blocks cut): the hash splits them evenly whatever the numbering. (LAMMPS's rule,
the ghost above the owned particle in z, then y, then x, splits the pairs across an x or y face
but hands all those across a z face to the lower block.)

The pair list stays in ascending (gid_i, gid_j). At each rebuild cross_layout picks out the
sent pairs (resolved here, the other end a ghost) and the received ones (resolved there) as index
lists, each grouped by the direction of the ghost's owner and in list order within a group; the
sent pairs are copied out, with their history, into a list of their own (take_sent). A step
first resolves that list (one contiguous range, STORE: their terms into its pf), packs the ghost
ends' terms and starts the messages, waits for and unpacks the neighbours' terms, and then
resolves the whole list in order as one thread does (dem.forces, TAKEN): each local pair is
resolved and summed into its ends, each cross pair's terms are added to its owned end in the
pair's place. Every particle thus sums its terms in ascending partner gid, as serial does, and
no particle gathers: the result is bit-identical to serial. The cross pairs' terms sit in one
small array in list order (terms [c, 7], L2-resident), which the in-order pass walks with a
cursor.

Hybrid runs (threads over ranges of the gid-sorted list, modes.threads: partition, static,
dynamic) do the same with T threads: the sent list in chunks handed out at run time (STORE: any
order), then each thread's range of the whole list with SPLIT_TAKEN, its cursor starting at
the range's first cross pair. A particle whose pairs lie in two ranges gathers, as without
Newton: its cross pairs' terms are written into the list's own pf rows for the gather, the
others' added in place. The dynamic cut weighs a taken pair 1, as a pair apart. Under frogleap
and headtail (every pair's forces stored, pairs handed out in any order) a cross pair is
resolved on both ranks (newton off; on is refused).

Measured on 12k packed ellipsoids, 2 ranks (both modes in one MPI job, alternating blocks of 40
steps): 11.93 ms/step against 11.92 without (off/on 0.998): resolution 2.4 % cheaper, the
exchange 0.13 ms dearer (its wire is 9 us; the rest is the ranks' skew at a second meeting in
the step). What a rank repeats without Newton grows with the ranks (12k packed: +2.6 % contacts
on 2 ranks, +5.0 % on 4, +7.4 % on 8, +11.8 % on 16). Designs measured and left: the pairs'
terms in their own rows of pf (a cache miss a pair on a 2.6 MB array: 0.1 ms a step more), and
the local pairs resolved while the messages travel, the particles with a cross pair then
gathering their terms (600 particles a rank: 0.3 ms a step more). Measured again in December
2026 with compact slots instead of the gather (the pass writes each waiting particle's terms in
list order into its own rows of a small array, checked only on the pairs listed as touching one,
and the particle sums them after the messages: bit-identical to serial): the pass alone 54-130 us
dearer on 67k pairs (488 waiting particles, 5894 slots), and 2-rank steps on 12k packed 0.15-0.38
ms dearer (blocks of 8 steps alternating in one job, 4 jobs), its commuT 40-100 us higher: the
wait after the pass was no shorter than the one before it, as mpich progresses messages only
inside MPI calls (an asynchronous progress thread, MPIR_CVAR_ASYNC_PROGRESS, would take a core
from the ranks), so nothing travelled during the pass.

Both ranks find the same cross pairs (the candidate test is symmetric, both hold both particles
as identical copies, and the border layer is wider than any pair's reach), so what a rank sends
and what its neighbour expects agree in membership and order without a message; the counts are
checked at each rebuild all the same, by a checksum in the step's allreduce (count_checksum), and
a mismatch ends the run with an error at the end of that step, never silently.

History: the received pairs' contact history lives with the resolver. It travels back at each
rebuild, and before a checkpoint, ahead of the list's history being carried to the next list or
written to the per-particle rows (leaver_history, sync_history), so that both ends hold the same
history, as without Newton: migration and checkpoints carry it unchanged. With --skin 0 (every
list lives one step) it rides on each step's terms instead (NewtonPlan carry_history), and a
rebuild sends no message for it.

The owner of a ghost is the rank whose block holds its centre: at a rebuild migration has just
put every particle in the block that holds it, and the ghosts are chosen at those positions.
With `--halo 6` (ghosts forwarded through face neighbours) the terms still go straight to the
owner, one of the 26 neighbours.
"""
import numpy as np
from numba import njit

from dem.forces import PF_F, PF_LEN, PF_TI, PF_TJ, TERMS
from dem.state import HIST_LEN
from modes.base import call_entry
from modes.decomposition import DIRECTIONS, OPPOSITE, direction_of
from modes.wire import Traffic

# tags of the per-step messages and of the rebuild's history (apart from the halo's)
REVERSE_TAG = 400
HISTORY_TAG = 500
NDIR = len(DIRECTIONS)


@njit(cache=True, _nrt=False)
def pack_sent(sent, pos, n_owned, buf, terms):
    """The sent pairs' records sent = (pi, pj, hist, on, pf) [s] (resolved as their own list) into
    the send buffer, buf[u] = (pair force, torque on the ghost end, on) and, where buf is wider
    (buf [s, TERMS + HIST_LEN]: a plan that carries history, NewtonPlan), the pair's contact
    history after this resolution; and into the in-order pass's terms [cross pairs, TERMS] at rows
    pos [s]: (pair force, torque on the owned end, on). The ghost is j where pj >= n_owned, else i."""
    spi, spj, shist, son, spf = sent
    with_hist = buf.shape[1] > TERMS
    for u in range(pos.shape[0]):
        ghost_j = spj[u] >= n_owned
        tg = PF_TJ if ghost_j else PF_TI
        to = PF_TI if ghost_j else PF_TJ
        r = pos[u]
        for c in range(3):
            buf[u, c] = spf[u, PF_F + c]
            buf[u, 3 + c] = spf[u, tg + c]
            terms[r, c] = spf[u, PF_F + c]
            terms[r, 3 + c] = spf[u, to + c]
        buf[u, 6] = float(son[u])
        terms[r, 6] = float(son[u])
        if with_hist:
            for c in range(HIST_LEN):
                buf[u, TERMS + c] = shist[u, c]


@njit(cache=True, _nrt=False)
def unpack_received(buf, pos, terms):
    """The received terms buf [r, TERMS (+ HIST_LEN)] (pair force, torque on this rank's end, on;
    the history columns stay in buf) into rows pos [r] of the in-order pass's terms."""
    for u in range(pos.shape[0]):
        for c in range(TERMS):
            terms[pos[u], c] = buf[u, c]


@njit(cache=True, _nrt=False)
def put_back_history(sent_idx, shist, son, received_idx, pos_recv, terms, recv_buf, with_hist, hist, on):
    """The cross pairs' history and touching flags back into the pair list's hist [m, HIST_LEN] and
    on [m]: the sent pairs' rows sent_idx [s] from their own list (shist, son [s]), the received
    pairs' flags (rows received_idx [r]) from the last terms received (terms at rows pos_recv [r])
    and, with with_hist, their history from the last message, recv_buf [r, TERMS + HIST_LEN]."""
    for u in range(sent_idx.shape[0]):
        k = sent_idx[u]
        for c in range(HIST_LEN):
            hist[k, c] = shist[u, c]
        on[k] = son[u]
    for u in range(received_idx.shape[0]):
        k = received_idx[u]
        on[k] = np.int8(terms[pos_recv[u], 6])
        if with_hist:
            for c in range(HIST_LEN):
                hist[k, c] = recv_buf[u, TERMS + c]


def compile_kernels():
    """Compile (into numba's cache) the layout, pack and unpack kernels, so that ranks do not compile
    at once."""
    pf = np.zeros((1, PF_LEN))
    on = np.zeros(1, dtype=np.int8)
    buf = np.zeros((1, TERMS))
    idx = np.zeros(1, dtype=np.int64)
    pack_sent((idx, idx, np.zeros((1, HIST_LEN)), on, pf), idx, 1, buf, buf)
    unpack_received(buf, idx, buf)
    cross_layout(idx, idx + 1, np.arange(2), 1, idx)
    put_back_history(idx, np.zeros((1, HIST_LEN)), on, idx, idx, buf, np.zeros((1, TERMS + HIST_LEN)), True,
                     np.zeros((1, HIST_LEN)), on)
    resolver_end(idx, idx)


def resolver_end(gid_i, gid_j):
    """1 where the j end's owner resolves the pair (gid_i, gid_j) [m], 0 where the i end's: the
    lowest bit of splitmix64 (Steele, Lea & Flood 2014) of gid_i 2^32 + gid_j, so that the pairs
    across a border split evenly between its two ranks however the particles are numbered."""
    gi, gj = np.broadcast_arrays(np.asarray(gid_i, dtype=np.int64), np.asarray(gid_j, dtype=np.int64))
    out = np.empty(gi.shape, dtype=np.int64)
    _resolver_ends(gi.ravel(), gj.ravel(), out.reshape(-1))
    return out


@njit(cache=True, inline="always")
def _resolver_bit(gid_i, gid_j):
    """resolver_end of one pair (uint64 arithmetic wraps, as splitmix64 needs)."""
    x = (np.uint64(gid_i) << np.uint64(32)) ^ np.uint64(gid_j)
    x = x + np.uint64(0x9E3779B97F4A7C15)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    x = x ^ (x >> np.uint64(31))
    return np.int64(x & np.uint64(1))


@njit(cache=True)
def _resolver_ends(gid_i, gid_j, out):
    for u in range(gid_i.shape[0]):
        out[u] = _resolver_bit(gid_i[u], gid_j[u])


def cross_layout(pi, pj, gid, n_owned, ghost_dir):
    """The cross-border pairs of a pair list (pi, pj [m] over local ids with global ids gid [n]):
    (sent_idx [s], sent [26], received_idx [r], received [26]): the pairs resolved here and those
    resolved by the ghost's owner, grouped by the direction of the ghost's owner (sent[d],
    received[d] pairs in direction d), in list order within a group. ghost_dir [n - n_owned]: the
    direction (modes.decomposition.DIRECTIONS) of each ghost's owner."""
    m = len(pi)
    return cross_plan(np.ascontiguousarray(pi, dtype=np.int64), np.ascontiguousarray(pj, dtype=np.int64),
                      np.zeros((m, HIST_LEN)), np.zeros(m, dtype=np.int8), np.ascontiguousarray(gid, dtype=np.int64),
                      int(n_owned), np.ascontiguousarray(ghost_dir, dtype=np.int64))[:4]


@njit(cache=True)
def cross_plan(pi, pj, hist, on, gid, n_owned, ghost_dir):
    """Everything a rebuild fixes for the reverse exchange of the list (pi, pj, hist, on) [m], in
    one call (a counting sort in two passes over the list): the layout of cross_layout (sent_idx
    [s], sent [26], received_idx [r], received [26]); the cross pairs in list order, cross
    [s + r], and the rows of the sent and received pairs in it, pos_sent [s], pos_recv [r]; and
    the sent pairs' own list with their history (spi, spj [s], shist [s, HIST_LEN], son [s])."""
    m = pi.shape[0]
    sent = np.zeros(NDIR, dtype=np.int64)
    received = np.zeros(NDIR, dtype=np.int64)
    code = np.empty(m, dtype=np.int64)  # -1 local, the direction where sent, + NDIR where received
    for k in range(m):
        code[k] = -1
        i = pi[k]
        j = pj[k]
        j_ghost = j >= n_owned
        if not j_ghost and i < n_owned:
            continue
        d = ghost_dir[(j if j_ghost else i) - n_owned]
        # resolved here when the resolving end is the owned one: i (j a ghost) with bit 0, j with bit 1
        if _resolver_bit(gid[i], gid[j]) == (0 if j_ghost else 1):
            code[k] = d
            sent[d] += 1
        else:
            code[k] = NDIR + d
            received[d] += 1
    fill_s = np.zeros(NDIR, dtype=np.int64)
    fill_r = np.zeros(NDIR, dtype=np.int64)
    for d in range(1, NDIR):
        fill_s[d] = fill_s[d - 1] + sent[d - 1]
        fill_r[d] = fill_r[d - 1] + received[d - 1]
    ns = fill_s[NDIR - 1] + sent[NDIR - 1]
    nr = fill_r[NDIR - 1] + received[NDIR - 1]
    sent_idx = np.empty(ns, dtype=np.int64)
    received_idx = np.empty(nr, dtype=np.int64)
    cross = np.empty(ns + nr, dtype=np.int64)
    pos_sent = np.empty(ns, dtype=np.int64)
    pos_recv = np.empty(nr, dtype=np.int64)
    c = 0
    for k in range(m):
        d = code[k]
        if d < 0:
            continue
        cross[c] = k
        if d < NDIR:
            sent_idx[fill_s[d]] = k
            pos_sent[fill_s[d]] = c
            fill_s[d] += 1
        else:
            received_idx[fill_r[d - NDIR]] = k
            pos_recv[fill_r[d - NDIR]] = c
            fill_r[d - NDIR] += 1
        c += 1
    spi = np.empty(ns, dtype=np.int64)
    spj = np.empty(ns, dtype=np.int64)
    shist = np.empty((ns, HIST_LEN))
    son = np.empty(ns, dtype=np.int8)
    for u in range(ns):
        k = sent_idx[u]
        spi[u] = pi[k]
        spj[u] = pj[k]
        for h in range(HIST_LEN):
            shist[u, h] = hist[k, h]
        son[u] = on[k]
    return sent_idx, sent, received_idx, received, cross, pos_sent, pos_recv, spi, spj, shist, son


class NewtonPlan:
    """The reverse exchange of one neighbour list (fixed at a rebuild): the sent pairs sent_idx
    [s] in groups per direction (sent [26]), the received pairs received_idx [r] likewise (received
    [26]), the cross pairs in list order and the sent pairs' own list (`layout`: cross_plan's
    arrays), buffers and persistent requests to the neighbour ranks (ranks [26], None where there
    is none). traffic (modes.wire.Traffic, of the wire model and the neighbour ranks on another
    node, `links`): what one step sends.

    carry_history: each step's message carries the sent pairs' contact history too (15 doubles a
    pair, not 7), so that a rebuild finds the received pairs' history already here (put_back) and
    sends no message of its own (send_history). For lists that live one step (--skin 0, every
    step a rebuild): on 2 ranks of 500 packed ellipsoids a rebuild's round of history messages
    took 17 us of a 670 us step (in-run timers)."""

    def __init__(self, cart, ranks, layout, links=(None, frozenset()), entries=None, carry_history=False):
        self.cart = cart
        self.ranks = ranks
        (self.sent_idx, self.sent, self.received_idx, self.received, self.cross, self.pos_sent, self.pos_recv,
         spi, spj, shist, son) = layout
        self.m_sent = len(self.sent_idx)
        self.m_recv = len(self.received_idx)
        # the sent pairs' own list (pi, pj, hist, on, pf) [s], copied out of the pair list with their
        # history (cross_plan): the first phase of a step resolves it as one contiguous range, with
        # the loop every mode uses; its history is the authority until put_back
        self.list = (spi, spj, shist, son, np.zeros((self.m_sent, PF_LEN)))
        # the in-order pass meets the cross pairs in list order: their rows of terms
        self.terms = np.zeros((len(self.cross), TERMS))
        self.carry_history = bool(carry_history)
        width = TERMS + HIST_LEN if carry_history else TERMS
        self.send_buf = np.zeros((self.m_sent, width))
        self.recv_buf = np.zeros((self.m_recv, width))
        self.exchanged = False  # recv_buf holds the neighbours' terms (and history) of a step
        self.requests = []
        self.traffic = Traffic(*links)
        # the pack and unpack kernels' entry points (modes.base call_entry), shared by the plans of a
        # run when the caller passes its dict: a plan's first exchange checks its arrays' types
        self.entries = {} if entries is None else entries
        # per neighbour that exists, in direction order: (direction, rank, pairs sent, received,
        # their first rows); the loops visit only these, a direction without a neighbour has none
        self.slots = []
        self.checksum = None  # count_checksum's term, once made
        so = ro = 0
        for k, r in enumerate(ranks):
            if r is None:
                continue
            ns, nr = int(self.sent[k]), int(self.received[k])
            self.slots.append((k, r, ns, nr, so, ro))
            if nr:
                self.requests.append(cart.Recv_init(self.recv_buf[ro:ro + nr], source=r,
                                                    tag=REVERSE_TAG + int(OPPOSITE[k])))
            if ns:
                self.requests.append(cart.Send_init(self.send_buf[so:so + ns], dest=r, tag=REVERSE_TAG + k))
                self.traffic.send(r, 8 * ns * width)
            so += ns
            ro += nr
        if so != self.m_sent or ro != self.m_recv:
            k = next(k for k, r in enumerate(ranks) if r is None and self.sent[k] + self.received[k])
            self.free()
            raise RuntimeError(f"cross-border pairs towards direction {k}, where there is no neighbour")

    def adopt(self, layout):
        """Take the layout (cross_plan's arrays) of the next list where it sends and expects as many
        pairs in every direction as this plan: its buffers, persistent requests and traffic then
        serve unchanged (the messages' sizes are the same), and only the index arrays, the sent
        pairs' own list and the terms' rows are replaced. Returns whether it did (else the caller
        frees this plan and makes another). With --skin 0 and a halo skin (a list every step, the
        same ghosts) most lists cross as the one before: on 2 ranks of 500 packed ellipsoids the
        plan's requests and buffers took ~15 us a step to make and free."""
        # bytes, not np.array_equal: 26 counts each, compared in ~1 us where array_equal took ~8
        if layout[1].tobytes() != self.sent.tobytes() or layout[3].tobytes() != self.received.tobytes():
            return False
        (self.sent_idx, self.sent, self.received_idx, self.received, self.cross, self.pos_sent, self.pos_recv,
         spi, spj, shist, son) = layout
        # the pair forces' rows are written by the resolution before they are read (pack_sent)
        self.list = (spi, spj, shist, son, self.list[4])
        if self.terms.shape[0] != len(self.cross):
            self.terms = np.zeros((len(self.cross), TERMS))
        else:  # as a new plan's: nothing of the last list's terms is read as this one's
            self.terms[:] = 0.0
        self.exchanged = False
        return True

    def count_checksum(self):
        """This rank's term of a checksum of the cross pairs' counts, summed over the ranks in the
        step's one allreduce (modes.mpi decide): the pairs each neighbour b is sent, weighted by
        the link's weight w(me, b), less those expected from it, weighted w(b, me), with
        w(a, b) = 1 + a P + b for P ranks. Summed over the ranks every link's two counts meet with
        one weight, so the sum is 0 exactly when every rank receives as many pairs as its
        neighbour sends (integers below 2^53 add exactly in float64). It replaced a message round
        at each rebuild (12 us of a 2-rank rebuild of 1521 falling ellipsoids)."""
        if self.checksum is None:  # the slots' counts are fixed for the plan's life (adopt keeps them)
            me, size = self.cart.Get_rank(), self.cart.Get_size()
            total = 0
            for _, r, ns, nr, _, _ in self.slots:
                total += ns * (1 + me * size + r) - nr * (1 + r * size + me)
            self.checksum = float(total)
        return self.checksum

    def put_back(self, pairs):
        """The cross pairs' history and touching flags back into the pair list (before its history is
        read: a rebuild, a checkpoint): the sent pairs' from their own list, the received pairs' flags
        from the last terms received, and with carry_history their history from the last message
        (else it comes with send_history). One kernel call (put_back_history)."""
        if self.m_sent or self.m_recv:
            call_entry(self.entries, put_back_history, (self.sent_idx, self.list[2], self.list[3], self.received_idx,
                                                        self.pos_recv, self.terms, self.recv_buf,
                                                        self.carry_history and self.exchanged, pairs.hist,
                                                        pairs.on), True)

    def exchange(self, n_owned, startall, waitall):
        """Pack the sent pairs' terms (for the neighbours and for the in-order pass; with
        carry_history their history too), start the messages, wait for the neighbours' and put
        them in the in-order pass's terms."""
        check = not self.exchanged
        call_entry(self.entries, pack_sent, (self.list, self.pos_sent, n_owned, self.send_buf, self.terms), check)
        startall(self.requests)
        waitall(self.requests)
        call_entry(self.entries, unpack_received, (self.recv_buf, self.pos_recv, self.terms), check)
        self.exchanged = True

    def send_history(self, hist, account):
        """The sent pairs' history rows of hist [m, HIST_LEN] (at their resolution's end) into the
        neighbours' received pairs' rows, and theirs into this list's (one message each way per
        neighbour with pairs; called at a rebuild and before a checkpoint, after put_back).
        account(rank, bytes) is told of each message sent. Nothing where the last exchange carried
        the history (carry_history): put_back has written it; every rank's plan has exchanged as
        often as its neighbours' (the steps are collective), so both ends of a link skip alike."""
        if (not self.m_sent and not self.m_recv) or (self.carry_history and self.exchanged):
            return
        from mpi4py import MPI
        out = hist.take(self.sent_idx, axis=0)
        into = np.empty((self.m_recv, HIST_LEN))
        reqs = []
        for k, r, ns, nr, so, ro in self.slots:
            if nr:
                reqs.append(self.cart.Irecv(into[ro:ro + nr], source=r, tag=HISTORY_TAG + int(OPPOSITE[k])))
            if ns:
                reqs.append(self.cart.Isend(out[so:so + ns], dest=r, tag=HISTORY_TAG + k))
                account(r, 8 * ns * HIST_LEN)
        MPI.Request.Waitall(reqs)
        hist[self.received_idx] = into

    def free(self):
        for req in self.requests:
            req.Free()
        self.requests = []


def ghost_owner_directions(grid, coords, pos_ghosts):
    """The direction (DIRECTIONS index) of the block that owns each ghost [g, 3] (its centre's)."""
    if not len(pos_ghosts):
        return np.zeros(0, dtype=np.int64)
    d = direction_of(coords, grid.block_of(pos_ghosts))
    if np.any(d < 0):
        raise RuntimeError("a ghost whose owner is not a neighbour block")
    return d
