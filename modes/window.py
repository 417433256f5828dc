"""The forward exchange through an MPI-3 shared-memory window, where every rank runs on one node.

Between neighbour rebuilds the forward exchange refreshes the ghosts' moving fields (modes/halo.py).
By messages, the paper's way and LAMMPS's (comm_brick forward_comm), each step pays per neighbour a
send and a receive, the library's matching and two copies through its shared-memory cells, and a
rank that starts its sends late holds up the ranks that wait for them. Ranks that share a node can
instead share memory (MPI_Win_allocate_shared, MPI 3.0 §11.2.3; the "MPI+MPI" model of Hoefler et
al., "MPI+MPI: a new hybrid approach to parallel programming with MPI plus shared memory",
Computing 95 (2013) 1121-1136): each rank writes the rows its neighbours need into its own segment
before the step's allreduce, and at the next step's start each rank copies its ghosts' rows
straight out of its neighbours' segments. No message, no matching, one copy each way.

Segments: rank r's segment of float64, a header of HEADER doubles ([0] the capacity C_r in rows,
[1 + k] the first row of the rows that go in direction k, a DIRECTIONS index), then two slots of
C_r rows of `width` doubles. Publication s writes slot s % 2; every rank publishes once a step (the
count is the same on every rank).

Synchronisation: the writer packs its rows, then MPI_Win_sync; the step's allreduce (modes.mpi
decide) orders that before the readers' MPI_Win_sync and copy at the next step's start (the unified
memory model, one passive-target epoch, MPI_Win_lock_all, for the window's life: MPI 3.1 §11.7).
The next write into the same slot comes two publications later, after the next step's allreduce,
which no rank enters before its copy is done: two slots suffice, and no rank waits for another
outside the allreduce.

Capacity: each rank sizes its own segment. A rank whose rows do not fit says so in the step's
allreduce; then every rank allocates the window anew (a collective call), each at 5/4 of its own
need, writes its rows and its header again, and the ranks meet at a barrier before any reads.

Measured at 2 ranks on a 2-vCPU VM (one job of 2 pinned ranks alternating 50-step blocks of a
mode by messages and one through the window, 20 steps of each block dropped; 1521 falling
ellipsoids, default skin and --skin 0, 23 jobs): messages / window per job 0.95-1.05, geometric
mean 0.992 [0.978, 1.007]. Within a job the ranking holds (its quartiles on one side), from job
to job it turns: the window's writes and reads cost 5 us a step in some jobs (publish 3.4-4.0 us,
the copy 1.6-2.9 us) and the messages' start and wait in others. With one neighbour the messages'
per-neighbour cost is small; the window's case is a rank with many neighbours on one node (up to
26), which a 2-core machine cannot show. Another day, by `bench perf --what forward` (the same
method, in the repository), the window led on the falling ellipsoids by 3 % (8 jobs at each skin:
1.032 [1.019, 1.045] and 1.035 [1.023, 1.048]) and tied on packed scenes (500 at --skin 0, 10 000).
The default stays the paper's (messages), which also needs no room in the node's shared-memory file
system (the window's segments; a container's /dev/shm may be small).
"""
import numpy as np
from numba import njit

from modes.decomposition import DIRECTIONS, OPPOSITE
from modes.halo import pack_moving

HEADER = 32   # doubles before a segment's two slots: [0] its capacity [rows], [1 + k] direction k's first row


@njit(cache=True, _nrt=False)
def unpack_shared(mem, src, counts, g0s, width, pos, vel, angmom, quat, with_quat):
    """Ghost rows g0s[i] .. g0s[i] + counts[i] - 1 take (pos, vel, angmom[, quat]) from the rows of
    `width` doubles at mem[src[i]:] (the node's window, flat), for each neighbour i: the inverse of
    modes.halo.pack_moving, read from the neighbours' segments."""
    for i in range(src.shape[0]):
        b0 = src[i]
        g = g0s[i]
        for u in range(counts[i]):
            b = b0 + u * width
            p = g + u
            for c in range(3):
                pos[p, c] = mem[b + c]
                vel[p, c] = mem[b + 3 + c]
                angmom[p, c] = mem[b + 6 + c]
            if with_quat:
                for c in range(4):
                    quat[p, c] = mem[b + 9 + c]


