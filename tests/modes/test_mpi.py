"""MPI and hybrid modes, launched through `bench run` (mpiexec started by the harness, with a
timeout): every mapping reproduces the serial trajectory bit for bit."""
import json
import os

import numpy as np
import pandas as pd
import pytest

from bench.run.transport import MPICH_EAGER
from tests.helpers import GOOD, assert_same, bench, mpi_run, one_line_error, serial_state, write

pytestmark = pytest.mark.skipif(not os.path.exists(os.path.join(os.path.dirname(os.sys.executable), "mpiexec"))
                                and not __import__("shutil").which("mpiexec"), reason="no mpiexec")


@pytest.mark.parametrize("mapping", ["2-2-1-1-1", "2-1-2-1-1", "4-2-2-1-1", "3-3-1-1-1"])
def test_patch162_bit_identical(tmp_path, tmp_path_factory, mapping):
    """The paper's patch test on 2, 3 and 4 blocks: the deposited ellipsoids touch across block
    borders from step 1; the final state equals the serial one exactly."""
    ref = serial_state(tmp_path_factory, "patch162", 150)
    got, steps, info = mpi_run(tmp_path, "patch162", 150, mapping)
    assert_same(ref, got)
    assert (steps.groupby("step")["rank"].count() == info["procs"]).all()
    assert steps["n_ghost"].sum() > 0 and steps["bytes_sent"].sum() > 0


@pytest.mark.parametrize("mapping", ["2-2-1-1-1", "3-1-3-1-1", "4-2-2-1-1", "8-2-2-2-1"])
def test_gas_crossing_borders_bit_identical(tmp_path, tmp_path_factory, mapping):
    """A soft granular gas with walls: particles migrate across block faces, edges and corners
    (8 = 2x2x2 blocks) many times, carrying their contact history; bit-identical to serial."""
    ref = serial_state(tmp_path_factory, "gas", 2500)
    got, steps, _ = mpi_run(tmp_path, "gas", 2500, mapping)
    assert steps["n_migrated"].sum() > 10
    assert steps["n_contacts"].sum() > 0
    assert_same(ref, got)


@pytest.mark.parametrize("scheme", ["partition", "frogleap", "headtail", "static", "dynamic"])
def test_hybrid_bit_identical(tmp_path, tmp_path_factory, scheme):
    """Hybrid 2 processes x 2 threads with each scheme, on the gas (migration) scene."""
    ref = serial_state(tmp_path_factory, "gas", 2500)
    got, steps, info = mpi_run(tmp_path, "gas", 2500, "2-2-1-1-2", "--scheme", scheme)
    assert info["threads"] == 2 and info["scheme"] == scheme
    assert steps["n_migrated"].sum() > 0
    assert_same(ref, got)


@pytest.mark.parametrize("mapping,scheme", [("2-2-1-1-2", "dynamic"), ("2-1-2-1-3", "static")])
def test_hybrid_patch162_bit_identical(tmp_path, tmp_path_factory, mapping, scheme):
    """Hybrid on the patch test: each rank's threads resolve ranges of its gid-sorted list, whose
    pairs reach ghosts (never summed there) and particles of two ranges (gathered); the contacts
    cross block borders from step 1; bit-identical to serial."""
    ref = serial_state(tmp_path_factory, "patch162", 150)
    got, steps, info = mpi_run(tmp_path, "patch162", 150, mapping, "--scheme", scheme)
    assert info["threads"] == int(mapping.split("-")[-1])
    assert steps["n_ghost"].sum() > 0 and steps["n_contacts"].sum() > 0
    assert_same(ref, got)


def scene_with(particles, box="[[0.0, 0.0, 0.0], [0.02, 0.02, 0.02]]"):
    head = GOOD.split("[[particles]]")[0].replace('box = [[0.0, 0.0, 0.0], [0.02, 0.02, 0.04]]', f"box = {box}")
    head = head.replace('gravity = [0.0, 0.0, -9.81]', 'gravity = [0.0, 0.0, -9.81]')
    body = "".join(f"""
[[particles]]
shape = "{shape}"
axes = {axes}
pos = {pos}
vel = {vel}
""" for shape, axes, pos, vel in particles)
    return head + body


