"""Ghost exchange and particle migration between link blocks (MPI; no physics here).

Ghosts (commuT): every step each block sends the owned particles inside the border layer to
each neighbour that needs them, directly to all 26 neighbours (the paper's exchange, --halo 26)
or in three sweeps of two messages that forward what earlier sweeps brought (--halo 6: fewer,
larger messages; the same ghosts). The
message carries only what the contact kernels read: for a scene of spheres 14 doubles
(gid, material, mass, radius, moment of inertia, position, velocity, angular momentum: 112
bytes); otherwise 23 (plus shape, three semi-axes, three moments, quaternion: 184 bytes); in a
scene with poly-ellipsoids also the poly record (six semi-axes, octant-origin offset, principal ->
octant rotation: 18 doubles, 328 bytes in all). The paper sends 624 bytes per ellipsoid. Ghosts are exact binary copies, so each rank derives the
same rotation matrix and angular velocity from them as the owner does.

Migration (migraT): particles whose centre left the block move to the neighbour that owns it
with their whole state, wall history and contact history (rows keyed by partner gid), so the
tangential springs never reset (the paper's code loses them).

Messages are numpy float64 buffers sent with the uppercase (buffer) mpi4py calls: first the
row counts, then the rows, all with Irecv/Isend and one Waitall per round.
"""
import numpy as np

from dem.state import HIST_LEN, POLY_LEN, SPHERE, bounding_radii, csr_rows
from modes.decomposition import DIRECTIONS, OPPOSITE, direction_of, send_masks

GHOST_SPHERE = ("gid", "material", "mass", "axes0", "inertia0", "pos", "vel", "angmom")
GHOST_GENERAL = ("gid", "shape", "material", "mass", "axes", "inertia", "pos", "vel", "angmom", "quat")
GHOST_POLY = GHOST_GENERAL + ("poly",)
WIDTH = {"gid": 1, "shape": 1, "material": 1, "mass": 1, "axes0": 1, "inertia0": 1, "axes": 3, "inertia": 3,
         "pos": 3, "vel": 3, "angmom": 3, "quat": 4, "poly": POLY_LEN}


def ghost_fields(all_spheres, has_poly):
    """The fields a ghost carries: only what the scene's kernels read."""
    return GHOST_POLY if has_poly else GHOST_SPHERE if all_spheres else GHOST_GENERAL


def _owner_fields(state):
    """The fields of a migrating particle (with its histories besides)."""
    return GHOST_POLY if state.has_poly else GHOST_GENERAL


def _columns(state, fields, idx):
    """Rows idx of the state's fields as one float64 matrix [len(idx), sum widths] (gid and the
    small integer fields travel bit-exactly: gid by reinterpretation, the others as floats)."""
    cols = []
    for f in fields:
        if f == "gid":
            cols.append(state.gid[idx].view(np.float64)[:, None])
        elif f == "axes0":
            cols.append(state.axes[idx, :1])
        elif f == "inertia0":
            cols.append(state.inertia[idx, :1])
        else:
            a = getattr(state, f)[idx]
            cols.append(a.astype(np.float64).reshape(len(idx), WIDTH[f]))
    return np.ascontiguousarray(np.concatenate(cols, axis=1)) if cols else np.zeros((len(idx), 0))


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


