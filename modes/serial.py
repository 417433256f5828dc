"""Serial mode: one process, one thread; the reference trajectory every mode reproduces.

The step follows DESIGN.md. On a rebuild step (the first, and whenever a particle has moved
half the skin since the last one; every step with skin 0): contact history into the state's
per-particle rows, migrate and exchange ghosts (no-ops here), a spatial re-sort (with a skin),
then the neighbour estimate into the pair list (neighborT). Every step: contact resolution of
the pair list (resolveT), then one pass over the owned particles: gather (ascending partner
gid), walls, gravity, integration and the derived quantities of the new orientation. A step
between rebuilds is two kernel calls and allocates nothing. Timers wrap these phases here,
never inside kernels; the subclasses (modes/mpi.py) fill the migrate and ghost hooks.
"""
import copy
import time

import numpy as np

from dem.contact.ellipsoid import OUT_LEN
from dem.contact import CONTACT_METHODS, DEFAULT_CONTACT_METHOD
from dem.forces import (SUM, STORE, TAKEN, TERMS, body_arrays, finish_range, law_tables, resolve_range, scene_kind,
                        wall_arrays, wall_candidates)
from dem.integrate import derive_all
from dem.neighbor import cell_order, find_pairs
from dem.pairs import DEFAULT_SKIN, PairList
from dem.shapes import SPHERE
from modes.base import ModeError, call_entry, register


# the warm-up twin's largest size (SerialMode._twin_state)
WARMUP_PARTICLES = 2000