EDGE_CASES = {
    # centre exactly on the block face x = 0.01 (owned by the upper block); neighbours 10-50 um
    # away on both sides of the face run into it (overlaps start by motion, as the guard wants)
    "on-face": [("sphere", [1e-3], [0.01, 0.01, 0.0011], [0.0, 0.0, 0.0]),
                ("sphere", [1e-3], [0.00799, 0.01, 0.0011], [0.2, 0.0, 0.0]),
                ("ellipsoid", [1e-3, 8e-4, 6e-4], [0.01205, 0.0101, 0.0011], [-0.1, 0.0, 0.0])],
    # everything in one block of four: three blocks stay empty until particles arrive
    "one-block": [("sphere", [1e-3], [0.003, 0.003, 0.0011], [0.3, 0.3, 0.0]),
                  ("sphere", [1e-3], [0.0055, 0.003, 0.0011], [0.0, 0.2, 0.0]),
                  ("ellipsoid", [1e-3, 8e-4, 6e-4], [0.003, 0.006, 0.0011], [0.2, 0.0, 0.0])],
}


@pytest.mark.parametrize("case", sorted(EDGE_CASES))
def test_edge_cases_bit_identical(tmp_path, case):
    """A particle exactly on a block face, empty blocks and all particles in one block."""
    scene = write(tmp_path, scene_with(EDGE_CASES[case]), f"{case}.toml")
    ref_out = tmp_path / "serial"
    res = bench("run", "--scene", scene, "--steps", "600", "--out", str(ref_out), "--quiet")
    assert res.returncode == 0, res.stderr
    ref = dict(np.load(ref_out / "state.npz"))
    got, steps, _ = mpi_run(tmp_path, scene, 600, "4-2-2-1-1")
    assert_same(ref, got)
    if case == "on-face":
        assert steps["n_contacts"].sum() > 0
    if case == "one-block":
        first = steps[steps["step"] == 1]
        assert sorted(first["n_owned"].tolist()) == [0, 0, 0, 3]


def test_particle_larger_than_block_refused(tmp_path):
    """Blocks narrower than the largest particle's bounding diameter are refused in one line."""
    scene = write(tmp_path, scene_with(EDGE_CASES["on-face"]))
    one_line_error(bench("run", "--scene", scene, "--mapping", "16-16-1-1-1", "--out", str(tmp_path / "o")),
                   "use fewer blocks along x")


def test_records_of_a_pure_mpi_run(tmp_path):
    """steps.csv has one row per step and rank with commuT, migraT, ghosts and bytes; compuT is
    totalT - commuT - migraT; run.json names the MPI library and the transport variables the
    launcher gave the ranks (bench.run.transport.MPICH_EAGER: 128 KiB cells)."""
    _, steps, info = mpi_run(tmp_path, "gas", 50, "2-2-1-1-1")
    assert len(steps) == 2 * 50 and set(steps["rank"]) == {0, 1}
    # ghosts travel every step; migration only on the neighbour-list rebuilds (the first step and
    # whenever a particle has moved half the skin)
    rebuilt = steps["neighbor_rebuilt"] == 1
    assert (steps["commuT"] > 0).all() and (steps["migraT"][rebuilt] > 0).all()
    assert (steps["migraT"][~rebuilt] == 0).all() and rebuilt.sum() < len(steps)
    assert np.allclose(steps["compuT"], steps["totalT"] - steps["commuT"] - steps["migraT"])
    assert steps["n_owned"].groupby(steps["step"]).sum().eq(300).all()
    assert "MPICH" in info["mpi_library"] or "Open MPI" in info["mpi_library"]
    assert info["mpi_transport"] == MPICH_EAGER and MPICH_EAGER["MPIR_CVAR_CH4_SHM_POSIX_IQUEUE_CELL_SIZE"] == "131072"


def test_six_message_halo_same_ghosts(tmp_path, tmp_path_factory):
    """--halo 6 (three sweeps forwarding ghosts) delivers exactly the ghosts of the direct
    26-neighbour exchange on 2x2x2 blocks (same count every step) and the serial trajectory."""
    ref = serial_state(tmp_path_factory, "gas", 2500)
    got6, steps6, info = mpi_run(tmp_path, "gas", 2500, "8-2-2-2-1", "--halo", "6")
    assert info["halo"] == "6"
    assert_same(ref, got6)
    _, steps26, _ = mpi_run(tmp_path / "direct", "gas", 2500, "8-2-2-2-1")
    assert steps6["n_ghost"].tolist() == steps26["n_ghost"].tolist()


def test_update_grid_bit_identical(tmp_path, tmp_path_factory):
    """The paper's updateGrid: re-fitting the block grid to the settling pluviation every 500
    steps hands particles to new owners (whole state and history) without changing a bit."""
    ref = serial_state(tmp_path_factory, "pluviation", 10000, ("--particles", "300"))
    got, steps, info = mpi_run(tmp_path, "pluviation", 10000, "2-1-1-2-1", "--particles", "300",
                               "--update-grid", "500")
    assert info["grid_updates"] >= 10
    assert steps["n_contacts"].sum() > 0
    assert_same(ref, got)