class SharedWindow:
    """The node's window of one run's forward exchange (module docstring). Made collectively over
    cart by every rank (`whole`: every rank of cart is on this rank's node; otherwise the window is
    not made and `whole` is False on every rank, since then no node holds them all)."""

    def __init__(self, cart, width):
        from mpi4py import MPI
        self.MPI = MPI
        self.width = int(width)
        self.node = cart.Split_type(MPI.COMM_TYPE_SHARED)
        self.whole = self.node.Get_size() == cart.Get_size()
        self.win = None
        if not self.whole:
            self.node.Free()
            self.node = None
            return
        # the node rank of each rank of cart (the window's segments are the node's)
        self.node_of = np.array(MPI.Group.Translate_ranks(cart.Get_group(), list(range(cart.Get_size())),
                                                          self.node.Get_group()), dtype=np.int64)
        self.published = 0        # publications so far (the same on every rank)
        self.offsets = np.zeros(len(DIRECTIONS), dtype=np.int64)  # the current layout's first rows
        self.rows = 0             # the rows this rank publishes (the current layout's)
        self.slots = None
        self.plan = None          # where the ghosts' rows lie in the neighbours' segments (read)
        self.allocations = 0      # windows made so far (the first is empty: the first rows make the second)
        self._allocate(0)

    def _allocate(self, capacity):
        """A new window (collective over the node), this rank's segment of `capacity` rows a slot."""
        MPI = self.MPI
        if self.win is not None:
            self.win.Unlock_all()
            self.win.Free()
        self.capacity = int(capacity)
        self.allocations += 1
        self.win = MPI.Win.Allocate_shared(8 * (HEADER + 2 * self.capacity * self.width), 8, comm=self.node)
        self.win.Lock_all()
        bufs = [self.win.Shared_query(r)[0] for r in range(self.node.Get_size())]
        lo = min(b.address for b in bufs)
        hi = max(b.address + len(b) for b in bufs)
        self.mem = np.frombuffer(MPI.buffer.fromaddress(lo, hi - lo), dtype=np.float64)
        self.base = np.array([(b.address - lo) // 8 for b in bufs], dtype=np.int64)   # each segment's first double
        me = self.base[self.node.Get_rank()]
        self.mine = self.mem[me:me + HEADER + 2 * self.capacity * self.width]
        self.mine[0] = self.capacity
        self.plan = None
        self._write_layout()

    def _write_layout(self):
        self.mine[1:1 + len(DIRECTIONS)] = self.offsets
        n, w, c = self.rows, self.width, self.capacity
        self.slots = None if n > c else tuple(
            self.mine[HEADER + s * c * w:HEADER + s * c * w + n * w].reshape(n, w) for s in (0, 1))

    def layout(self, dirs, counts):
        """A rebuild's rows to publish: counts[i] rows for direction dirs[i], in that order (the
        forward round's send_idx). Written into this rank's header; read by the neighbours at their
        first copy after the step's allreduce."""
        self.offsets[:] = 0
        first = 0
        for k, c in zip(dirs, counts):
            self.offsets[k] = first
            first += int(c)
        self.rows = first
        self.plan = None
        self._write_layout()

    def publish(self, idx, state, with_quat, entries, call):
        """Write rows idx of the owned particles' moving fields into this step's slot (before the
        step's allreduce). Returns whether they fit (else the allreduce asks for a new window: grow)."""
        s = self.published & 1
        self.published += 1
        if self.slots is None:
            return False
        call(entries, pack_moving, (idx, state.pos, state.vel, state.angmom, state.quat, with_quat, self.slots[s]))
        self.win.Sync()
        return True

    def grow(self, idx, state, with_quat, entries, call):
        """Every rank (collective, after an allreduce said some rank's rows did not fit): a new
        window, this rank's segment at 5/4 of its rows, its rows of the last publication written
        again, and a barrier before anyone reads."""
        self._allocate(self.rows + self.rows // 4 + 16)
        self.published -= 1
        self.publish(idx, state, with_quat, entries, call)
        self.node.Barrier()

    def _read_plan(self, ranks, dirs, recv_counts, g0):
        """Where this rank's ghosts come from: for each neighbour direction dirs[i] (rank
        ranks[dirs[i]]) with recv_counts[i] ghost rows, the first double of its rows in each slot of
        that rank's segment, read from its header: (src [2][m], counts [m], g0s [m])."""
        src = ([], [])
        counts, g0s = [], []
        row = g0
        w = self.width
        for k, c in zip(dirs, recv_counts):
            c = int(c)
            if c:
                b = int(self.base[self.node_of[ranks[k]]])
                cap = int(self.mem[b])
                first = int(self.mem[b + 1 + int(OPPOSITE[k])])
                for s in (0, 1):
                    src[s].append(b + HEADER + (s * cap + first) * w)
                counts.append(c)
                g0s.append(row)
            row += c
        as_int = (lambda a: np.array(a, dtype=np.int64))
        return (as_int(src[0]), as_int(src[1])), as_int(counts), as_int(g0s)

    def read(self, ranks, dirs, recv_counts, g0, state, with_quat, entries, call):
        """Copy this rank's ghosts' rows of the last publication (after the step's allreduce) from
        its neighbours' segments into rows g0.. of the state (recv_counts[i] from direction dirs[i],
        in that order, as the rebuild appended them); the plan of where they lie is made at the
        first copy after each rebuild or new window."""
        self.win.Sync()
        if self.plan is None:
            self.plan = self._read_plan(ranks, dirs, recv_counts, g0)
        src, counts, g0s = self.plan
        call(entries, unpack_shared, (self.mem, src[(self.published - 1) & 1], counts, g0s, self.width,
                                      state.pos, state.vel, state.angmom, state.quat, with_quat))

    def free(self):
        """Close the epoch and free the window and the node's communicator (collective)."""
        if self.win is not None:
            self.win.Unlock_all()
            self.win.Free()
            self.win = None
        if self.node is not None:
            self.node.Free()
            self.node = None


