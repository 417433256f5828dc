"""Ghost exchange and particle migration between link blocks (MPI; no physics here).

As LAMMPS does (comm_brick: exchange() and borders() on reneighbouring steps, forward_comm()
between them), the work splits by how often it is needed:

- on neighbour-rebuild steps, migration (migraT): particles whose centre left the block move to
  the neighbour that owns it with their whole state, wall history and contact history (rows
  keyed by partner gid, written for the leaving particles only: modes.mpi leaver_history), so
  the tangential springs never reset (the paper's code loses them); when nobody leaves, a
  message of empty headers is all that travels;
  then the choice of ghosts (commuT): each block sends the owned particles inside the border
  layer to each neighbour that needs them, with every field the contact kernels read, directly
  to all 26 neighbours (the paper's exchange, --halo 26) or in three sweeps of two messages that
  forward what earlier sweeps brought (--halo 6: fewer, larger messages; the same ghosts).
  Full ghost records: for a scene of spheres 14 doubles (gid, material, mass, radius, moment of
  inertia, position, velocity, angular momentum: 112 bytes); otherwise 23 (plus shape, three
  semi-axes, three moments, quaternion: 184 bytes); in a scene with poly-ellipsoids also the
  poly record (18 doubles, 328 bytes). The paper sends 624 bytes per ellipsoid every step.
- on the steps between, forward communication (commuT): only what changes (position, velocity,
  angular momentum, and for non-spheres the quaternion: 72 or 104 bytes a ghost) travels to the
  same ghosts, packed and unpacked by numba over the index lists of the last rebuild, into
  buffers allocated once per rebuild, one message per neighbour per round. The first round is
  packed and started at the end of the step that integrated the positions (forward_start),
  once the ranks' collective decision has said that the next step does not rebuild (a step
  before a rebuild sends nothing); the next step only waits and unpacks (forward). Measured on
  2 ranks, 1521 falling ellipsoids (127 ghosts, 13 kB): the forward exchange inside a step took
  42-48 us started in the step (pack 3-15 us, transfer 14 us from the later send to the receive,
  skew 3-8 us, unpack 2-3 us). Against the messages started before the decision (the order
  until December 2026, emulated by wrapping the step's two calls, which adds a few us of
  Python), blocks of 8 steps of each order alternating in one 2-rank job (medians of the slower
  rank's steps, two jobs each): 1521 falling ellipsoids 0.165 against 0.167 ms, 500 packed 0.478
  against 0.481 ms, 12k packed 11.88 against 11.86 and 12.17 against 12.19 ms: the same within
  what the emulation adds and the noise; a step before a rebuild no longer sends what it then
  drops.

Ghosts are exact binary copies, so each rank derives the same rotation matrix and angular
velocity from them as the owner does.

MPI pattern of the forward exchange: persistent point-to-point requests (Send_init/Recv_init
on the rebuild's buffers, then Startall + Waitall each step). Measured with mpi4py on 2 ranks
(mpich 4, shared memory, one neighbour, best of two means over 3000 exchanges each way; the same
measurement on any grid: `bench perf --what comm --patterns`, modes.wire.exchange_patterns):

    bytes a message      104      12 480     52 000
    Isend/Irecv          5.8 us   9.4 us     14.0 us
    persistent           3.0 us   7.5 us     12.2 us
    Neighbor_alltoallv   5.5 us   9.7 us     15.3 us

Persistent requests create no request objects in Python each step; the neighbourhood collective
(on a distributed-graph communicator) adds its argument handling to the same messages in mpich,
and one collective call cannot express the --halo 6 sweeps, whose later rounds forward what the
first brought.

Message sizes are fixed between rebuilds, so a forward round sends no counts; a rebuild's
exchange (migration, ghost choice) sends one message per neighbour, a header of row counts and
the rows, which the receiver sizes by a matched probe (Halo.exchange). The direct exchange's
ghost choice is two numba calls: one selects the border particles and packs their records
straight into each neighbour's message (pack_border_messages), the other writes the received
ones in place after the owned rows of capacity arrays the halo keeps (write_border_messages,
Halo._grow); the owned rows are copied only when a migration replaced the arrays or they are
full.
"""
import functools
import operator

import numpy as np
from numba import njit

from dem.shapes import ELLIPSOID, POLY, POLY_LEN
from dem.shapes.registry import bounding_radii, shapes
from dem.state import HIST_LEN, State, csr_rows
from modes.base import call_entry
from modes.decomposition import (DIRECTIONS, NEEDS, OPPOSITE, BlockGrid, border_lists, border_lists_kernel,
                                 direction_of, face_bits)
from modes.wire import Traffic

# the fields a ghost record may carry (a shape's ghost_fields: dem.shapes.shape.Shape) and their
# widths [doubles]; axes0, inertia0: the first semi-axis and moment only (a shape whose three are equal)
WIDTH = {"gid": 1, "shape": 1, "material": 1, "mass": 1, "axes0": 1, "inertia0": 1, "axes": 3, "inertia": 3,
         "pos": 3, "vel": 3, "angmom": 3, "quat": 4, "poly": POLY_LEN}
# forward messages have tags of their own: one started at the end of a step may still be on its
# way while a rebuild's migration or ghost choice exchanges its messages (EXCHANGE_TAG + k)
EXCHANGE_TAG = 100
FORWARD_TAG = 200


def ghost_fields(kind):
    """The fields a ghost carries in a scene of this kind (its most general shape code:
    dem.forces.scene_kind): that shape's ghost_fields, only what the scene's kernels read."""
    return shapes()[kind].ghost_fields


def moving_fields(kind):
    """The fields a forward exchange refreshes in a scene of this kind (a sphere's orientation
    shapes nothing)."""
    return shapes()[kind].moving_fields