def test_every_step_estimate_bit_identical(tmp_path, tmp_path_factory):
    """--skin 0 --halo-skin 0 (the paper's every-step neighbour estimate, ghosts chosen every step,
    as the paper's code does) on 2 and on 2x2x2 blocks with the three-sweep halo: the serial
    trajectory bit for bit. Both kinds of rebuild occur: steps where some rank sends migrants (the
    migration's message round) and steps where none does, whose round the step before's collective
    decision skipped (modes.mpi decide)."""
    ref = serial_state(tmp_path_factory, "gas", 2500)
    for mapping, extra in (("2-2-1-1-1", ()), ("8-2-2-2-1", ("--halo", "6"))):
        got, steps, info = mpi_run(tmp_path / mapping, "gas", 2500, mapping, "--skin", "0", "--halo-skin", "0",
                                   *extra)
        assert info["skin"] == 0.0 and info["halo_skin"] == 0.0
        assert (steps["neighbor_rebuilt"] == 1).all() and (steps["halo_rebuilt"] == 1).all()
        moved = steps.groupby("step")["n_migrated"].sum()
        assert 0 < (moved > 0).sum() < len(moved) - 100, (moved > 0).sum()
        assert_same(ref, got)


def test_every_step_estimate_with_a_halo_skin(tmp_path, tmp_path_factory):
    """--skin 0 with the halo's own skin (default 0.1 of the largest bounding diameter, modes.mpi
    DEFAULT_HALO_SKIN): the list is rebuilt every step on the ghosts just forwarded, the halo
    (migration and ghost choice, with a border layer widened by the halo skin) only when some
    particle has moved half the halo skin since its last choice, decided together. On 2 and on 2x2x2
    blocks with the three-sweep halo: the serial trajectory bit for bit; the halo is rebuilt on the
    same steps by every rank, on fewer than half of them (the gas, 0.5 m/s at dt = 4e-6 s,
    dem/scenes/gas.toml: 58 of 2500 on both grids when this was written), and particles change rank
    only at those steps; run.json records the halo skin."""
    ref = serial_state(tmp_path_factory, "gas", 2500)
    for mapping, extra in (("2-2-1-1-1", ()), ("8-2-2-2-1", ("--halo", "6"))):
        got, steps, info = mpi_run(tmp_path / mapping, "gas", 2500, mapping, "--skin", "0", *extra)
        assert info["skin"] == 0.0 and info["halo_skin"] == pytest.approx(0.1, rel=1e-12)
        assert (steps["neighbor_rebuilt"] == 1).all()
        assert (steps.groupby("step")["halo_rebuilt"].nunique() == 1).all()  # every rank on the same steps
        halo = steps.groupby("step")["halo_rebuilt"].max()
        moved = steps.groupby("step")["n_migrated"].sum()
        assert 1 < halo.sum() < len(halo) / 2, halo.sum()
        assert (moved[halo == 0] == 0).all() and (moved > 0).sum() > 0
        assert_same(ref, got)


def test_rebuilds_decided_together_and_forward_sends_moving_fields(tmp_path):
    """With a skin every rank rebuilds on the same steps (one collective decision); a step that
    neither rebuilds nor precedes a rebuild sends one message per neighbour at its end, holding only
    the moving fields of the same ghosts for the next step: position, velocity, angular momentum,
    quaternion = 13 doubles = 104 bytes a ghost for ellipsoids, so rank 0's bytes equal 104 x rank
    1's ghosts on those steps; a step followed by a rebuild sends nothing (the decision comes first).
    Newton off: the forward exchange alone; the reverse one is
    test_newton_resolves_each_cross_border_pair_once's. Forward by messages (--forward messages; the
    shared window's is test_shared_forward_sends_no_message)."""
    _, steps, info = mpi_run(tmp_path, "gas", 400, "2-2-1-1-1", "--newton", "off", "--forward", "messages")
    assert info["forward_transport"] == "messages"
    wide = steps.pivot(index="step", columns="rank")
    rebuilt = wide["neighbor_rebuilt"][0]
    assert (rebuilt == wide["neighbor_rebuilt"][1]).all()
    next_rebuilt = rebuilt.shift(-1)
    between = wide[(rebuilt == 0) & (next_rebuilt == 0)]
    before = wide[(rebuilt == 0) & (next_rebuilt == 1)]
    assert 0 < len(between) < 400 and len(before) > 0 and info["forward_bytes_per_ghost"] == 104
    assert (between["n_migrated"][0] == 0).all() and (between["migraT"][0] == 0).all()
    assert (between["msgs_sent"][0] == 1).all() and (between["msgs_sent"][1] == 1).all()
    assert (between["bytes_sent"][0] == 104 * between["n_ghost"][1]).all()
    assert (between["bytes_sent"][1] == 104 * between["n_ghost"][0]).all()
    assert (before["msgs_sent"][0] == 0).all() and (before["bytes_sent"][1] == 0).all()


