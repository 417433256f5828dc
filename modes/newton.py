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

The pair list is laid out at each rebuild (cross_layout) as
    [sent: resolved here, the other end a ghost | received: resolved there | local: both owned],
the sent pairs grouped by the direction of the ghost's owner, the received ones likewise, each
group in ascending (gid_i, gid_j). A step resolves the sent pairs, packs the ghost ends' terms and
starts the messages, resolves the local pairs while they travel, then waits and unpacks the
received terms into the received pairs' records (pf, on), which nobody resolves here. Both ranks
find the same cross pairs (the candidate test is symmetric, both hold both particles as identical
copies, and the border layer is wider than any pair's reach), so what a rank sends and what its
neighbour expects agree in membership and order without a message; the counts are checked at
each rebuild all the same (one message per neighbour), and a mismatch is an error, never a
silent one.

Determinism (DESIGN.md): every particle with a cross pair gathers (gat = 1: dem.forces, SPLIT):
it sums its stored and received terms in ascending partner gid, as serial does; the others sum
as they are resolved, in the local group's gid order. The result is bit-identical to serial.

History: the received pairs' contact history lives with the resolver. It travels back at each
rebuild, and before a checkpoint, ahead of the list's history being written to the per-particle
rows (sync_history), so that both ends' rows stay identical, as without Newton: migration and
checkpoints carry them unchanged.

The owner of a ghost is the rank whose block holds its centre: at a rebuild migration has just
put every particle in the block that holds it, and the ghosts are chosen at those positions.
With `--halo 6` (ghosts forwarded through face neighbours) the terms still go straight to the
owner, one of the 26 neighbours.
"""
import numpy as np
from numba import njit

from dem.forces import PF_F, PF_TI, PF_TJ
from dem.state import HIST_LEN
from modes.base import compiled_entry
from modes.decomposition import DIRECTIONS, OPPOSITE, direction_of

# a received pair's terms: pair force [3] (on j; i takes its negation), torque on the receiver's end [3],
# touching flag
TERMS = 7
# tags of the per-step messages, and of the rebuild's counts and history (apart from the halo's)
REVERSE_TAG = 400
COUNT_TAG = 450
HISTORY_TAG = 500
LOCAL = len(DIRECTIONS)   # the group key of a pair with both ends owned (after 26 sent, 26 received keys)


@njit(cache=True, _nrt=False)
def pack_sent(pi, pj, pf, on, m_sent, buf, force, torque, n_owned):
    """buf[k] = (pair force, torque on the ghost end, on) of the sent pairs k < m_sent (buf
    [m_sent, TERMS]; the ghost is j where pj[k] >= n_owned, else i), then zero the force and
    torque [n, 3] of the owned particles (0..n_owned-1): the sent pairs are resolved first and
    sum into nobody (their owned end gathers), so the sums of the local pairs start here."""
    for k in range(m_sent):
        tc = PF_TJ if pj[k] >= n_owned else PF_TI
        for c in range(3):
            buf[k, c] = pf[k, PF_F + c]
            buf[k, 3 + c] = pf[k, tc + c]
        buf[k, 6] = float(on[k])
    for p in range(n_owned):
        for c in range(3):
            force[p, c] = 0.0
            torque[p, c] = 0.0


@njit(cache=True, _nrt=False)
def unpack_received(buf, k0, pi, n_owned, pf, on):
    """The received pairs k0.. take the pair force and their owned end's torque (j where the i end,
    pi[k] >= n_owned, is the ghost) from buf [m_recv, TERMS] into pf, and the touching flag into on."""
    for u in range(buf.shape[0]):
        k = k0 + u
        tc = PF_TJ if pi[k] >= n_owned else PF_TI
        for c in range(3):
            pf[k, PF_F + c] = buf[u, c]
            pf[k, tc + c] = buf[u, 3 + c]
        on[k] = np.int8(buf[u, 6])


def compile_kernels():
    """Compile (into numba's cache) the pack and unpack kernels, so that ranks do not compile at once."""
    pf = np.zeros((1, 9))
    on = np.zeros(1, dtype=np.int8)
    buf = np.zeros((1, TERMS))
    a = np.zeros((1, 3))
    idx = np.zeros(1, dtype=np.int64)
    pack_sent(idx, idx, pf, on, 1, buf, a, a, 1)
    unpack_received(buf, 0, idx, 1, pf, on)


def resolver_end(gid_i, gid_j):
    """1 where the j end's owner resolves the pair (gid_i, gid_j) [m], 0 where the i end's: the
    lowest bit of splitmix64 (Steele, Lea & Flood 2014) of gid_i 2^32 + gid_j, so that the pairs
    across a border split evenly between its two ranks however the particles are numbered."""
    with np.errstate(over="ignore"):
        x = (np.asarray(gid_i, dtype=np.uint64) << np.uint64(32)) ^ np.asarray(gid_j, dtype=np.uint64)
        x = x + np.uint64(0x9E3779B97F4A7C15)
        x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        x = x ^ (x >> np.uint64(31))
    return (x & np.uint64(1)).astype(np.int64)


def cross_layout(pi, pj, gid, n_owned, ghost_dir):
    """The permutation [m] that lays a gid-sorted pair list (pi, pj [m] over local ids with global
    ids gid [n]) out as sent | received | local (see the module docstring) and the group sizes:
    (perm, sent [26] pairs per direction of the ghost's owner, received [26] likewise).
    ghost_dir [n - n_owned]: the direction (modes.decomposition.DIRECTIONS) of each ghost's owner."""
    key = np.full(len(pi), 2 * LOCAL, dtype=np.int16)
    j_ghost = pj >= n_owned
    i_ghost = pi >= n_owned
    cross = j_ghost | i_ghost
    ghost = np.where(j_ghost, pj, pi)[cross]
    # resolved here when the resolving end is the owned one: i (j a ghost) with bit 0, j with bit 1
    here = resolver_end(gid[pi[cross]], gid[pj[cross]]) == (1 - j_ghost[cross].astype(np.int64))
    key[cross] = ghost_dir[ghost - n_owned] + np.where(here, 0, LOCAL)
    perm = np.argsort(key, kind="stable")   # a radix sort on int16: O(m), the gid order kept in each group
    counts = np.bincount(key, minlength=2 * LOCAL + 1)
    return perm, counts[:LOCAL], counts[LOCAL:2 * LOCAL]


class NewtonPlan:
    """The reverse exchange of one neighbour list (fixed at a rebuild): the sent pairs [0, m_sent)
    in groups per direction (sent [26]), the received pairs [m_sent, m_sent + m_recv) likewise
    (received [26]), buffers and persistent requests to the neighbour ranks (ranks [26], None where
    there is none). bytes, msgs, wire_s: what one step sends."""

    def __init__(self, cart, ranks, sent, received, wire):
        self.cart = cart
        self.ranks = ranks
        self.sent = np.asarray(sent, dtype=np.int64)
        self.received = np.asarray(received, dtype=np.int64)
        self.m_sent = int(self.sent.sum())
        self.m_recv = int(self.received.sum())
        self.send_buf = np.zeros((self.m_sent, TERMS))
        self.recv_buf = np.zeros((self.m_recv, TERMS))
        self.requests = []
        self.bytes = 0
        self.msgs = 0
        self.wire_s = 0.0
        self.entries = {}
        so = ro = 0
        for k, r in enumerate(ranks):
            ns, nr = int(self.sent[k]), int(self.received[k])
            if r is None:
                if ns or nr:
                    raise RuntimeError(f"cross-border pairs towards direction {k}, where there is no neighbour")
                continue
            if nr:
                self.requests.append(cart.Recv_init(self.recv_buf[ro:ro + nr], source=r,
                                                    tag=REVERSE_TAG + int(OPPOSITE[k])))
            if ns:
                self.requests.append(cart.Send_init(self.send_buf[so:so + ns], dest=r, tag=REVERSE_TAG + k))
                self.bytes += 8 * ns * TERMS
                self.msgs += 1
                if wire is not None:
                    self.wire_s += wire.cost(r, 8 * ns * TERMS)
            so += ns
            ro += nr

    def check_counts(self, account):
        """Each neighbour's count of the pairs it sends here equals this rank's count of the pairs it
        receives from there (one message per neighbour, at the rebuild); RuntimeError if not.
        account(rank, bytes) is told of each message sent (modes.halo.Halo's counters)."""
        from mpi4py import MPI
        reqs = []
        got = {}
        mine = {}
        for k, r in enumerate(self.ranks):
            if r is None:
                continue
            got[k] = np.zeros(1, dtype=np.int64)
            mine[k] = np.array([self.sent[k]], dtype=np.int64)
            reqs.append(self.cart.Irecv(got[k], source=r, tag=COUNT_TAG + int(OPPOSITE[k])))
            reqs.append(self.cart.Isend(mine[k], dest=r, tag=COUNT_TAG + k))
            account(r, 8)
        MPI.Request.Waitall(reqs)
        for k, c in got.items():
            if int(c[0]) != int(self.received[k]):
                raise RuntimeError(f"cross-border pair lists disagree: rank {self.ranks[k]} sends {int(c[0])} "
                                   f"pairs, rank {self.cart.Get_rank()} expects {int(self.received[k])}")

    def _call(self, kernel, args):
        entry = self.entries.get(kernel)
        if entry is None:
            kernel(*args)  # through the dispatcher: compiles where needed
            self.entries[kernel] = compiled_entry(kernel, args)
        else:
            entry(*args)

    def start(self, pi, pj, pf, on, force, torque, n_owned, startall):
        """Pack the sent pairs' ghost-end terms (and zero the owned sums: pack_sent) and start the
        messages."""
        self._call(pack_sent, (pi, pj, pf, on, self.m_sent, self.send_buf, force, torque, n_owned))
        startall(self.requests)

    def finish(self, pi, n_owned, pf, on, waitall):
        """Wait for the neighbours' terms and put them into the received pairs' records."""
        waitall(self.requests)
        self._call(unpack_received, (self.recv_buf, self.m_sent, pi, n_owned, pf, on))

    def send_history(self, hist, account):
        """The sent pairs' history rows hist [m, HIST_LEN] (at their resolution's end) into the
        neighbours' received pairs' rows, and theirs into this list's (one message each way per
        neighbour with pairs; called at a rebuild and before a checkpoint). account(rank, bytes) is
        told of each message sent."""
        from mpi4py import MPI
        reqs = []
        so, ro = 0, self.m_sent
        for k, r in enumerate(self.ranks):
            ns, nr = int(self.sent[k]), int(self.received[k])
            if nr:
                reqs.append(self.cart.Irecv(hist[ro:ro + nr], source=r, tag=HISTORY_TAG + int(OPPOSITE[k])))
            if ns:
                reqs.append(self.cart.Isend(hist[so:so + ns], dest=r, tag=HISTORY_TAG + k))
                account(r, 8 * ns * HIST_LEN)
            so += ns
            ro += nr
        MPI.Request.Waitall(reqs)

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