def _owner_fields(state):
    """The fields of a migrating particle (with its histories besides): every per-particle array of
    a ghost but those derived (rbound) or made each step (force, torque); poly in a scene with
    poly-ellipsoids only."""
    return _migrant_fields(state.has_poly)


@functools.lru_cache(maxsize=None)
def _migrant_fields(has_poly):
    return tuple(f for f in PER_PARTICLE if f not in ("rbound", "force", "torque") and (f != "poly" or has_poly))


def _columns(state, fields, idx):
    """Rows idx of the state's fields as one float64 matrix [len(idx), sum widths] (gid and the
    small integer fields travel bit-exactly: gid by reinterpretation, the others as floats)."""
    out = np.empty((len(idx), sum(WIDTH[f] for f in fields)))
    c = 0
    for f in fields:
        w = WIDTH[f]
        if f == "gid":
            out[:, c] = state.gid.take(idx).view(np.float64)
        elif f == "axes0":
            out[:, c] = state.axes[:, 0].take(idx)
        elif f == "inertia0":
            out[:, c] = state.inertia[:, 0].take(idx)
        else:  # take: a row gather of [n, 3] at a quarter of the time of a[idx]
            out[:, c:c + w] = getattr(state, f).take(idx, axis=0).reshape(len(idx), w)
        c += w
    return out


def _split(rows, fields):
    """Inverse of _columns: dict field -> array."""
    out = {}
    c = 0
    for f in fields:
        w = WIDTH[f]
        block = rows[:, c:c + w]
        c += w
        if f == "gid":
            out["gid"] = np.ascontiguousarray(block[:, 0]).view(np.int64)
        elif f in ("shape", "material"):
            out[f] = block[:, 0].astype(np.int64)
        elif f in ("axes0", "inertia0"):
            out[f[:-1]] = np.repeat(block, 3, axis=1)
        elif f == "mass":
            out[f] = block[:, 0].copy()
        else:
            out[f] = block.copy()
    return out


@njit(cache=True, _nrt=False)
def pack_moving(idx, pos, vel, angmom, quat, with_quat, buf):
    """buf[u] = (pos, vel, angmom[, quat]) of row idx[u] (buf [len(idx), 9 or 13])."""
    for u in range(idx.shape[0]):
        p = idx[u]
        for c in range(3):
            buf[u, c] = pos[p, c]
            buf[u, 3 + c] = vel[p, c]
            buf[u, 6 + c] = angmom[p, c]
        if with_quat:
            for c in range(4):
                buf[u, 9 + c] = quat[p, c]


@njit(cache=True, _nrt=False)
def unpack_moving(buf, g0, pos, vel, angmom, quat, with_quat):
    """Rows g0.. of the state take (pos, vel, angmom[, quat]) from buf (inverse of pack_moving)."""
    for u in range(buf.shape[0]):
        p = g0 + u
        for c in range(3):
            pos[p, c] = buf[u, c]
            vel[p, c] = buf[u, 3 + c]
            angmom[p, c] = buf[u, 6 + c]
        if with_quat:
            for c in range(4):
                quat[p, c] = buf[u, 9 + c]


def _record_kernels():
    """The ghost records' pack and write kernels, generated from the registered shapes'
    ghost_fields (numba compiles the straight-line code a programmer would write for each kind of
    record, as dem.shapes.dispatch does for the contact kernels; not cached themselves: the
    cached pack_ghost_rows and write_ghost_rows compile them in).

    pack(idx, kind, gid_bits, shape, material, mass, axes, inertia, pos, vel, angmom, quat, poly,
    out): out[u] = the record (ghost_fields(kind), in its order and widths) of row idx[u];
    write(n, rows, gids, kind, gid, shape, axes, rbound, mass, inertia, material, pos, vel, quat,
    angmom, force, torque, poly): row n + u of the arrays takes record rows[u]. A field the
    record lacks takes what it means for the kind: its code for shape, the first semi-axis and
    moment thrice for axes0 and inertia0, the unit quaternion (never read), a zero poly record;
    rbound the largest semi-axis (the caller adds a poly-ellipsoid's offset); force and torque
    zero."""
    pack = ["def pack(idx, kind, gid_bits, shape, material, mass, axes, inertia, pos, vel, angmom, quat, poly, out):"]
    write = ["def write(n, rows, gids, kind, gid, shape, axes, rbound, mass, inertia, material, pos, vel, quat,",
             "          angmom, force, torque, poly):"]
    source = {"gid": "gid_bits[p]"}
    for s in shapes():
        fields = s.ghost_fields
        pack += [f"    if kind == {s.code}:", "        for u in range(idx.shape[0]):", "            p = idx[u]"]
        write += [f"    if kind == {s.code}:", "        for u in range(rows.shape[0]):", "            p = n + u"]
        c = 0
        for f in fields:
            w = WIDTH[f]
            if w == 1:
                src = source.get(f, f"{f[:-1]}[p, 0]" if f.endswith("0") else f"{f}[p]")
                pack.append(f"            out[u, {c}] = {src}")
            else:  # bounded by the array too: never past a narrower one (a scene without the record)
                pack += [f"            for a in range(min({w}, {f}.shape[1])):",
                         f"                out[u, {c} + a] = {f}[p, a]"]
            if f == "gid":
                write.append("            gid[p] = gids[u]")
            elif f in ("shape", "material"):
                write.append(f"            {f}[p] = np.{'int8' if f == 'shape' else 'int32'}(rows[u, {c}])")
            elif f == "mass":
                write.append(f"            mass[p] = rows[u, {c}]")
            elif f.endswith("0"):
                write += [f"            {f[:-1]}[p, {a}] = rows[u, {c}]" for a in range(3)]
            else:
                write += [f"            for a in range(min({w}, {f}.shape[1])):",
                          f"                {f}[p, a] = rows[u, {c} + a]"]
            c += w
        if "shape" not in fields:
            write.append(f"            shape[p] = {s.code}")
        if "quat" not in fields:
            write += [f"            quat[p, {a}] = {1.0 if a == 0 else 0.0}" for a in range(4)]
        if "poly" not in fields:
            write += ["            for a in range(poly.shape[1]):", "                poly[p, a] = 0.0"]
        write += [f"            {f}[p, {a}] = 0.0" for f in ("force", "torque") for a in range(3)]
        write += ["            rbound[p] = max(axes[p, 0], axes[p, 1], axes[p, 2])"]
        pack.append("        return")
        write.append("        return")
    namespace = {"np": np}
    exec(compile("\n".join(pack + write) + "\n", "<modes.halo ghost records>", "exec"), namespace)
    return njit(inline="always")(namespace["pack"]), njit(inline="always")(namespace["write"])