@pytest.mark.parametrize("mapping", ["2-2-1-1-1", "8-2-2-2-1", "2-2-1-1-2"])
def test_shared_forward_sends_no_message(tmp_path, tmp_path_factory, mapping):
    """--forward shared (every rank on one node): between rebuilds the ghosts' moving fields pass
    through the node's shared-memory window (modes.window), so a step that does not rebuild sends no
    message at all (with newton off, no reverse exchange either), where by messages it sends one per
    neighbour; the gas (migration, contacts across faces, edges and
    corners on 2x2x2 blocks; hybrid 2 x 2 threads) ends bit-identical to serial. The window starts
    empty and is made anew whenever a rank's rows outgrow its segment, at least once
    (forward_windows in run.json)."""
    ref = serial_state(tmp_path_factory, "gas", 400)
    got, steps, info = mpi_run(tmp_path, "gas", 400, mapping, "--newton", "off", "--forward", "shared")
    assert info["forward_transport"] == "shared" and info["forward"] == "shared"
    assert info["forward_windows"] >= 2
    wide = steps.pivot(index="step", columns="rank")
    rebuilt = wide["neighbor_rebuilt"][0]
    between = wide[rebuilt == 0]
    assert len(between) > 0 and (between["n_ghost"] > 0).all().all()
    assert (between["msgs_sent"] == 0).all().all() and (between["bytes_sent"] == 0).all().all()
    assert_same(ref, got)


def test_shared_forward_refused_where_it_cannot_be(tmp_path):
    """--forward shared needs --halo 26 (the three sweeps forward what earlier sweeps brought) and
    every rank on one node (--hosts with two hosts): bench run and bench sweep refuse each in one
    line naming --forward, exit 2, before any rank starts; an unknown value is argparse's one line."""
    one_line_error(bench("run", "--scene", "gas", "--particles", "200", "--steps", "5", "--mapping", "2-2-1-1-1",
                         "--halo", "6", "--forward", "shared", "--out", str(tmp_path / "a")), "--forward", "--halo 26")
    one_line_error(bench("sweep", "--scene", "gas", "--particles", "200", "--steps", "5", "--mappings", "2-2-1-1-1",
                         "--halo", "6", "--forward", "shared", "--out", str(tmp_path / "b")), "--forward", "--halo 26")
    one_line_error(bench("run", "--scene", "gas", "--particles", "200", "--steps", "5", "--mapping", "2-2-1-1-1",
                         "--hosts", "node1,node2", "--forward", "shared", "--out", str(tmp_path / "c")),
                   "--forward", "one node")
    one_line_error(bench("run", "--scene", "gas", "--mapping", "2-2-1-1-1", "--forward", "bogus",
                         "--out", str(tmp_path / "d")), "--forward")


def test_wire_time_is_the_measured_model_of_the_bytes_sent(tmp_path):
    """run.json holds each rank's ping-pong fit of its link (latency alpha > 0, bandwidth beta > 0,
    the same for both ends); steps.csv's wire_s is sum over the step's messages of
    alpha + bytes / beta (Hockney's model; modes/wire.py), which for one neighbour is
    msgs_sent alpha + bytes_sent / beta, to the 7 significant digits steps.csv keeps: above zero on
    every step that sent (all but those followed by a rebuild without a cross pair), zero on the
    others."""
    _, steps, info = mpi_run(tmp_path, "gas", 100, "2-2-1-1-1")
    w0 = info["wire"]["0"]["partners"]["1"]
    w1 = info["wire"]["1"]["partners"]["0"]
    assert w0 == w1 and w0["latency_s"] > 0 and w0["bandwidth_Bps"] > 0
    model = steps["msgs_sent"] * w0["latency_s"] + steps["bytes_sent"] / w0["bandwidth_Bps"]
    assert np.allclose(steps["wire_s"], model, rtol=1e-6, atol=0)
    assert ((steps["wire_s"] > 0) == (steps["msgs_sent"] > 0)).all() and (steps["msgs_sent"] > 0).mean() > 0.5


