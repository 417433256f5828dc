"""The wire under the halo: an OSU-style MPI ping-pong between neighbour ranks and the cost model
it fits (issue 11, item 4). No physics; mpi4py is imported only inside functions, so this module
imports (and WireModel works) without MPI.

Measurement (`pingpong`). Every unordered pair {a, b} of ranks that list each other is measured
once, pair after pair in one global order (lexicographic (min, max)) that every rank follows,
with a barrier after each pair: at most one pair is on the wire at a time, so pairs do not
disturb each other, and the order cannot deadlock (the first unfinished pair in the global order
always has both ranks ready). The lower rank pings, as in the OSU micro-benchmarks' osu_latency
(mvapich.cse.ohio-state.edu/benchmarks; mpi4py's demo/osu_latency.py and mpi4py.bench's
ringtest): numpy byte buffers, uppercase (buffer) Send/Recv, warm-up round trips, then timed
round trips with MPI.Wtime; the one-way time of a message of n bytes is half the mean round
trip, t(n) = (t_end - t_start) / (2 iterations) [s], here the median over 3 timed blocks (a
block hit by a preemption on a shared machine is dropped). Iteration counts are time-bounded
and decided by the pinging side, which sends each count to the other side before it is used,
so both ends run the same counts: 2 probe round trips size the warm-up (up to OSU-like 100
round trips for n <= 8 KiB, 4 above, at most about time_per_size / 2), and the warm-up's mean
round trip sizes each timed block, k = clamp(ceil(time_per_size / (3 round trips)), min_iters,
max_iters). The pinging side then sends its one-way times over, and both ends fit them
with the same code, so both get the same numbers for their link.

Model (Hockney's alpha-beta model): t(n) = alpha + n / beta, alpha the latency [s] and beta the
bandwidth [B/s], fitted by least squares on the relative residuals (t_fit(n) - t(n)) / t(n) with
alpha >= 0 and 1/beta >= 0: absolute least squares over sizes from 8 B to 1 MiB would let the
largest message alone set alpha. The fit is a straight line through a curve that bends where the
MPI library switches protocol (eager to rendezvous, tens of KiB for MPICH's shared memory), so it
is within a few tens of % at each size, not exact.

What "wire" means here: the cost of a bare mpi4py Send/Recv between the two ranks on an
otherwise idle pair, the MPI library's own per-message software included (on one node the
"wire" is shared memory). It is the floor the harness could reach with the same library and
placement.

`WireModel.cost_messages(partners, nbytes)` sums alpha_p + n_i / beta_p over the messages a
rank sends in a step (count messages of 0 bytes cost alpha). It models the one-way time of each
message on its measured link, one message after another. It does not model contention (several
ranks or messages sharing memory bandwidth or a network port makes the real wire slower) nor the
overlap of concurrent non-blocking messages (which can make it faster), nor receive-side waits.
The sum is the fair reference for the exchanges, commuT - syncT + migraT (syncT: the step's one
allreduce, where a rank waits for the slowest), because those are one rank's wall time in the
exchange phases, during which that rank must at least inject every byte and pay every
message's fixed cost once; the sum counts exactly that, whatever the software does around it.
So commuT + migraT - syncT - wire (runs.csv `above_wireT`) is the time the harness spends above
the wire: packing and unpacking rows, Python and mpi4py call overhead, request handling. A
negative value means the messages overlapped better than one after another.
"""
import math

import numpy as np

DEFAULT_SIZES = (8, 64, 512, 4096, 32768, 262144, 1048576)
LARGE = 8192          # OSU's large_message_size: fewer warm-up rounds above it [B]
TAG = 0x3A7E          # on a duplicated communicator, so no message of the caller can match


class WireError(ValueError):
    """Bad ping-pong request or wire table; str() is one line."""