_pack_records, _write_records = _record_kernels()


@njit(cache=True, _nrt=False)
def pack_ghost_rows(idx, kind, gid_bits, shape, material, mass, axes, inertia, pos, vel, angmom, quat, poly, out):
    """out[u] = the ghost record (ghost_fields(kind), in its order and widths) of row idx[u]:
    _columns in one pass (a take per field cost ~2 us each, 20 us of a rebuild at 120 ghosts).
    gid_bits: the gids [n] viewed as float64, so that they travel bit-exactly; out [len(idx),
    record width]."""
    _pack_records(idx, kind, gid_bits, shape, material, mass, axes, inertia, pos, vel, angmom, quat, poly, out)


@njit(cache=True, _nrt=False)
def write_ghost_rows(n, rows, gids, kind, gid, shape, axes, rbound, mass, inertia, material, pos, vel, quat,
                     angmom, force, torque, poly):
    """Rows n..n+m-1 of the per-particle arrays (at least n + m rows each) take the ghosts of rows
    [m, record width] (pack_ghost_rows' records; gids [m] their gids, the first column's bits):
    see _record_kernels for the fields a record lacks."""
    _write_records(n, rows, gids, kind, gid, shape, axes, rbound, mass, inertia, material, pos, vel, quat, angmom,
                   force, torque, poly)


@njit(cache=True)
def pack_border_messages(n, lo, hi, width, needs, faces, nbr_dirs, kind, ncol, gid_bits, shape, material, mass,
                         axes, inertia, pos, vel, angmom, quat, poly):
    """The ghost choice's messages of the direct exchange in one pass over the owned rows 0..n-1:
    for each neighbour i (direction nbr_dirs[i], ascending) its message, buf[offs[i]:offs[i + 1]]
    = [row count, the records (pack_ghost_rows, ncol doubles each) of the particles within width of
    the block faces on its side] (border_lists' test and order), and those rows, send_idx
    [sum counts] in neighbour order (the forward exchange's index lists). Returns (buf, offs
    [nd + 1], send_idx, counts [nd]). One numba call instead of border_lists, a record packing
    and the exchange's copy into a message per neighbour (border_lists' kernel, then
    pack_ghost_rows per message)."""
    start, items = border_lists_kernel(pos[:n], lo, hi, width, needs, faces)
    nd = nbr_dirs.shape[0]
    counts = np.zeros(nd, dtype=np.int64)
    offs = np.zeros(nd + 1, dtype=np.int64)
    first = np.zeros(nd + 1, dtype=np.int64)
    for i in range(nd):
        k = nbr_dirs[i]
        counts[i] = start[k + 1] - start[k]
        offs[i + 1] = offs[i] + 1 + counts[i] * ncol
        first[i + 1] = first[i] + counts[i]
    buf = np.empty(offs[nd])
    send_idx = np.empty(first[nd], dtype=np.int64)
    for i in range(nd):
        k = nbr_dirs[i]
        send_idx[first[i]:first[i + 1]] = items[start[k]:start[k + 1]]
        buf[offs[i]] = counts[i]
        rows = buf[offs[i] + 1:offs[i + 1]].reshape((counts[i], ncol))
        pack_ghost_rows(send_idx[first[i]:first[i + 1]], kind, gid_bits, shape, material, mass, axes, inertia, pos, vel,
                        angmom, quat, poly, rows)
    return buf, offs, send_idx, counts


@njit(cache=True, _nrt=False)
def write_border_messages(n, recv, recv_bits, offs, nbr_dirs, ncol, kind, ghost_dirs, counts, gid, shape, axes, rbound,
                          mass, inertia, material, pos, vel, quat, angmom, force, torque, poly):
    """The received ghost-choice messages (recv, neighbour i's at recv[offs[i]:offs[i + 1]], as
    pack_border_messages packs them; recv_bits the same buffer viewed as int64) into rows n.. of
    the per-particle arrays, in neighbour order; ghost_dirs [ghosts] takes each
    ghost's owner's direction, counts [nd] the rows of each message (write_ghost_rows per message)."""
    p = n
    for i in range(nbr_dirs.shape[0]):
        m = np.int64(recv[offs[i]])
        counts[i] = m
        rows = recv[offs[i] + 1:offs[i + 1]].reshape((m, ncol))
        write_ghost_rows(p, rows, recv_bits[offs[i] + 1:offs[i + 1]:ncol], kind, gid, shape, axes, rbound, mass,
                         inertia, material, pos, vel, quat, angmom, force, torque, poly)
        ghost_dirs[p - n:p - n + m] = nbr_dirs[i]
        p += m