@register("serial")
class SerialMode:
    """Reference step driver. options: neighbor ('allpairs' | 'linkcell'); skin: the neighbour
    list's skin as a fraction of the largest bounding diameter (None: dem.pairs.DEFAULT_SKIN; 0:
    estimate neighbours every step, the paper's way); contact_method: ellipsoid contact geometry,
    one of dem.contact.CONTACT_METHODS."""

    clock = staticmethod(time.perf_counter)
    collective = False   # whether decide() communicates (its time is then commuT)
    guard_overlap = 0.05  # the stability guard's overlap limit (bench.run.guard sets it)
    deliver = SUM         # one thread sums the pair forces as it resolves them (dem.forces.resolve_range)
    migrates = False      # particles change rank at rebuilds (MPI): history then travels through the state
    owned_derived = False  # the owned particles' rot, omega are current (the last step's pass; build_list)
    carry_sorted = None   # how a rebuild carries the history of a gid-sorted list (None: dem.pairs' merge)
    wall_list = staticmethod(wall_candidates)   # the rebuild's wall list (threads: their own loop)
    placing_s = 0.0   # the part of find_pairs [s] that sorted the list and carried its history (threads)

    def setup(self, scene, dt, neighbor="linkcell", skin=None, contact_method=DEFAULT_CONTACT_METHOD, **options):
        if options:
            raise ModeError(f"unknown option(s) for the {self.name} mode: {', '.join(sorted(options))}")
        if contact_method not in CONTACT_METHODS:
            raise ModeError(f"unknown contact method {contact_method!r} ({', '.join(CONTACT_METHODS)})")
        if neighbor not in ("allpairs", "linkcell"):
            raise ModeError(f"unknown neighbour method {neighbor!r} (allpairs, linkcell)")
        self.contact_method = contact_method
        self.method = CONTACT_METHODS.index(contact_method)
        self.scene = scene
        self.state = scene.state
        self.dt = float(dt)
        self.neighbor = neighbor
        self.g = np.asarray(scene.gravity, dtype=np.float64)
        self.has_gravity = bool(np.any(self.g != 0.0))
        self.gravity = (float(self.g[0]), float(self.g[1]), float(self.g[2]), self.has_gravity)
        self.law = law_tables(scene.materials)
        self.touches_walls = True   # MPI: whether this block touches a wall (modes/mpi.py)
        self.no_walls = (np.zeros((0, 3)), np.zeros(0))
        self.kind = scene_kind(self.state.shape, self.state.has_poly)
        self.octants = self.state.has_poly   # every particle's octant geometry derived (dem.integrate)
        self.skin_fraction = DEFAULT_SKIN if skin is None else float(skin)
        self.skin = self.skin_fraction * 2.0 * float(self.state.rbound.max()) if self.state.n else 0.0
        self.max_overlap_ratio = 0.0
        self.worst = ("pair", -1)
        self._fresh()
        return self

    def _fresh(self):
        """Per-run buffers: pair list, derived arrays, scratch; the next step rebuilds."""
        self.pairs = PairList(max(1024, 8 * self.state.n))
        self.entries = {}  # kernel_call's compiled entry points, by call name (modes.base call_entry)
        self.seen = {}     # the (key, epoch) of each call name's last call: a new one checks the arrays' types
        self.epoch = 0  # rebuilds so far: the kernels' arguments may take other types after one (kernel_call)
        self.rebuild_next = True
        self.rot = None
        self.derived_store = None  # the capacity arrays behind rot, omega, oorg, orot, ax6 (ensure_derived)
        self.out = np.zeros(OUT_LEN)
        self.n0 = np.zeros(3)
        self.gat = np.zeros(0, dtype=np.int8)   # the particles that gather (threads: SPLIT)
        # the state's wall histories when the last wall list was made (build_list): while the same
        # array, the particles are stored as they were, and only those on that list may hold one
        self.listed = None
        self.no_near = np.zeros(0, dtype=np.int8)
        self.no_terms = np.zeros((0, TERMS))     # the cross pairs' terms of TAKEN (MPI: modes.newton)
        self.taking = (self.deliver, self.no_terms)  # how resolve delivers, and the terms it takes (split)
        self.ensure_derived()

    def warmup(self):
        """Compile every kernel by stepping a twin three times: a first build, a step between
        rebuilds (with what a mode does only now and then between rebuilds: warm_between) and a
        rebuild that carries history over (nothing of it is kept; under MPI every rank does it
        together)."""
        twin = copy.copy(self)
        twin.state = self._twin_state()
        twin._fresh()
        for rebuild in (True, False, True):
            twin.rebuild_next = rebuild
            if not rebuild:
                twin.warm_between()
            twin.step()
        twin.release()

    def warm_between(self):
        """Before the warm-up's step between rebuilds: make that step run the rare paths of such a
        step (here none)."""

    def _twin_state(self):
        """The warm-up twin's state: a deep copy, or for more than WARMUP_PARTICLES owned particles
        the WARMUP_PARTICLES nearest the first one, with their history (a compact piece of the same
        scene: the same kernels compile, in a time that does not grow with n; issue 14)."""
        s = self.state
        if s.n_owned <= WARMUP_PARTICLES or s.n != s.n_owned:
            return copy.deepcopy(s)
        d2 = np.sum((s.pos[:s.n_owned] - s.pos[0]) ** 2, axis=1)
        twin = copy.copy(s)
        twin.permute_keep(np.sort(np.argpartition(d2, WARMUP_PARTICLES)[:WARMUP_PARTICLES]))  # new arrays
        return twin

    def release(self):
        """Free what the mode holds outside Python's reach (MPI requests); nothing here."""

    # --- phases -------------------------------------------------------------------------------
    def ensure_derived(self):
        """Rotation matrices [n,3,3] and angular velocities [n,3] sized to the current n (MPI
        changes n at rebuilds: ghosts and migrants); in a scene with poly-ellipsoids also the
        octant geometry oorg [n,3], orot [n,3,3], ax6 [n,6] (empty otherwise). Then the kernels'
        bodies and polys groups (dem.forces) over the current arrays: they are bound here, at
        every rebuild, the only time the state's arrays are replaced (re-sorting, migration,
        ghosts); a step between rebuilds allocates nothing."""
        n = self.state.n
        if self.rot is None or self.rot.shape[0] != n:
            store = self.derived_store
            if store is None or store[0].shape[0] < n:
                # where n changes at every rebuild (MPI: ghosts, migrants) the arrays are views of
                # capacity arrays, so that the owned rows a step's pass derived stay where they are
                # (build_list then derives the ghosts only): grown by a quarter, their rows kept
                cap = n + n // 4 + 16 if self.migrates else n
                g = cap if self.octants else 0
                fresh = (np.zeros((cap, 3, 3)), np.zeros((cap, 3)), np.zeros((g, 3)), np.zeros((g, 3, 3)),
                         np.zeros((g, 6)))
                if store is None:
                    self.owned_derived = False
                else:
                    for a, b in zip(fresh, store):
                        a[:b.shape[0]] = b
                store = self.derived_store = fresh
            g = n if self.octants else 0
            self.rot, self.omega = store[0][:n], store[1][:n]
            self.oorg, self.orot, self.ax6 = store[2][:g], store[3][:g], store[4][:g]
        self.bodies = body_arrays(self.state, self.rot, self.omega)
        self.polys = (self.state.poly, self.oorg, self.orot, self.ax6)

    def derive(self, lo, hi):
        """Derived quantities of particles lo..hi-1 (all of them after a rebuild; ghosts after a
        forward exchange), through the kernel's entry point (kernel_call: its dispatcher typed the
        bodies and polys groups at every call, ~2 us more)."""
        self.kernel_call("derive", derive_all, (lo, hi, self.bodies, self.polys, self.octants))

    def sync_history(self):
        """Write the pair list's contact history into the state's per-particle rows (the form that
        migrates, is cached and restarts)."""
        s = self.state
        s.hist_start, s.hist_partner, s.hist_val = self.pairs.history(s.gid, s.n_owned)

    def leaver_history(self):
        """At a rebuild that migrates (MPI), before migration: the state's per-particle rows of the
        particles that will leave (here: every owned particle's, sync_history)."""
        self.sync_history()

    def reorder(self):
        """With a skin, re-sort the owned particles at each rebuild, for locality (memory order never
        changes results: DESIGN.md, Determinism): by global id where the pairs are resolved in gid
        order (one thread, or threads over ranges of the sorted list), else in space (cell order)."""
        s = self.state
        if self.skin <= 0 or s.n != s.n_owned or s.n < 2:
            return
        if self.deliver != STORE:
            if np.any(s.gid[1:] < s.gid[:-1]):
                s.permute(np.argsort(s.gid, kind="stable"))
                self.owned_derived = False
        else:
            s.permute(cell_order(s.pos, 2.0 * float(s.rbound.max())))
            self.owned_derived = False

    def find_pairs(self, radii):
        """Candidate pairs whose spheres of radii [n] overlap, into the pair list's buffers (the
        mode's loop strategy); returns their number. The estimate's kernel through its compiled
        entry point (kernel_call)."""
        s = self.state
        return find_pairs(self.neighbor, s.pos, radii, s.gid, s.n_owned, self.pairs.buffers, self._estimate_call)

    def _estimate_call(self, kernel, args):
        return self.kernel_call("estimate_pairs", kernel, args)

    def build_list(self, rows=True, ref=None):
        """The neighbour list: pairs within r_i + r_j + skin, their history (carried from the last
        list, or from the state's rows on a first build and where particles migrate; rows=False:
        no particle came since the state's rows were written, MPI's relist), its reference
        positions (ref [n_owned, 3], the list's own to keep: MPI's relist keeps the halo's
        rebuild's; None: the owned positions now), and the wall list
        (the particles within their bounding radius plus half the skin of a wall)."""
        self.epoch += 1  # the kernels' arguments may take other types now (kernel_call)
        clock = self.clock
        t0 = clock()
        s = self.state
        self.ensure_derived()
        # the owned particles' rot and omega are the step's pass's own (finish) unless their arrays
        # were made anew or moved since: then all are derived (the pass and this derive give the
        # same numbers: dem.integrate derive_particle); ghosts always (MPI)
        lo = s.n_owned if self.owned_derived else 0
        if lo < s.n:
            self.derive(lo, s.n)
        t1 = clock()
        reach = s.rbound + 0.5 * self.skin if self.skin > 0 else s.rbound
        m = self.find_pairs(reach)
        t2 = clock()
        # the first build takes the state's own (loaded) history; later ones carry the list's own,
        # and where particles migrated (MPI) the pairs of those that came take their rows (state)
        self.pairs.set(m, s.gid, s.n_owned, s.hist_start, s.hist_partner, s.hist_val, s.pos,
                       by_gid=self.deliver != STORE, carry=bool(self.pairs.rebuilds), rows=self.migrates and rows,
                       carry_sorted=self.carry_sorted, ref=self._list_ref(ref))
        t3 = clock()
        was = self.pairs.near
        if self.listed is not s.wall_hist or was.shape[0] != s.n_owned:
            was = self.no_near   # stored anew (re-sorted, migrated, a first list): every history is closed
        self.pairs.near = np.zeros(s.n_owned, dtype=np.int8)
        self.wall_list(s.n_owned, s.pos, reach, *self.wall_planes(), s.wall_hist, self.pairs.near, was)
        self.listed = s.wall_hist
        self.plist = self.pairs.arrays
        t4 = clock()
        self.split()
        t5 = clock()
        self.adj = self.pairs.gather_arrays(self.deliver, self.gat)
        t6 = clock()
        # the rebuild's phases [s] (bench perf --what phases); a few clock reads a rebuild. The list's
        # sort by gid and its history carry count as carry wherever they run (the threads do both as
        # they place the list, in find_pairs: placing_s)
        placing = self.placing_s
        self.build_phases = {"derive": t1 - t0, "find_pairs": t2 - t1 - placing, "carry": t3 - t2 + placing,
                             "wall_list": t4 - t3, "cut": t5 - t4, "gather_list": t6 - t5}

    def _list_ref(self, keep):
        """The new list's reference positions: keep where given (no copy of the owned positions
        only to be replaced), else rebuild_ref's (the threads' wall list still fills the array it
        hands out)."""
        fill = self.rebuild_ref()
        return fill if keep is None else keep

    def rebuild_ref(self):
        """The array that is to hold the owned positions at this rebuild (PairList.ref) where the
        mode fills it itself, else None: the list copies them (threads: modes.threads)."""
        return None

    def split(self, cross=None, terms=None):
        """Who resolves which pairs of a new list (threads: modes/threads.py): here the one thread
        resolves them all, summing as it goes (SUM), or, given cross [c] (the ascending indices of
        the pairs with a ghost end: MPI with Newton's third law, modes.newton), takes their terms
        [c, TERMS] in their place (TAKEN)."""
        self.taking = (self.deliver, self.no_terms) if cross is None else (TAKEN, terms)

    def migrate(self):
        """Hand particles that left the block to their new owner (MPI); returns how many left."""
        return 0

    def ghosts(self, rebuild):
        """Exchange ghosts (MPI): new ones on a rebuild, else the moving fields of the same ones."""

    def start_forward(self):
        """Start the next step's ghost refresh at the end of this one, once it is decided that the
        next step does not rebuild (MPI); nothing here."""

    def decide(self, max_disp2, flag, ke, wg):
        """Whether the next step rebuilds (some particle moved half the skin), and the run's sums
        for the stability guard, self.sums = (flagged, kinetic energy [J], gravity work [J]) from
        this rank's flag (a non-finite particle or an overlap above guard_overlap) and sums. Under
        MPI both are one allreduce (its time is commuT)."""
        self.sums = (flag, ke, wg)
        return self.skin <= 0 or max_disp2 >= (0.5 * self.skin) ** 2

    def kernel_call(self, name, kernel, args, key=None):
        """kernel(*args) through its compiled entry point (modes.base call_entry, one per call name).
        Between rebuilds a step passes the same arrays, so their types cannot change. The first call
        after a rebuild (the arrays replaced) or with a new key checks that the arguments' type
        fingerprint is the one the entry was found for, and goes through the dispatcher (which
        compiles where needed) only where it is not (the dispatcher and a new lookup cost ~3.5 us a
        kernel at every rebuild)."""
        seen = (key, self.epoch)
        check = self.seen.get(name) != seen
        if check:
            self.seen[name] = seen
        return call_entry(self.entries.setdefault(name, {}), kernel, args, check)

    def resolve(self):
        """Contact resolution of the pair list (as split fixed it); returns dem.forces.RESOLVED."""
        deliver, terms = self.taking
        return self.kernel_call("resolve", resolve_range, (
            self.kind, self.method, 0, self.pairs.m, self.plist, self.bodies, self.polys, self.law, self.dt,
            deliver, self.state.n_owned, self.gat, terms, self.out, self.n0))

    def resolve_stored(self, name, plist, m):
        """Contact resolution of another list plist (pi, pj, hist, on, pf) of m pairs, every pair's
        forces stored into its pf (STORE: MPI with Newton's third law, the pairs whose other end's
        terms travel); returns dem.forces.RESOLVED."""
        return self.kernel_call(name, resolve_range, (
            self.kind, self.method, 0, m, plist, self.bodies, self.polys, self.law, self.dt, STORE,
            self.state.n_owned, self.gat, self.no_terms, self.out, self.n0))

    @property
    def has_walls(self):
        """Whether the step has a wall pass (a scene with walls, a block that touches one)."""
        return bool(len(self.scene.walls)) and self.touches_walls

    def wall_planes(self):
        """Wall planes (normals [n_walls, 3], offsets [n_walls]) this rank's particles can touch;
        read from the scene each step (a build moves them)."""
        return (self.scene.wall_m, self.scene.wall_d) if self.has_walls else self.no_walls

    def walls(self):
        """The kernels' walls group (dem.forces.wall_arrays) of this step."""
        return wall_arrays(*self.wall_planes(), self.scene.materials, self.state.wall_hist)

    def finish(self):
        """Gather, walls, integration, derived quantities and guard sums; returns dem.forces.FINISHED."""
        walls = self.walls()  # the scene's planes may be replaced between rebuilds (a build moves them)
        return self.kernel_call("finish", finish_range, (
            0, self.state.n_owned, self.kind == SPHERE, self.deliver, self.adj, self.bodies, walls, self.polys,
            self.gravity, self.dt, self.octants, self.pairs.ref, self.out), key=(id(walls[0]), id(walls[1])))

    @property
    def worst_contact(self):
        """The deepest contact of the last step by global ids: (i, j), (i, "wall") or None."""
        what, k = self.worst
        gid = self.state.gid
        if k < 0:
            return None
        if what == "wall":
            return int(gid[k]), "wall"
        return int(gid[self.pairs.pi[k]]), int(gid[self.pairs.pj[k]])

    # --- contact detection alone (bench schemes: the paper's Table 1) --------------------------
    def neighbour_phase(self):
        """The neighbour estimate on the current positions into the pair list (with its history
        and adjacency); returns (pi, pj)."""
        self.build_list()
        return self.pairs.pi, self.pairs.pj

    def resolve_phase(self, pi=None, pj=None):
        """Contact resolution of the current pair list; positions do not move."""
        return self.resolve()

    def step(self):
        """One time step; returns the phase times [s] and counters of DESIGN.md's steps.csv."""
        clock = self.clock
        t0 = clock()
        rebuild = self.rebuild_next
        migra = commu = 0.0
        sent = 0
        if rebuild:
            if self.pairs.rebuilds and self.migrates:  # history rows travel with migrants
                self.leaver_history()
            ta = clock()
            sent = self.migrate()
            tb = clock()
            self.reorder()
            tc = clock()
            self.reorder_s = tc - tb
            self.ghosts(True)
            td = clock()
            self.build_list()
            migra, commu = tb - ta, td - tc
        else:
            tc = clock()
            self.ghosts(False)
            commu = clock() - tc
            if self.relist_every_step:  # MPI, skin 0 with a halo skin: the list alone, on the same particles
                self.relist()
            elif self.state.n > self.state.n_owned:  # ghosts moved: their rotations and spins
                self.derive(self.state.n_owned, self.state.n)
        t1 = clock()
        relisted = rebuild or self.relist_every_step
        neighbor = t1 - t0 - commu - migra if relisted else 0.0
        nc, calls, worst, worst_k, rsum = self.resolve()
        t2 = clock()
        n_wall, wall_worst, wall_p, ke, wg, n_bad, first_bad, disp2 = self.finish()
        # the pass derived every owned particle's rot and omega: the next rebuild need not derive
        # them again (issue 33: 16 us of a 308 us serial step of the 1521 falling ellipsoids at
        # --skin 0) unless their rows move before it (re-sorting, migration: they clear this)
        self.owned_derived = True
        pair_worst = worst
        if wall_worst > worst:
            worst = wall_worst
        t3 = clock()
        self.finish_s = t3 - t2
        self.rebuild_next = self.decide(disp2, float(n_bad > 0 or worst > self.guard_overlap), ke, wg)
        if not self.rebuild_next:
            self.start_forward()
        t4 = clock()
        commu += t4 - t3 if self.collective else 0.0
        s = self.state
        self.worst = ("wall", wall_p) if wall_worst > pair_worst else ("pair", worst_k)
        self.max_overlap_ratio = max(self.max_overlap_ratio, worst)
        total = t4 - t0
        return {"totalT": total, "commuT": commu, "migraT": migra, "compuT": total - commu - migra,
                "neighborT": neighbor, "resolveT": t2 - t1,
                "n_owned": s.n_owned, "n_ghost": s.n - s.n_owned, "n_contacts": nc, "n_wall_contacts": n_wall,
                "n_candidates": self.pairs.m, "neighbor_rebuilt": int(relisted),
                "halo_rebuilt": int(rebuild and self.collective), "n_migrated": sent,
                "bytes_sent": 0, "ellipsoid_calls": calls, "max_overlap_ratio": worst,
                "pair_overlap_ratio_sum": rsum, "pair_worst_ratio": pair_worst,
                "kinetic_energy": ke, "gravity_work": wg, "n_bad": n_bad,
                "first_bad": int(s.gid[first_bad]) if first_bad >= 0 else -1}

    def snapshot(self):
        return self.state.snapshot()

    # --- the mode contract's rest (modes.base.Mode) ---------------------------------------------
    sums = (0.0, 0.0, 0.0)  # (flagged, kinetic energy [J], gravity work [J]) of the last step (decide)
    # a step that does not rebuild the halo rebuilds the list all the same (relist; MPI at skin 0)
    relist_every_step = False

    @classmethod
    def accepts(cls, mapping):
        """One process, one thread (1-1-1-1-1)."""
        return mapping.procs == 1 and mapping.threads == 1

    def run_info(self, end=False):
        """The mode's part of run.json. At the start: skin (a fraction of the largest bounding
        diameter) and skin_m [m], newton and balance (MPI; None here). At the end (end=True): the
        neighbour rebuilds, grid updates and final block cuts (MPI), thread re-cuts (threads)."""
        if end:
            return {"neighbor_rebuilds": self.pairs.rebuilds, "grid_updates": None, "thread_recuts": None,
                    "block_cuts_final": None}
        return {"skin": self.skin_fraction, "skin_m": self.skin, "halo_skin": None, "halo_skin_m": None,
                "newton": None, "balance": None}