# --- fitting (no MPI) -------------------------------------------------------------------------------
def fit_alpha_beta(sizes, one_way):
    """Least-squares fit of t(n) = alpha + n / beta to one-way times one_way [s] at sizes [B],
    minimising sum_i ((alpha + n_i / beta - t_i) / t_i)^2 with alpha >= 0 and 1/beta >= 0
    (bound-constrained: the unconstrained solution, else the best with one bound active).
    Returns (alpha [s], beta [B/s]); beta is inf when the times do not grow with size."""
    n = np.asarray(sizes, dtype=np.float64)
    t = np.asarray(one_way, dtype=np.float64)
    if n.shape != t.shape or n.ndim != 1 or len(n) == 0:
        raise WireError(f"fit needs matching 1-D sizes and times, got {n.shape} and {t.shape}")
    if not (np.all(np.isfinite(t)) and np.all(t > 0)):
        raise WireError("fit needs finite positive one-way times")
    w = 1.0 / t
    X = np.stack([np.ones_like(n), n], axis=1) * w[:, None]
    y = t * w  # = 1

    def sse(a, b):
        return float(np.sum((X[:, 0] * a + X[:, 1] * b - y) ** 2))

    cands = []
    if len(n) >= 2 and np.ptp(n) > 0:
        (a, b), *_ = np.linalg.lstsq(X, y, rcond=None)
        if a >= 0 and b >= 0:
            cands.append((sse(a, b), a, b))
    # alpha = 0: through the origin; 1/beta = 0: the weighted mean time
    xx = float(np.dot(X[:, 1], X[:, 1]))
    if xx > 0:
        b0 = max(float(np.dot(X[:, 1], y)) / xx, 0.0)
        cands.append((sse(0.0, b0), 0.0, b0))
    a0 = max(float(np.dot(X[:, 0], y)) / float(np.dot(X[:, 0], X[:, 0])), 0.0)
    cands.append((sse(a0, 0.0), a0, 0.0))
    _, a, b = min(cands, key=lambda c: c[0])
    return float(a), (1.0 / float(b) if b > 0 else math.inf)


# --- measurement (MPI) ------------------------------------------------------------------------------
def _pairs(lists, size):
    """The sorted unordered pairs of the gathered partner lists; WireError naming every problem
    (out of range, self, not symmetric). Same input on every rank, so every rank agrees."""
    bad = []
    for r, ps in enumerate(lists):
        for p in ps:
            if not 0 <= p < size:
                bad.append(f"rank {r} lists rank {p} (only 0..{size - 1} exist)")
            elif p == r:
                bad.append(f"rank {r} lists itself")
            elif r not in lists[p]:
                bad.append(f"rank {r} lists rank {p} but rank {p} does not list rank {r}")
    if bad:
        raise WireError("pingpong partners: " + "; ".join(bad[:5])
                        + (f"; and {len(bad) - 5} more" if len(bad) > 5 else ""))
    return sorted({(min(r, p), max(r, p)) for r, ps in enumerate(lists) for p in ps})


PROBE = 2             # round trips that size the warm-up (at most warmup, about time_per_size / 2)


def _warm(n, warmup):
    return max(1, int(warmup[0] if n <= LARGE else warmup[1]))


def _rounds(comm, peer, s_msg, r_msg, k, first):
    """k round trips; `first` sends first (the pinging side), the other side echoes."""
    if first:
        for _ in range(k):
            comm.Send(s_msg, peer, TAG)
            comm.Recv(r_msg, peer, TAG)
    else:
        for _ in range(k):
            comm.Recv(r_msg, peer, TAG)
            comm.Send(s_msg, peer, TAG)


def _ping(comm, peer, sizes, sbuf, rbuf, warmup, time_per_size, min_iters, max_iters, repeats):
    """The pinging side of one pair: (one-way times [s], timed round trips) per size. Per size: 2
    probe round trips size the warm-up w (<= warmup, ~time_per_size / 2), the warm-up's mean
    round trip sizes the block k; w and k are sent to the other side before they are used."""
    from mpi4py import MPI
    wtime = MPI.Wtime
    count = np.zeros(1, dtype=np.int64)
    one_way, iters = [], []
    for n in sizes:
        s_msg, r_msg = [sbuf, n, MPI.BYTE], [rbuf, n, MPI.BYTE]
        t0 = wtime()
        _rounds(comm, peer, s_msg, r_msg, PROBE, True)
        rt = max((wtime() - t0) / PROBE, 1e-9)
        w = int(min(max(math.ceil(0.5 * time_per_size / rt), 1), _warm(n, warmup)))
        count[0] = w
        comm.Send(count, peer, TAG)
        t0 = wtime()
        _rounds(comm, peer, s_msg, r_msg, w, True)
        rt = max((wtime() - t0) / w, 1e-9)
        k = int(min(max(math.ceil(time_per_size / (repeats * rt)), min_iters), max_iters))
        count[0] = k
        comm.Send(count, peer, TAG)
        blocks = []
        for _ in range(repeats):
            t0 = wtime()
            _rounds(comm, peer, s_msg, r_msg, k, True)
            blocks.append((wtime() - t0) / (2 * k))
        one_way.append(float(np.median(blocks)))
        iters.append(k * repeats)
    return one_way, iters