def compile_kernels():
    """Compile (into numba's cache) the pack and unpack kernels and the border and direction tests
    of the ghost choice and migration, so that ranks do not compile at once."""
    a = np.zeros((1, 3))
    q = np.zeros((1, 4))
    buf = np.zeros((1, 13))
    idx = np.zeros(1, dtype=np.int64)
    pack_moving(idx, a, a, a, q, True, buf)
    unpack_moving(buf, 0, a, a, a, q, True)
    one, i8, i32 = np.zeros(1), np.zeros(1, dtype=np.int8), np.zeros(1, dtype=np.int32)
    # the kind is an argument: one compilation for each width of the poly record serves them all
    for kind, poly in ((ELLIPSOID, np.zeros((1, 0))), (POLY, np.zeros((1, POLY_LEN)))):
        ncol = sum(WIDTH[f] for f in ghost_fields(kind))
        rows = np.zeros((1, ncol))
        pack_ghost_rows(idx, kind, one, i8, i32, one, a, a, a, a, a, q, poly, rows)
        write_ghost_rows(0, rows, idx, kind, idx, i8, a, one, one, a, i32, a, a, q, a, a, a, poly)
        buf, offs, _, counts = pack_border_messages(1, np.zeros(3), np.ones(3), 0.1, NEEDS, 63, idx, kind, ncol, one,
                                                    i8, i32, one, a, a, a, a, a, q, poly)
        write_border_messages(0, buf, buf.view(np.int64), offs, idx, ncol, kind, idx, counts, idx, i8, a, one, one, a,
                              i32, a, a, q, a, a, a, poly)
    border_lists(a, np.zeros(3), np.ones(3), 0.1)
    for cuts in (None, ([0.5], [], [])):
        grid = BlockGrid(((0.0, 0.0, 0.0), (1.0, 1.0, 1.0)), (2, 1, 1), cuts=cuts)
        grid.block_of(a)
        grid.leavers(a, np.zeros(3, dtype=np.int64))
    csr_rows(np.zeros(2, dtype=np.int64), idx)
    direction_of(np.zeros(3, dtype=np.int64), np.zeros((1, 3), dtype=np.int64))


class _Round:
    """One round of a forward exchange, fixed at a rebuild: the rows sent to each neighbour
    (send_idx, concatenated in direction order), the ghost rows received from each (rows g0 + ..),
    their buffers and persistent requests. The buffers and requests are made at the round's first
    start (prepare): with --skin 0 every step rebuilds and no forward exchange ever runs (making
    them took 9 us of each 2-rank rebuild of 1521 falling ellipsoids). The pack and unpack kernels
    are called through their compiled entry points (modes.base call_entry), kept in the halo's
    kernels dict across rounds: a round's first call checks its arrays' types against them, later
    ones see the same arrays until the next rebuild replaces the round."""

    def __init__(self, cart, dirs, ranks, send_idx, send_counts, recv_counts, g0, width, links, kernels):
        self.g0 = g0
        self.kernels = kernels
        self.checked = set()  # the kernels whose entry this round's arrays were checked against
        self.send_idx = send_idx
        self.plan = (cart, dirs, ranks, send_counts, recv_counts, width, links)
        self.requests = None

    def prepare(self):
        """Buffers, persistent requests and what one start sends (self.traffic: modes.wire.Traffic;
        links: the halo's (wire model, ranks on another node))."""
        if self.requests is not None:
            return
        cart, dirs, ranks, send_counts, recv_counts, width, links = self.plan
        self.send_buf = np.zeros((len(self.send_idx), width))
        self.recv_buf = np.zeros((int(sum(recv_counts)), width))
        self.requests = []
        self.traffic = Traffic(*links)
        so = ro = 0
        for d, k in enumerate(dirs):
            r = ranks[k]
            ns, nr = int(send_counts[d]), int(recv_counts[d])
            if nr:
                self.requests.append(cart.Recv_init(self.recv_buf[ro:ro + nr], source=r,
                                                    tag=FORWARD_TAG + int(OPPOSITE[k])))
            if ns:
                self.requests.append(cart.Send_init(self.send_buf[so:so + ns], dest=r, tag=FORWARD_TAG + int(k)))
                self.traffic.send(r, 8 * ns * width)
            so += ns
            ro += nr

    def call(self, kernel, args):
        """kernel(*args), through its entry point (checked at the round's first call of it)."""
        check = kernel not in self.checked
        if check:
            self.checked.add(kernel)
        call_entry(self.kernels, kernel, args, check)

    def free(self):
        for req in self.requests or ():
            req.Free()
        self.requests = None