def test_placement_recorded_and_one_node_sends_nothing_across_nodes(tmp_path):
    """run.json `placement` names each rank's host, CPU set, block and neighbour ranks; on one host
    no neighbour is on another node, so steps.csv's inter-node counts (issue 37) are 0 on every
    step while the step's totals are not."""
    _, steps, info = mpi_run(tmp_path, "gas", 40, "2-2-1-1-1")
    place = info["placement"]
    assert sorted(place) == ["0", "1"] and len(info["nodes"]) == 1
    assert [place[r]["block"] for r in ("0", "1")] == [[0, 0, 0], [1, 0, 0]]
    assert place["0"]["neighbours"] == [1] and place["1"]["neighbours"] == [0]
    assert all(p["neighbours_internode"] == [] and p["host"] == info["nodes"][0] and p["cpus"] for p in place.values())
    assert (steps["bytes_sent"] > 0).any()
    for c in ("bytes_internode", "msgs_internode", "wire_internode_s"):
        assert (steps[c] == 0).all(), c


def test_default_skin_fits_narrow_blocks_explicit_one_refused(tmp_path):
    """Ghost layers are the largest bounding diameter plus the skin wide: on blocks too narrow for
    the default skin it shrinks to fit (run.json says by how much); an explicit skin that does not
    fit is refused in one line. The same for the halo's own skin at --skin 0 (--halo-skin), which
    without --skin 0 is refused in one line by bench run and bench sweep."""
    # blocks 2.1 mm wide along x, the largest bounding diameter 2 mm: room for a 0.1 mm skin (0.05 d)
    pair = [("sphere", [1e-3], [0.0011, 0.01, 0.0011], [0.1, 0.0, 0.0]),
            ("sphere", [1e-3], [0.00312, 0.01, 0.0011], [-0.1, 0.0, 0.0])]
    scene = write(tmp_path, scene_with(pair, box="[[0.0, 0.0, 0.0], [0.0042, 0.02, 0.02]]"))
    got, _, info = mpi_run(tmp_path, scene, 50, "2-2-1-1-1")
    assert info["skin"] == pytest.approx(0.05, rel=1e-6) and info["skin_requested"] is None
    one_line_error(bench("run", "--scene", scene, "--mapping", "2-2-1-1-1", "--skin", "0.5",
                         "--out", str(tmp_path / "o")), "use a skin of at most")
    # with --skin 0 the halo's own skin fits the same way: the default shrinks, an explicit one is refused
    _, _, info = mpi_run(tmp_path / "zero", scene, 50, "2-2-1-1-1", "--skin", "0")
    assert info["skin"] == 0.0 and info["halo_skin"] == pytest.approx(0.05, rel=1e-6)
    one_line_error(bench("run", "--scene", scene, "--mapping", "2-2-1-1-1", "--skin", "0", "--halo-skin", "0.5",
                         "--out", str(tmp_path / "h")), "--halo-skin", "use a halo skin of at most")
    # and it is the halo's own only with --skin 0 (a run, and a sweep before any point runs)
    one_line_error(bench("run", "--scene", scene, "--mapping", "2-2-1-1-1", "--halo-skin", "0.02",
                         "--out", str(tmp_path / "k")), "--halo-skin needs --skin 0")
    one_line_error(bench("sweep", "--scene", scene, "--mappings", "2-2-1-1-1", "--halo-skin", "0.02",
                         "--out", str(tmp_path / "s")), "--halo-skin needs --skin 0")


MPI_ALLOCATION_PROBE = """
import json, sys
from mpi4py import MPI
from numba.core.runtime import rtsys
from bench.run.prepare import load_prepared
from dem.timestep import choose_time_step
from modes.mpi import MpiMode
cart = MPI.COMM_WORLD.Create_cart([2, 1, 1], periods=[False] * 3, reorder=False)
sc = load_prepared("packed", particles=500)
m = MpiMode().setup(sc, dt=choose_time_step(sc).dt, cart=cart, forward=sys.argv[2])
m.warmup()
m.step()  # the first build: migration, ghosts, list
s, p, h = m.state, m.pairs, m.halo
w = h.window
buffers = (lambda: [h.rounds[0].send_buf, h.rounds[0].recv_buf]) if w is None else (lambda: [w.mem, *w.slots])
keep = lambda: [s.pos, s.vel, s.quat, s.angmom, s.wall_hist, p.pi, p.hist, p.pf, p.on, m.rot, m.omega,
                *buffers(), m.plan.send_buf, m.plan.recv_buf]
arrays = keep()
before = rtsys.get_allocation_stats().alloc
rows = [m.step() for _ in range(20)]
out = {"rank": cart.Get_rank(), "allocs": rtsys.get_allocation_stats().alloc - before,
       "rebuilt": sum(r["neighbor_rebuilt"] for r in rows), "same": all(a is b for a, b in zip(arrays, keep())),
       "msgs": [r["msgs_sent"] for r in rows], "ghosts": s.n - s.n_owned, "sent": m.plan.m_sent,
       "received": m.plan.m_recv}
m.release()
with open(sys.argv[1] + f"/rank{cart.Get_rank()}.json", "w") as fh:
    json.dump(out, fh)
"""