def _pong(comm, peer, sizes, sbuf, rbuf, repeats):
    """The answering side of one pair: echo the probe, learn w, echo the warm-up, learn k, echo
    the timed blocks."""
    from mpi4py import MPI
    count = np.zeros(1, dtype=np.int64)
    for n in sizes:
        s_msg, r_msg = [sbuf, n, MPI.BYTE], [rbuf, n, MPI.BYTE]
        _rounds(comm, peer, s_msg, r_msg, PROBE, False)
        comm.Recv(count, peer, TAG)
        _rounds(comm, peer, s_msg, r_msg, int(count[0]), False)
        comm.Recv(count, peer, TAG)
        _rounds(comm, peer, s_msg, r_msg, int(count[0]) * repeats, False)


def _record(sizes, one_way, iters, pinger):
    alpha, beta = fit_alpha_beta(sizes, one_way)
    return {"latency_s": alpha, "bandwidth_Bps": beta, "sizes": [int(n) for n in sizes],
            "one_way_s": [float(t) for t in one_way], "iterations": [int(k) for k in iters], "pinger": int(pinger)}


def pingpong(comm, partners, sizes=DEFAULT_SIZES, time_per_size=2e-3, warmup=(100, 4), min_iters=4,
             max_iters=400, repeats=3):
    """OSU-style ping-pong between this rank and each of `partners` (collective over `comm`: every
    rank calls it with its own partner list; the relation must be symmetric, else every rank
    raises the same WireError before any message).

    sizes: message sizes [B]; time_per_size: target timed seconds per size and pair, spread over
    `repeats` timed blocks of k round trips each (k clamped to [min_iters, max_iters]); the one-way
    time is the median of the blocks' means (OSU reports one mean; the median drops a block hit by
    a preemption on a shared machine); warmup: warm-up round trips for sizes <= 8192 B and above.
    With the defaults a pair takes about 7 x 2 ms plus warm-up (2 ranks: ~20 ms; 16 ranks x 26
    neighbours, ~200 pairs: ~4 s).

    Returns {partner rank: {"latency_s": alpha [s], "bandwidth_Bps": beta [B/s], "sizes": [B],
    "one_way_s": [s], "iterations": [...], "pinger": the lower rank}}; both ends of a pair get
    the same numbers. A rank with no partner gets {} (it still takes part in the barriers)."""
    from mpi4py import MPI
    sizes = [int(n) for n in sizes]
    if not sizes or min(sizes) < 0:
        raise WireError(f"pingpong sizes must be >= 0 bytes, got {sizes}")
    if time_per_size <= 0 or min_iters < 1 or max_iters < min_iters or repeats < 1:
        raise WireError("pingpong needs time_per_size > 0, 1 <= min_iters <= max_iters and repeats >= 1")
    me = comm.Get_rank()
    mine = sorted({int(p) for p in partners})
    lists = comm.allgather(mine)
    pairs = _pairs(lists, comm.Get_size())
    wc = comm.Dup()
    try:
        cap = max(max(sizes), 1)
        sbuf = np.full(cap, 0x2A, dtype=np.uint8)
        rbuf = np.zeros(cap, dtype=np.uint8)
        ow = np.zeros(len(sizes), dtype=np.float64)
        it = np.zeros(len(sizes), dtype=np.int64)
        out = {}
        wc.Barrier()
        for a, b in pairs:
            if me == a:
                one_way, iters = _ping(wc, b, sizes, sbuf, rbuf, warmup, time_per_size, min_iters, max_iters,
                                       repeats)
                ow[:] = one_way
                it[:] = iters
                wc.Send([ow, MPI.DOUBLE], b, TAG)
                wc.Send([it, MPI.INT64_T], b, TAG)
                out[b] = _record(sizes, ow, it, a)
            elif me == b:
                _pong(wc, a, sizes, sbuf, rbuf, repeats)
                wc.Recv([ow, MPI.DOUBLE], a, TAG)
                wc.Recv([it, MPI.INT64_T], a, TAG)
                out[a] = _record(sizes, ow, it, a)
            wc.Barrier()
    finally:
        wc.Free()
    return out