class Halo:
    """Neighbour ranks of one block and the exchanges between them.

    cart: MPI Cartesian communicator (not periodic); grid: BlockGrid; coords: this block; wire:
    a modes.wire.WireModel of the links to the neighbour ranks (or None), for the wire time of
    what each step sends; remote: the neighbour ranks on another node. `traffic` (a
    modes.wire.Traffic: bytes, messages and wire time, all and across nodes) accumulates what
    this rank sends until the caller resets it."""

    def __init__(self, cart, grid, coords, halo="26", wire=None, remote=frozenset(), window=None):
        if halo not in ("26", "6"):
            raise ValueError(f"halo must be '26' or '6', got {halo!r}")
        self.halo = halo
        self.cart = cart
        self.grid = grid
        self.coords = np.asarray(coords)
        self.lo, self.hi = grid.bounds(coords)
        self.ranks = []
        for k in range(len(DIRECTIONS)):
            c = grid.neighbour(coords, k)
            self.ranks.append(None if c is None else cart.Get_cart_rank([int(x) for x in c]))
        # the (direction, rank) of the neighbours that exist: the loops of a rebuild visit these
        # only (a loop over all 26 directions in Python cost ~0.4 us a direction, each exchange)
        self.neighbours = [(k, r) for k, r in enumerate(self.ranks) if r is not None]
        self.neighbour_list = [k for k, _ in self.neighbours]
        self.neighbour_dirs = np.array(self.neighbour_list, dtype=np.int64)
        self.faces = face_bits([k for k, _ in self.neighbours])  # the block's faces that have a neighbour
        self.set_links(wire, remote)
        from mpi4py import MPI  # a halo exists only under MPI; the per-step calls are bound once
        self.startall = MPI.Prequest.Startall
        self.waitall = MPI.Request.Waitall
        self.status = MPI.Status()
        self.double = MPI.DOUBLE
        self.rounds = []
        self.ghost_dirs = None  # the direction of each ghost's owner [n_ghost] (direct exchange), or None
        self.started = False   # the first forward round's messages are on their way (forward_start)
        self.store = {}        # the capacity arrays that hold the state's rows and its ghosts (_append)
        self.held = None       # the same, in PER_PARTICLE order
        self.entries = {}      # the compiled entry points of the ghost records' kernels (their types are fixed)
        self.with_quat = True
        # the forward exchange through the node's shared-memory window (modes.window; --halo 26 only),
        # or None: by messages
        self.window = window if halo == "26" else None

    def set_links(self, wire, remote):
        """The wire model of the links (or None) and the neighbour ranks on another node; the
        counts start again."""
        self.wire = wire
        self.remote = frozenset(remote)
        self.traffic = Traffic(wire, self.remote)

    def clone(self):
        """The same neighbours and grid, without a forward plan."""
        return Halo(self.cart, self.grid, self.coords, halo=self.halo, wire=self.wire, remote=self.remote,
                    window=self.window)

    def reset_counters(self):
        self.traffic.reset()

    def neighbour_ranks(self):
        """The distinct ranks of the neighbour blocks."""
        return sorted({r for r in self.ranks if r is not None})

    def set_grid(self, grid):
        self.grid = grid
        self.lo, self.hi = grid.bounds(self.coords)

    def account(self, rank, nbytes):
        """Count one message of nbytes [B] sent to rank (self.traffic)."""
        self.traffic.send(rank, nbytes)

    def exchange(self, outgoing, widths, dirs=None):
        """Send outgoing[k] (a tuple of float64 arrays [rows_a, widths[a]], or None) to neighbour k
        and return what each neighbour sent (tuples; None where there is no neighbour). One message
        per neighbour, whatever the number of arrays: a header of the arrays' row counts, then their
        rows, flat; the receiver sizes it by probing (Mprobe, MPI-3's matched probe), so no round of
        counts goes first. Measured on 2 ranks, 1521 falling ellipsoids with --skin 0 (a rebuild
        every step, two exchanges a step; medians of 300 steps, in-process timers): 26-27 us an
        exchange with a round of counts first, 19-20 us without."""
        na = len(widths)
        nbrs = self.neighbours if dirs is None else [(k, self.ranks[k]) for k in dirs if self.ranks[k] is not None]
        messages = []
        for k, _ in nbrs:
            parts = outgoing[k] or ()
            rows = [len(a) for a in parts] + [0] * (na - len(parts))
            buf = np.empty(na + sum(n * w for n, w in zip(rows, widths)))
            buf[:na] = rows
            c = na
            for a, part in enumerate(parts):
                size = rows[a] * widths[a]
                buf[c:c + size] = part.reshape(size)
                c += size
            messages.append(buf)
        recv, offs = self._swap(nbrs, messages)
        incoming = [None] * len(DIRECTIONS)
        for i, (k, _) in enumerate(nbrs):
            buf = recv[offs[i]:offs[i + 1]]
            got = []
            c = na
            for a in range(na):
                n = int(buf[a])
                got.append(buf[c:c + n * widths[a]].reshape(n, widths[a]))
                c += n * widths[a]
            incoming[k] = tuple(got)
        return incoming

    def _swap(self, nbrs, messages):
        """Send messages[i] (float64 [*]) to neighbour nbrs[i] = (direction k, rank) and receive
        what each sent towards this block, sized by a matched probe (Mprobe): returns (recv, offs),
        neighbour i's message recv[offs[i]:offs[i + 1]], in nbrs' order."""
        cart, status, double = self.cart, self.status, self.double
        reqs = []
        for (k, r), msg in zip(nbrs, messages):
            reqs.append(cart.Isend(msg, dest=r, tag=EXCHANGE_TAG + k))
            self.account(r, msg.nbytes)
        probed = []
        offs = np.zeros(len(nbrs) + 1, dtype=np.int64)
        for i, (k, r) in enumerate(nbrs):
            # what neighbour k sent towards me travelled in the opposite direction
            probed.append(cart.Mprobe(source=r, tag=EXCHANGE_TAG + int(OPPOSITE[k]), status=status))
            offs[i + 1] = offs[i] + status.Get_count(double)
        recv = np.empty(int(offs[-1]))
        for i, msg in enumerate(probed):
            msg.Recv(recv[offs[i]:offs[i + 1]])
        self.waitall(reqs)
        return recv, offs

    # --- ghosts -----------------------------------------------------------------------------
    def _round_dirs(self):
        """The rounds of an exchange: lists of directions whose neighbours exist."""
        if self.halo == "26":
            return [[k for k, _ in self.neighbours]]
        rounds = []
        for axis in range(3):
            sweep = []
            for sign in (-1, 1):
                d = np.zeros(3, dtype=np.int64)
                d[axis] = sign
                k = int(np.flatnonzero((DIRECTIONS == d).all(axis=1))[0])
                if self.ranks[k] is not None:
                    sweep.append(k)
            rounds.append(sorted(sweep))
        return rounds

    def build(self, state, width, kind):
        """Choose the ghosts (a neighbour-rebuild step): drop old ghosts, send the particles within
        `width` of the block faces to the neighbours that need them with their full records,
        append the received ones after the owned particles, and fix the forward exchange's plan
        (index lists; its buffers and persistent requests at its first use) until the next
        rebuild. Returns the number of ghosts."""
        self.free()
        drop_ghosts(state)
        ncol, mwidth = self.record_widths(kind)
        self.with_quat = "quat" in moving_fields(kind)
        if self.halo == "26":
            return self._build_direct(state, width, kind, ncol, mwidth)
        n = state.n_owned
        for dirs in self._round_dirs():
            # a sweep along one axis forwards the ghosts of the earlier sweeps too, so edge and
            # corner neighbours are served in two or three hops (the same particles as the
            # direct exchange: the faces crossed are the same planes)
            outgoing = [None] * len(DIRECTIONS)
            lists = []
            for k in dirs:
                axis = int(np.flatnonzero(DIRECTIONS[k])[0])
                x = state.pos[:, axis]
                near = (x - self.lo[axis] < width) if DIRECTIONS[k][axis] < 0 else (self.hi[axis] - x < width)
                lists.append(np.flatnonzero(near))
            for k, idx in zip(dirs, lists):
                outgoing[k] = (self._records(state, kind, idx, ncol),)
            incoming = self.exchange(outgoing, (ncol,), dirs=dirs)
            counts = [len(incoming[k][0]) for k in dirs]
            send_idx = np.concatenate(lists).astype(np.int64) if lists else np.zeros(0, dtype=np.int64)
            self.rounds.append(_Round(self.cart, dirs, self.ranks, send_idx, [len(x) for x in lists], counts, state.n,
                                      mwidth, (self.wire, self.remote), self.entries))
            self._append(state, incoming, kind)
        # after the sweeps an edge or corner ghost was forwarded: its owner is found by place
        self.ghost_dirs = None
        return state.n - n

    @staticmethod
    @functools.lru_cache(maxsize=None)
    def record_widths(kind):
        """The widths [doubles] of a scene kind's ghost record and of its forward exchange's row."""
        return (sum(WIDTH[f] for f in ghost_fields(kind)), sum(WIDTH[f] for f in moving_fields(kind)))

    def _build_direct(self, state, width, kind, ncol, mwidth):
        """The direct exchange's ghost choice (--halo 26) in two numba calls and one message each
        way per neighbour: pack_border_messages selects the border particles and packs their
        records into the messages, write_border_messages writes the received ones after the owned
        rows of the halo's capacity arrays (_grow). Measured on 2 ranks, 1521 falling ellipsoids,
        --skin 0 (every step a rebuild; in-process timers, medians of 300 steps, two rounds
        alternating with the code before): 37-40 us a build against 56 us through border_lists,
        a record packing, the exchange's copy into a message and the append."""
        n = state.n_owned
        nbr_dirs = self.neighbour_dirs
        send, offs, send_idx, send_counts = call_entry(self.entries, pack_border_messages, (
            n, self.lo, self.hi, float(width), NEEDS, self.faces, nbr_dirs, kind, ncol, state.gid.view(np.float64),
            state.shape, state.material, state.mass, state.axes, state.inertia, state.pos, state.vel, state.angmom,
            state.quat, state.poly))
        recv, roffs = self._swap(self.neighbours, [send[offs[i]:offs[i + 1]] for i in range(len(nbr_dirs))])
        m = (len(recv) - len(nbr_dirs)) // ncol
        self.ghost_dirs = np.empty(m, dtype=np.int64)
        recv_counts = np.zeros(len(nbr_dirs), dtype=np.int64)
        if m:
            view = self._grow(state, m)
            call_entry(self.entries, write_border_messages, (n, recv, recv.view(np.int64), roffs, nbr_dirs, ncol, kind,
                                                             self.ghost_dirs, recv_counts, *view))
            self._finish_append(state, view)
        self.rounds.append(_Round(self.cart, self.neighbour_list, self.ranks, send_idx, send_counts, recv_counts, n,
                                  mwidth, (self.wire, self.remote), self.entries))
        if self.window is not None:
            self.window.layout(self.neighbour_list, send_counts)
        return m

    def _start(self, rd, state):
        rd.prepare()
        rd.call(pack_moving, (rd.send_idx, state.pos, state.vel, state.angmom, state.quat, self.with_quat, rd.send_buf))
        self.startall(rd.requests)
        self.traffic.add(rd.traffic)

    def publish(self, state):
        """Through the shared window (modes.window): write the owned particles' moving fields that the
        neighbours' ghosts take into this step's slot, before the step's allreduce. Returns whether
        they fit (True without a window or a round); where a rank's did not, every rank calls grow
        after the allreduce."""
        if self.window is None or not self.rounds:
            return True
        return self.window.publish(self.rounds[0].send_idx, state, self.with_quat, self.entries, call_entry)

    def grow(self, state):
        """Every rank, after an allreduce that said some rank's rows did not fit its segment: a new
        window, the rows written again (collective over the node)."""
        self.window.grow(self.rounds[0].send_idx, state, self.with_quat, self.entries, call_entry)

    def forward_start(self, state):
        """Pack the owned particles' moving fields for the first round of the next forward exchange
        and start its messages: called at the end of a step, after integration, so that they travel
        while the ranks agree on the next step (the collective decision), which also absorbs their
        skew. Completed by forward() on a step between rebuilds, discarded by build() on a rebuild.
        Nothing through a shared window (publish)."""
        if self.rounds and not self.started and self.window is None:
            self._start(self.rounds[0], state)
            self.started = True

    def _complete_started(self):
        if self.started:
            self.waitall(self.rounds[0].requests)
            self.started = False

    def forward(self, state):
        """Refresh the ghosts' moving fields from their owners (a step between rebuilds): per round,
        pack and start the persistent requests (the first round's may have been started by
        forward_start), wait, unpack. Allocates nothing. Through a shared window: copy the rows the
        neighbours published before the last step's allreduce (modes.window)."""
        if self.window is not None:
            rd = self.rounds[0]
            self.window.read(self.ranks, self.neighbour_list, rd.plan[4], rd.g0, state, self.with_quat, self.entries,
                             call_entry)
            return
        for i, rd in enumerate(self.rounds):
            if i == 0 and self.started:
                self.started = False
            else:
                self._start(rd, state)
            self.waitall(rd.requests)
            rd.call(unpack_moving, (rd.recv_buf, rd.g0, state.pos, state.vel, state.angmom, state.quat, self.with_quat))

    def free(self):
        """Complete a started exchange (its data is not needed) and release the persistent requests."""
        self._complete_started()
        for rd in self.rounds:
            rd.free()
        self.rounds = []

    def _records(self, state, kind, idx, ncol):
        """The ghost records [len(idx), ncol] of rows idx (pack_ghost_rows)."""
        out = np.empty((len(idx), ncol))
        call_entry(self.entries, pack_ghost_rows, (
            np.ascontiguousarray(idx, dtype=np.int64), kind, state.gid.view(np.float64), state.shape, state.material,
            state.mass, state.axes, state.inertia, state.pos, state.vel, state.angmom, state.quat, state.poly, out))
        return out

    def _append(self, state, incoming, kind):
        """Append the ghosts of the incoming records (pack_ghost_rows') after the state's rows, in
        place (_grow, write_ghost_rows). Against a concatenation per field (31 us a rebuild at 127
        ghosts, 2 ranks, 1521 falling ellipsoids), and the records' split into fields before it
        (13 us), ~3 us."""
        parts = [m[0] for m in incoming if m is not None and len(m[0])]
        if not parts:
            return
        rows = np.concatenate(parts) if len(parts) > 1 else parts[0]
        view = self._grow(state, len(rows))
        gids = np.ascontiguousarray(rows[:, 0]).view(np.int64)
        call_entry(self.entries, write_ghost_rows, (state.n, rows, gids, kind, *view))
        self._finish_append(state, view)

    def _grow(self, state, m):
        """The per-particle arrays (PER_PARTICLE order) with room for m rows after the state's n:
        views [n + m] of capacity arrays this halo keeps (self.store), grown by a quarter when they
        are too small or no longer the state's (a migration replaced them); the state's rows are
        then copied once."""
        n = state.n
        held = self.held
        if held is None or len(held[0]) < n + m or not all(map(operator.is_, [a.base for a in _PER_PARTICLE_OF(state)],
                                                                 held)):
            cap = (n + m) * 5 // 4 + 16
            store = self.store
            for f in PER_PARTICLE:
                old = getattr(state, f)
                store[f] = np.empty((cap,) + old.shape[1:], dtype=old.dtype)
                store[f][:n] = old[:n]
            held = self.held = tuple(store[f] for f in PER_PARTICLE)
        return [a[:n + m] for a in held]

    @staticmethod
    def _finish_append(state, view):
        """The state's arrays become the views; a poly-ellipsoid's bounding sphere holds its octant
        origin's offset too."""
        n = state.n
        for f, a in zip(PER_PARTICLE, view):
            setattr(state, f, a)
        if state.has_poly:
            state.rbound[n:] = bounding_radii(state.axes[n:], state.shape[n:], state.poly[n:])

    # --- migration ----------------------------------------------------------------------------
    def migrate(self, state, found=None):
        """Move owned particles whose centre left this block to the neighbour block that holds
        it, with their whole state and contact history (a neighbour-rebuild step; ghosts are
        dropped first; found: BlockGrid.leavers' (blocks [n_owned, 3], outside marks [n_owned], count) when
        already found). Returns (sent, received)."""
        drop_ghosts(state)
        n = state.n_owned
        if found is None or len(found[0]) != n:
            found = self.grid.leavers(state.pos[:n], self.coords)
        target = found[0]
        leaving = np.flatnonzero(found[1])
        if not len(leaving):  # nobody leaves: one message each way, of empty headers, says so
            incoming = self.exchange([None] * len(DIRECTIONS), self.migrant_widths(state))
            return 0, self._take_migrants(state, incoming)
        dirs = direction_of(self.coords, target[leaving])
        if np.any(dirs < 0):
            p = leaving[np.flatnonzero(dirs < 0)[0]]
            raise RuntimeError(f"particle {state.gid[p]} jumped more than a block in one step "
                               f"(time step far too large)")
        nw = state.wall_hist.shape[1]
        fields = _owner_fields(state)
        base = sum(WIDTH[f] for f in fields)
        widths = self.migrant_widths(state)
        ncol = widths[0]
        counts = np.diff(state.hist_start)
        out = [None] * len(DIRECTIONS)
        for k, r in self.neighbours:
            sel = leaving[dirs == k]
            rows = np.empty((len(sel), ncol))
            rows[:, :base] = _columns(state, fields, sel)
            rows[:, base:base + nw * HIST_LEN] = state.wall_hist.take(sel, axis=0).reshape(len(sel), nw * HIST_LEN)
            rows[:, -1] = counts[sel]
            hrows, _ = csr_rows(state.hist_start, sel)
            h = np.empty((len(hrows), 1 + HIST_LEN))
            h[:, 0] = state.hist_partner[hrows].view(np.float64)
            h[:, 1:] = state.hist_val.take(hrows, axis=0)
            out[k] = (rows, h)
        incoming = self.exchange(out, widths)
        keep = np.ones(n, dtype=bool)
        keep[leaving] = False
        state.permute_keep(np.flatnonzero(keep))
        return len(leaving), self._take_migrants(state, incoming)

    @staticmethod
    def migrant_widths(state):
        """The widths of a migration's two arrays: a migrant's record (its fields, wall history and
        count of history rows), and a history row (partner gid and values)."""
        base = sum(WIDTH[f] for f in _owner_fields(state))
        return (base + state.wall_hist.shape[1] * HIST_LEN + 1, 1 + HIST_LEN)

    @staticmethod
    def _take_migrants(state, incoming):
        """Append the migrants of a migration's incoming messages as owned rows; returns how many."""
        fields = _owner_fields(state)
        base = sum(WIDTH[f] for f in fields)
        nw = state.wall_hist.shape[1]
        parts = [m for m in incoming if m is not None and len(m[0])]
        if parts:
            rows = np.concatenate([p for p, _ in parts])
            hist = np.concatenate([h for _, h in parts])
            g = _split(rows[:, :base], fields)
            g["wall_hist"] = rows[:, base:base + nw * HIST_LEN].reshape(len(rows), nw, HIST_LEN)
            append_owned(state, g, rows[:, -1].astype(np.int64),
                         np.ascontiguousarray(hist[:, 0]).view(np.int64), hist[:, 1:])
        return sum(len(p) for p, _ in parts)