class Halo:
    """Neighbour ranks of one block and the exchanges between them.

    cart: MPI Cartesian communicator (not periodic); grid: BlockGrid; coords: this block."""

    def __init__(self, cart, grid, coords, halo="26"):
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
        self.bytes_sent = 0

    def exchange(self, outgoing, widths, dirs=None):
        """Send outgoing[k] (a tuple of float64 arrays [rows_a, widths[a]], or None) to neighbour k
        and return what each neighbour sent (tuples; None where there is no neighbour). One round
        of row counts, then one round of data: two Waitalls whatever the number of arrays."""
        from mpi4py import MPI
        na = len(widths)
        ranks = [r if (dirs is None or k in dirs) else None for k, r in enumerate(self.ranks)]
        counts_in = {k: np.zeros(na, dtype=np.int64) for k, r in enumerate(ranks) if r is not None}
        sizes = {}
        reqs = []
        for k, r in enumerate(ranks):
            if r is None:
                continue
            # what neighbour k sent towards me travelled in the opposite direction
            reqs.append(self.cart.Irecv(counts_in[k], source=r, tag=int(OPPOSITE[k])))
        for k, r in enumerate(ranks):
            if r is None:
                continue
            sizes[k] = (np.array([len(a) for a in outgoing[k]], dtype=np.int64) if outgoing[k] is not None
                        else np.zeros(na, dtype=np.int64))
            reqs.append(self.cart.Isend(sizes[k], dest=r, tag=k))
        MPI.Request.Waitall(reqs)
        incoming = [None] * len(DIRECTIONS)
        reqs = []
        for k, r in enumerate(ranks):
            if r is None:
                continue
            incoming[k] = tuple(np.empty((int(counts_in[k][a]), widths[a])) for a in range(na))
            for a in range(na):
                if len(incoming[k][a]):
                    reqs.append(self.cart.Irecv(incoming[k][a], source=r, tag=100 + 32 * a + int(OPPOSITE[k])))
        for k, r in enumerate(ranks):
            if r is None or outgoing[k] is None:
                continue
            for a in range(na):
                if len(outgoing[k][a]):
                    buf = np.ascontiguousarray(outgoing[k][a])
                    self.bytes_sent += buf.nbytes
                    reqs.append(self.cart.Isend(buf, dest=r, tag=100 + 32 * a + k))
        MPI.Request.Waitall(reqs)
        return incoming

    # --- ghosts -----------------------------------------------------------------------------
    def exchange_ghosts(self, state, width, all_spheres):
        """Drop old ghosts, send border particles to the neighbours that need them and append
        the received ones after the owned particles. Returns the number of ghosts."""
        drop_ghosts(state)
        n = state.n_owned
        fields = ghost_fields(all_spheres, state.has_poly)
        ncol = sum(WIDTH[f] for f in fields)
        if self.halo == "26":
            # direct: each border particle goes straight to every neighbour that needs it
            masks = send_masks(state.pos[:n], self.lo, self.hi, width)
            outgoing = [None] * len(DIRECTIONS)
            for k, r in enumerate(self.ranks):
                if r is not None:
                    outgoing[k] = (_columns(state, fields, np.flatnonzero(masks[k])),)
            self._append(state, self.exchange(outgoing, (ncol,)), fields, all_spheres)
        else:
            # three sweeps (x, y, z) of two messages; each sweep forwards the ghosts received
            # in the earlier ones, so edge and corner neighbours are served in two or three hops
            # (the same particles as the direct exchange: the faces crossed are the same planes)
            for axis in range(3):
                pos = state.pos
                outgoing = [None] * len(DIRECTIONS)
                sweep = []
                for sign in (-1, 1):
                    d = np.zeros(3, dtype=np.int64)
                    d[axis] = sign
                    k = int(np.flatnonzero((DIRECTIONS == d).all(axis=1))[0])
                    sweep.append(k)
                    near = (pos[:, axis] - self.lo[axis] < width) if sign < 0 else (self.hi[axis] - pos[:, axis] < width)
                    if self.ranks[k] is not None:
                        outgoing[k] = (_columns(state, fields, np.flatnonzero(near)),)
                self._append(state, self.exchange(outgoing, (ncol,), dirs=sweep), fields, all_spheres)
        return state.n - n

    @staticmethod
    def _append(state, incoming, fields, all_spheres):
        parts = [m[0] for m in incoming if m is not None and len(m[0])]
        if not parts:
            return
        g = _split(np.concatenate(parts), fields)
        m = len(g["gid"])
        if all_spheres:
            g["shape"] = np.full(m, SPHERE, dtype=np.int64)
            g["quat"] = np.tile([1.0, 0.0, 0.0, 0.0], (m, 1))  # never read for spheres
        append_ghosts(state, g)

    # --- migration ----------------------------------------------------------------------------
    def migrate(self, state):
        """Move owned particles whose centre left this block to the neighbour block that holds
        it, with their whole state and contact history. Returns (sent, received)."""
        drop_ghosts(state)
        n = state.n_owned
        target = self.grid.block_of(state.pos[:n])
        leaving = np.flatnonzero(np.any(target != self.coords, axis=1))
        dirs = direction_of(self.coords, target[leaving])
        if np.any(dirs < 0):
            p = leaving[np.flatnonzero(dirs < 0)[0]]
            raise RuntimeError(f"particle {state.gid[p]} jumped more than a block in one step "
                               f"(time step far too large)")
        nw = state.wall_hist.shape[1]
        fields = _owner_fields(state)
        base = sum(WIDTH[f] for f in fields)
        ncol = base + nw * HIST_LEN + 1
        counts = np.diff(state.hist_start)
        out = [None] * len(DIRECTIONS)
        for k, r in enumerate(self.ranks):
            if r is None:
                continue
            sel = leaving[dirs == k]
            rows = np.empty((len(sel), ncol))
            rows[:, :base] = _columns(state, fields, sel)
            rows[:, base:base + nw * HIST_LEN] = state.wall_hist[sel].reshape(len(sel), nw * HIST_LEN)
            rows[:, -1] = counts[sel]
            hrows, _ = csr_rows(state.hist_start, sel)
            h = np.empty((len(hrows), 1 + HIST_LEN))
            h[:, 0] = state.hist_partner[hrows].view(np.float64)
            h[:, 1:] = state.hist_val[hrows]
            out[k] = (rows, h)
        incoming = self.exchange(out, (ncol, 1 + HIST_LEN))
        if len(leaving):
            keep = np.ones(n, dtype=bool)
            keep[leaving] = False
            state.permute_keep(np.flatnonzero(keep))
        parts = [m for m in incoming if m is not None and len(m[0])]
        if parts:
            rows = np.concatenate([p for p, _ in parts])
            hist = np.concatenate([h for _, h in parts])
            g = _split(rows[:, :base], fields)
            g["wall_hist"] = rows[:, base:base + nw * HIST_LEN].reshape(len(rows), nw, HIST_LEN)
            append_owned(state, g, rows[:, -1].astype(np.int64),
                         np.ascontiguousarray(hist[:, 0]).view(np.int64), hist[:, 1:])
        return len(leaving), sum(len(p) for p, _ in parts)