@pytest.mark.parametrize("forward", ["messages", "shared"])
def test_forward_steps_allocate_nothing(tmp_path, forward):
    """Under MPI a step between rebuilds allocates nothing either: on both ranks numba's allocator
    counts nothing (NRT statistics: every kernel of such a step, pack, unpack, derive, resolve and
    finish, runs without the runtime), the state, pair list and exchange buffers (or the shared
    window and its slots) stay the same objects, and each step sends one message for the forward
    exchange to the one neighbour (none through the shared window), and one more where the rank
    resolves pairs whose other end the neighbour owns (newton: their terms go back); what one rank
    sends, the other receives."""
    import subprocess
    import sys
    from tests.helpers import ROOT
    probe = tmp_path / "probe.py"
    probe.write_text(MPI_ALLOCATION_PROBE)
    mpiexec = os.path.join(os.path.dirname(sys.executable), "mpiexec")
    env = dict(os.environ, NUMBA_NRT_STATS="1", NUMBA_NUM_THREADS="1", PYTHONPATH=ROOT)
    res = subprocess.run([mpiexec, "-n", "2", sys.executable, str(probe), str(tmp_path), forward],
                         capture_output=True, text=True, env=env, timeout=600, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    ranks = [json.loads((tmp_path / f"rank{r}.json").read_text()) for r in (0, 1)]
    assert sorted(r["rank"] for r in ranks) == [0, 1]
    for r in ranks:
        assert r["rebuilt"] == 0 and r["ghosts"] > 0, r
        assert r["allocs"] == 0 and r["same"], r
        assert r["msgs"] == [(forward == "messages") + (r["sent"] > 0)] * 20, r
    assert ranks[0]["sent"] == ranks[1]["received"] and ranks[1]["sent"] == ranks[0]["received"]
    assert ranks[0]["sent"] + ranks[1]["sent"] > 0


def _bed_in_tall_box():
    """100 spheres (r = 0.8 mm) in 4 layers of 5 x 5 on the floor of a 40 mm tall box, centres
    1.58 mm apart (each touches its neighbours: overlap 0.02 mm), z = 0.8..5.54 mm."""
    return [("sphere", [8e-4], [0.006 + 1.58e-3 * i, 0.006 + 1.58e-3 * j, 8e-4 + 1.58e-3 * k], [0.0, 0.0, 0.0])
            for k in range(4) for j in range(5) for i in range(5)]


def test_update_grid_fits_the_grid_at_the_start(tmp_path, tmp_path_factory):
    """A bed in the lowest seventh of its box, split in two along z. Blocks that divide the box put
    all 100 particles in the lower block (run.json block_particles [[[100, 0]]]) and the run says
    so in one warning line; with --update-grid the blocks divide the particles' extent from the
    first step (the paper's updateGrid, flowchart step 9), cutting at z = 3.17 mm between the
    second and third layers: 50 + 50. Both reproduce the serial trajectory bit for bit."""
    scene = write(tmp_path, scene_with(_bed_in_tall_box(), box="[[0.0, 0.0, 0.0], [0.02, 0.02, 0.04]]"))
    ref = serial_state(tmp_path_factory, scene, 40)
    out = tmp_path / "box"
    res = bench("run", "--scene", scene, "--steps", "40", "--mapping", "2-1-1-2-1", "--out", str(out), "--quiet",
                "--timeout", "600", timeout=900)
    assert res.returncode == 0, res.stderr
    info = json.loads((out / "run.json").read_text())
    assert info["block_particles"] == [[[100, 0]]]
    warned = [line for line in res.stderr.splitlines() if "hold no particle" in line]
    assert len(warned) == 1 and "1 of 2 blocks of the 1x1x2 grid" in warned[0] and "--update-grid" in warned[0]
    assert_same(ref, dict(np.load(out / "state.npz")))
    got, steps, info = mpi_run(tmp_path, scene, 40, "2-1-1-2-1", "--update-grid", "1000")
    assert info["block_particles"] == [[[50, 50]]]
    assert info["block_box"][1][2] == pytest.approx(8e-4 + 3 * 1.58e-3, rel=1e-6)
    assert (steps.query("step == 1").set_index("rank")["n_owned"] == 50).all()
    assert_same(ref, got)


def _staircase():
    """68 spheres (r = 0.8 mm) on the floor in 8 rows along y, row j holding 12 - j spheres 1.58 mm
    apart along x from x = 2 mm + 0.1 j mm (every centre its own x; neighbours touch, overlap
    0.02 mm along x, 0.017 mm across rows). Half of the centres' x extent (2.0..19.38 mm) is
    10.69 mm: the first 6 spheres of each row lie below it (x < 10.69 mm for i <= 5 in every row),
    and row 7 has only 5: 7 x 6 + 5 = 47 of 68."""
    return [("sphere", [8e-4], [0.002 + 1.58e-3 * i + 1e-4 * j, 0.002 + 1.58e-3 * j, 8e-4], [0.0, 0.0, 0.0])
            for j in range(8) for i in range(12 - j)]


def test_balance_count_splits_the_particles_equally(tmp_path, tmp_path_factory):
    """--balance count: the cut plane at equal particle counts. On the staircase, 2 blocks along x
    fitted to the extent (the paper's updateGrid) hold 47 + 21 (see _staircase); cut at equal
    counts they hold 34 + 34 from the first step. Both reproduce the serial trajectory bit for
    bit, and run.json records the balance and the cut planes."""
    scene = write(tmp_path, scene_with(_staircase(), box="[[0.0, 0.0, 0.0], [0.022, 0.016, 0.01]]"))
    ref = serial_state(tmp_path_factory, scene, 40)
    got, steps, info = mpi_run(tmp_path / "extent", scene, 40, "2-2-1-1-1", "--update-grid", "1000")
    assert info["block_particles"] == [[[47]], [[21]]] and info["balance"] == "extent"
    assert_same(ref, got)
    got, steps, info = mpi_run(tmp_path / "count", scene, 40, "2-2-1-1-1", "--update-grid", "1000",
                               "--balance", "count")
    assert info["block_particles"] == [[[34]], [[34]]] and info["balance"] == "count"
    assert (steps.query("step == 1").set_index("rank")["n_owned"] == 34).all()
    assert len(info["block_cuts"][0]) == 1 and info["block_cuts"][1] == [] and info["block_cuts"][2] == []
    assert_same(ref, got)


def _spheres_then_ellipsoids():
    """8 rows along y of 10 spheres (r = 0.8 mm, 1.58 mm apart) followed along x by 10 ellipsoids
    (semi-axes 1.0, 0.8, 0.6 mm, aligned, 1.98 mm apart) on the floor, each touching its
    neighbours (overlap 0.02 mm): 160 particles, the left half of the x extent spheres."""
    rows = []
    for j in range(8):
        y = 0.002 + 1.58e-3 * j
        rows += [("sphere", [8e-4], [0.002 + 1.58e-3 * i, y, 8e-4], [0.0, 0.0, 0.0]) for i in range(10)]
        x0 = 0.002 + 1.58e-3 * 9 + 0.8e-3 + 1e-3 - 2e-5
        rows += [("ellipsoid", [1e-3, 8e-4, 6e-4], [x0 + 1.98e-3 * i, y, 6e-4], [0.0, 0.0, 0.0]) for i in range(10)]
    return rows


def test_balance_time_gives_the_dearer_particles_a_smaller_block(tmp_path, tmp_path_factory):
    """--balance time (LAMMPS's weight time): each rank's median compute time per step spread over
    its particles sets the load profile. Spheres resolve in closed form, ellipsoid pairs through an
    iterative solver, at many times the cost: starting from equal counts (80 + 80, the spheres in
    block 0), the refits every 10 steps move the cut towards the ellipsoids, so that block 1 ends
    with fewer than 80 particles. The trajectory is the serial one bit for bit."""
    scene = write(tmp_path, scene_with(_spheres_then_ellipsoids(), box="[[0.0, 0.0, 0.0], [0.04, 0.016, 0.01]]"))
    ref = serial_state(tmp_path_factory, scene, 60)
    got, steps, info = mpi_run(tmp_path, scene, 60, "2-2-1-1-1", "--update-grid", "10", "--balance", "time")
    assert info["block_particles"] == [[[80]], [[80]]] and info["balance"] == "time"
    assert info["grid_updates"] >= 4
    last = steps.query("step == 60").set_index("rank")["n_owned"]
    assert last[1] < 80 < last[0] and last.sum() == 160
    assert info["block_cuts_final"][0][0] > info["block_cuts"][0][0]
    assert steps["ellipsoid_calls"].sum() > 0 and steps["n_migrated"].sum() > 0
    assert_same(ref, got)


@pytest.mark.parametrize("mapping", ["2-2-1-1-1", "2-2-1-1-2"])
def test_newton_resolves_each_cross_border_pair_once(tmp_path, tmp_path_factory, mapping):
    """Newton's third law across ranks (modes/newton.py) on the patch test, 2 blocks, pure MPI and
    hybrid (2 threads, dynamic: the threads take the cross pairs' terms in their ranges; on one
    rank seven cross pairs have an owned end that gathers, as counted while writing the test):
    with newton on, each touching pair is resolved (and counted) by exactly one rank, so the ranks'
    contact counts add up, step by step, to serial's own count (the reference number comes from
    the serial run of the same scene); with newton off the pairs across the border are counted on
    both ranks, so the sum exceeds serial's. Both are bit-identical to serial, and with newton on
    each step sends one more message per rank (the j ends' terms, 56 bytes a pair)."""
    out = tmp_path / "serial"
    res = bench("run", "--scene", "patch162", "--steps", "150", "--out", str(out), "--quiet")
    assert res.returncode == 0, res.stderr
    ref = dict(np.load(out / "state.npz"))
    serial = pd.read_csv(out / "steps.csv").set_index("step")["n_contacts"]
    on, steps_on, info_on = mpi_run(tmp_path / "on", "patch162", 150, mapping, "--newton", "on")
    off, steps_off, info_off = mpi_run(tmp_path / "off", "patch162", 150, mapping, "--newton", "off")
    assert info_on["newton"] is True and info_off["newton"] is False
    assert_same(ref, on)
    assert_same(ref, off)
    sum_on = steps_on.groupby("step")["n_contacts"].sum()
    sum_off = steps_off.groupby("step")["n_contacts"].sum()
    assert (sum_on == serial).all()
    assert (sum_off >= serial).all() and (sum_off > serial).sum() > 100
    forward = steps_on["neighbor_rebuilt"] == 0
    assert (steps_on.loc[forward, "msgs_sent"] == steps_off.loc[forward, "msgs_sent"] + 1).all()


@pytest.mark.parametrize("mapping", ["2-2-1-1-1", "2-2-1-1-2"])
def test_every_step_estimate_carries_history_with_the_terms(tmp_path, mapping):
    """With --skin 0 each pair list lives one step, so the reverse exchange carries the sent pairs'
    contact history with their terms (modes.newton NewtonPlan, carry_history: 7 + 8 doubles = 120
    bytes a pair) and a rebuild sends no history message of its own. On the patch test (contacts
    that last across the border, both ranks resolving some every step), pure MPI and hybrid: the
    serial trajectory bit for bit, and each rank sends exactly one message a step more than with
    newton off (the terms; before, two: the terms and, at the rebuild, the history), of a multiple
    of 120 bytes more. (That the history that came back is the resolver's own, a checkpoint shows:
    tests/bench/test_restart.py, test_every_step_estimate_checkpoints_the_resolvers_history.)"""
    out = tmp_path / "serial"
    res = bench("run", "--scene", "patch162", "--steps", "60", "--skin", "0", "--out", str(out), "--quiet")
    assert res.returncode == 0, res.stderr
    ref = dict(np.load(out / "state.npz"))
    on, steps_on, info_on = mpi_run(tmp_path / "on", "patch162", 60, mapping, "--newton", "on", "--skin", "0")
    off, steps_off, _ = mpi_run(tmp_path / "off", "patch162", 60, mapping, "--newton", "off", "--skin", "0")
    assert info_on["newton"] is True and (steps_on["neighbor_rebuilt"] == 1).all()
    assert_same(ref, on)
    assert_same(ref, off)
    assert steps_on["n_contacts"].sum() > 0
    on_, off_ = steps_on.set_index(["step", "rank"]), steps_off.set_index(["step", "rank"])
    assert (on_["msgs_sent"] == off_["msgs_sent"] + 1).all()
    extra = on_["bytes_sent"] - off_["bytes_sent"]
    assert (extra > 0).all() and (extra % 120 == 0).all()


def test_newton_refused_for_storing_schemes(tmp_path):
    """Under frogleap and headtail every pair's forces are stored and gathered, so a cross pair's
    terms cannot be taken in its place: --newton on is refused in one line naming the scheme."""
    for scheme in ("frogleap", "headtail"):
        res = bench("run", "--scene", "patch162", "--steps", "2", "--mapping", "2-2-1-1-2", "--scheme", scheme,
                    "--newton", "on", "--out", str(tmp_path / scheme), "--quiet")
        one_line_error(res, "--newton on", scheme)