def redistribute(cart, grid, state, coords):
    """After a change of block grid: send every owned particle to the rank whose new block holds
    its centre (one all-to-all; owners may change by more than one block). Whole state and
    contact history travel, as in migration. Returns the number of particles this rank sent away."""
    drop_ghosts(state)
    n = state.n_owned
    target = grid.block_of(state.pos[:n])
    # one Get_cart_rank per block, not per particle (that was 3 us a particle: 19 ms of a 12k refit)
    dims = [int(d) for d in grid.dims]
    rank_of = np.array([cart.Get_cart_rank([i, j, k]) for i in range(dims[0]) for j in range(dims[1])
                        for k in range(dims[2])], dtype=np.int64).reshape(dims)
    dest = rank_of[target[:, 0], target[:, 1], target[:, 2]] if n else np.zeros(0, dtype=np.int64)
    me = cart.Get_rank()
    fields = _owner_fields(state)
    counts = np.diff(state.hist_start)
    outgoing = []
    for r in range(cart.Get_size()):
        sel = np.flatnonzero(dest == r) if r != me else np.zeros(0, dtype=np.int64)
        hrows, _ = csr_rows(state.hist_start, sel)
        outgoing.append((_columns(state, fields, sel), state.wall_hist.take(sel, axis=0), counts[sel],
                         state.hist_partner[hrows], state.hist_val.take(hrows, axis=0)))
    incoming = cart.alltoall(outgoing)  # rare: pickled lists are fine here
    state.permute_keep(np.flatnonzero(dest == me))
    for rows, wall, hc, hp, hv in incoming:
        if len(rows):
            g = _split(rows, fields)
            g["wall_hist"] = wall
            append_owned(state, g, hc, hp, hv)
    return int(np.count_nonzero(dest != me))