def redistribute(cart, grid, state, coords):
    """After a change of block grid: send every owned particle to the rank whose new block holds
    its centre (one all-to-all; owners may change by more than one block). Whole state and
    contact history travel, as in migration. Returns the number of particles this rank sent away."""
    drop_ghosts(state)
    n = state.n_owned
    target = grid.block_of(state.pos[:n])
    dest = np.array([cart.Get_cart_rank([int(c) for c in t]) for t in target], dtype=np.int64) \
        if n else np.zeros(0, dtype=np.int64)
    me = cart.Get_rank()
    fields = _owner_fields(state)
    counts = np.diff(state.hist_start)
    outgoing = []
    for r in range(cart.Get_size()):
        sel = np.flatnonzero(dest == r) if r != me else np.zeros(0, dtype=np.int64)
        hrows, _ = csr_rows(state.hist_start, sel)
        outgoing.append((_columns(state, fields, sel), state.wall_hist[sel], counts[sel],
                         state.hist_partner[hrows], state.hist_val[hrows]))
    incoming = cart.alltoall(outgoing)  # rare: pickled lists are fine here
    state.permute_keep(np.flatnonzero(dest == me))
    for rows, wall, hc, hp, hv in incoming:
        if len(rows):
            g = _split(rows, fields)
            g["wall_hist"] = wall
            append_owned(state, g, hc, hp, hv)
    return int(np.count_nonzero(dest != me))


PER_PARTICLE = ("gid", "shape", "axes", "rbound", "mass", "inertia", "material", "pos", "vel", "quat",
                "angmom", "force", "torque", "poly")


def drop_ghosts(state):
    """Keep only the owned rows [0, n_owned)."""
    n = state.n_owned
    if state.n == n:
        return
    for f in PER_PARTICLE:
        setattr(state, f, getattr(state, f)[:n])  # a view: appending ghosts makes new arrays anyway


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