PATTERN_SIZES = (104, 12480, 52000)  # a ghost's forward record; ~120 and ~500 ghosts a neighbour
PATTERNS = ("isend", "persistent", "neighbor_alltoallv")


def exchange_patterns(comm, partners, sizes=PATTERN_SIZES, iters=1000, repeats=2, warmup=100):
    """The forward exchange's candidate MPI patterns, timed on the same messages (collective over
    `comm`; `partners` symmetric as for pingpong): every rank sends one message of n bytes to and
    receives one from each partner per exchange, all at once, as modes.halo.Halo.forward does:

    - isend: new Irecv/Isend requests each exchange, then Waitall;
    - persistent: Recv_init/Send_init once, then Startall + Waitall each exchange;
    - neighbor_alltoallv: one Neighbor_alltoallv on a distributed-graph communicator of the
      same partners (MPI-3 neighbourhood collective).

    Each timing is `iters` exchanges between barriers after `warmup` untimed ones, the patterns
    alternating `repeats` times; returns {pattern: {n: seconds per exchange}}, the smallest mean
    over the repeats and the slowest rank (allreduce MAX), the same on every rank."""
    from mpi4py import MPI
    mine = sorted({int(q) for q in partners})
    wc = comm.Dup()
    graph = wc.Create_dist_graph_adjacent(mine, mine, reorder=False)
    best = {p: {} for p in PATTERNS}
    try:
        for n in sizes:
            k = max(1, (int(n) + 7) // 8)
            send = [np.full(k, float(q)) for q in mine]
            recv = [np.zeros(k) for _ in mine]
            sb = np.concatenate(send) if mine else np.zeros(0)
            rb = np.zeros_like(sb)
            counts = [k] * len(mine)
            displ = [i * k for i in range(len(mine))]
            smsg, rmsg = [sb, (counts, displ), MPI.DOUBLE], [rb, (counts, displ), MPI.DOUBLE]
            preq = ([wc.Recv_init(r, source=q, tag=TAG) for r, q in zip(recv, mine)]
                    + [wc.Send_init(b, dest=q, tag=TAG) for b, q in zip(send, mine)])

            def isend():
                MPI.Request.Waitall([wc.Irecv(r, source=q, tag=TAG + 1) for r, q in zip(recv, mine)]
                                    + [wc.Isend(b, dest=q, tag=TAG + 1) for b, q in zip(send, mine)])

            def persistent():
                MPI.Prequest.Startall(preq)
                MPI.Request.Waitall(preq)

            def neighbor_alltoallv():
                graph.Neighbor_alltoallv(smsg, rmsg)

            run = {"isend": isend, "persistent": persistent, "neighbor_alltoallv": neighbor_alltoallv}
            for _ in range(repeats):
                for name in PATTERNS:
                    fn = run[name]
                    for _ in range(warmup):
                        fn()
                    wc.Barrier()
                    t0 = MPI.Wtime()
                    for _ in range(iters):
                        fn()
                    t = wc.allreduce((MPI.Wtime() - t0) / iters, op=MPI.MAX)
                    best[name][int(n)] = min(best[name].get(int(n), math.inf), t)
            for r in preq:
                r.Free()
    finally:
        graph.Free()
        wc.Free()
    return best


# --- the model (no MPI) -----------------------------------------------------------------------------
class WireModel:
    """cost(partner, n) = alpha_p + n / beta_p [s] for one message of n bytes to `partner`.

    table: {partner: {"latency_s": alpha [s], "bandwidth_Bps": beta [B/s], ...}} with int or str
    keys (pingpong's result, or run.json's "wire" entry {"partners": {"<rank>": {...}}})."""

    def __init__(self, table):
        if isinstance(table, dict) and isinstance(table.get("partners"), dict):
            table = table["partners"]
        if not isinstance(table, dict):
            raise WireError(f"wire table must be a dict of partner -> latency/bandwidth, got {type(table).__name__}")
        self.alpha, self.beta = {}, {}
        for key, rec in table.items():
            try:
                p = int(key)
                a = float(rec["latency_s"])
                b = float(rec["bandwidth_Bps"])
            except (TypeError, ValueError, KeyError):
                raise WireError(f"wire table entry {key!r}: need an int rank with latency_s and bandwidth_Bps, "
                                f"got {rec!r}") from None
            if not (math.isfinite(a) and a >= 0) or not (b > 0):
                raise WireError(f"wire table entry {key!r}: need latency_s >= 0 finite and bandwidth_Bps > 0, "
                                f"got {a!r}, {b!r}")
            self.alpha[p], self.beta[p] = a, b

    @property
    def partners(self):
        return sorted(self.alpha)

    def _lookup(self, partner):
        try:
            return self.alpha[partner], self.beta[partner]
        except KeyError:
            raise WireError(f"no wire measurement for partner rank {partner} (measured: {self.partners})") from None

    def cost(self, partner, nbytes):
        """One-way time [s] of one message of nbytes [B] to `partner`: alpha + nbytes / beta
        (nbytes = 0, a count message, costs alpha)."""
        if nbytes < 0:
            raise WireError(f"message size must be >= 0 bytes, got {nbytes}")
        a, b = self._lookup(int(partner))
        return a + float(nbytes) / b

    def cost_messages(self, partners, nbytes):
        """sum_i (alpha_{p_i} + nbytes_i / beta_{p_i}) [s] over messages i (arrays of equal
        length, or a scalar nbytes for every message): the wire time of a rank's sends in a step
        if they went one after another. 0 for no message."""
        p = np.atleast_1d(np.asarray(partners, dtype=np.int64))
        try:
            n = np.broadcast_to(np.asarray(nbytes, dtype=np.float64), p.shape)
        except ValueError:
            raise WireError(f"{len(p)} partners but nbytes of shape {np.shape(nbytes)}") from None
        if len(p) == 0:
            return 0.0
        if np.any(n < 0):
            raise WireError("message sizes must be >= 0 bytes")
        ab = np.array([self._lookup(int(q)) for q in p], dtype=np.float64)
        return float(np.sum(ab[:, 0] + n / ab[:, 1]))

    def as_dict(self):
        """{"partners": {"<rank>": {"latency_s", "bandwidth_Bps"}}}: run.json's "wire" form,
        which WireModel reads back."""
        return {"partners": {str(p): {"latency_s": self.alpha[p], "bandwidth_Bps": self.beta[p]}
                             for p in self.partners}}


class Traffic:
    """What a rank sends, counted message by message and split by where the receiver runs (issue
    37): bytes, msgs and wire_s [s] (the WireModel cost of each message on its own measured link;
    0 without a model) of all messages, and bytes_internode, msgs_internode, wire_internode_s of
    those to ranks on another node (`remote`: their ranks). Within the node = all less internode.

    A plan fixed at a rebuild (a forward round, the reverse exchange) counts its messages once into
    a Traffic of its own and adds it whole each step (add), so a step pays four additions, not a
    loop over its messages."""

    __slots__ = ("wire", "remote", "bytes", "msgs", "wire_s", "bytes_internode", "msgs_internode",
                 "wire_internode_s")

    def __init__(self, wire=None, remote=frozenset()):
        self.wire = wire
        self.remote = frozenset(remote)
        self.reset()

    def reset(self):
        self.bytes = self.msgs = self.bytes_internode = self.msgs_internode = 0
        self.wire_s = self.wire_internode_s = 0.0

    def send(self, rank, nbytes):
        """Count one message of nbytes [B] to rank."""
        cost = self.wire.cost(rank, nbytes) if self.wire is not None else 0.0
        self.bytes += nbytes
        self.msgs += 1
        self.wire_s += cost
        if rank in self.remote:
            self.bytes_internode += nbytes
            self.msgs_internode += 1
            self.wire_internode_s += cost

    def add(self, other):
        """Add another Traffic's counts (a plan's messages, sent once more)."""
        self.bytes += other.bytes
        self.msgs += other.msgs
        self.wire_s += other.wire_s
        if other.msgs_internode:
            self.bytes_internode += other.bytes_internode
            self.msgs_internode += other.msgs_internode
            self.wire_internode_s += other.wire_internode_s

    def row(self):
        """The steps.csv columns of these counts."""
        return {"bytes_sent": self.bytes, "msgs_sent": self.msgs, "wire_s": self.wire_s,
                "bytes_internode": self.bytes_internode, "msgs_internode": self.msgs_internode,
                "wire_internode_s": self.wire_internode_s}