# a ghost's per-particle arrays: the state's but the wall history (owned particles only)
PER_PARTICLE = tuple(f for f in State.PER_PARTICLE if f != "wall_hist")
_PER_PARTICLE_OF = operator.attrgetter(*PER_PARTICLE)  # a state's per-particle arrays, in one call


def drop_ghosts(state):
    """Keep only the owned rows [0, n_owned)."""
    n = state.n_owned
    if state.n == n:
        return
    for f, a in zip(PER_PARTICLE, _PER_PARTICLE_OF(state)):
        setattr(state, f, a[:n])  # a view: appending ghosts makes new arrays anyway


def append_ghosts(state, g):
    """Append ghost rows (dict of gid, shape, material, mass, axes, inertia, pos, vel, angmom, quat
    and, in a scene with poly-ellipsoids, poly)."""
    m = len(g["gid"])
    shape = g["shape"].astype(np.int8)
    poly = g.get("poly", np.zeros((m, state.poly.shape[1])))
    new = {"gid": g["gid"].astype(np.int64), "shape": shape, "axes": g["axes"], "poly": poly,
           "rbound": bounding_radii(g["axes"], shape, poly), "mass": g["mass"], "inertia": g["inertia"],
           "material": g["material"].astype(np.int32), "pos": g["pos"], "vel": g["vel"], "quat": g["quat"],
           "angmom": g["angmom"], "force": np.zeros((m, 3)), "torque": np.zeros((m, 3))}
    for f in PER_PARTICLE:
        setattr(state, f, np.ascontiguousarray(np.concatenate([getattr(state, f), new[f]])))


def append_owned(state, g, hist_counts, hist_partner, hist_val):
    """Append migrated particles as owned rows, with their wall history and contact-history rows."""
    m = len(g["gid"])
    append_ghosts(state, g)
    state.n_owned += m
    state.wall_hist = np.ascontiguousarray(np.concatenate([state.wall_hist, g["wall_hist"]]))
    state.hist_start = np.concatenate([state.hist_start, state.hist_start[-1] + np.cumsum(hist_counts)])
    state.hist_partner = np.concatenate([state.hist_partner, hist_partner])
    state.hist_val = np.ascontiguousarray(np.concatenate([state.hist_val, hist_val]))
