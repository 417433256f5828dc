"""CPU binding (`--pin`, bench/run/binding.py): the plan on described topologies, the check that
stops a run whose ranks lost CPUs, and runs on the machine itself (2 CPUs in CI: `2-2-1-1-1 --pin`
gives the ranks {0} and {1}, `1-1-1-1-2 --pin` the threads CPUs 0 and 1, tests/modes/test_threads.py).

The expected plans follow the rules of bench.run.binding: one hardware thread a core while P x T
fits in the cores, siblings together beyond that, ranks spread evenly over the sockets without
straddling one when they fit, and CPUs numbered as Linux numbers x86 CPUs (described())."""
import json
import os
import shutil
import socket
import sys

import pandas as pd
import pytest

from bench.run.binding import (BindingError, Cpu, check_binding, described, format_cpus, plan_binding,
                               read_topology)
from bench.sweep.records import binding_word
from tests.helpers import bench


def _sets(plan):
    return [set(row) for row in plan]


def _valid(plan, topology, ranks, threads):
    """Every plan: ranks rows of threads distinct CPUs of the topology, no CPU twice."""
    ids = {c.id for c in topology}
    flat = [c for row in plan for c in row]
    assert len(plan) == ranks and all(len(row) == threads for row in plan)
    assert len(set(flat)) == len(flat) and set(flat) <= ids


@pytest.mark.parametrize("ranks,threads,expected", [
    (4, 4, [range(0, 4), range(4, 8), range(8, 12), range(12, 16)]),  # 4-2-2-1-4
    (16, 1, [[k] for k in range(16)]),                                  # 16-4-2-2-1
    (1, 16, [range(16)]),                                               # 1-1-1-1-16
    (2, 8, [range(0, 8), range(8, 16)]),                                # 2-2-1-1-8
    (8, 2, [[2 * k, 2 * k + 1] for k in range(8)]),                     # 8-2-2-2-2
])
def test_one_socket_of_16(ranks, threads, expected):
    """The lent 16-core machine (1 socket x 16 cores, no SMT): consecutive blocks of T cores."""
    topo = described(1, 16)
    plan = plan_binding(topo, ranks, threads)
    _valid(plan, topo, ranks, threads)
    assert plan == [list(e) for e in expected]


def test_two_sockets_of_18_the_papers_thunder():
    """The paper's Thunder nodes (2 x 18-core Xeon E5-2695 v4, Yan & Regueiro 2019 §5): CPUs 0-17
    on socket 0, 18-35 on socket 1. 4 x 9 keeps two ranks on each socket; 2 x 18 one a socket;
    36 x 1 every core in rank order; 2 x 1 one a socket (memory bandwidth of both)."""
    topo = described(2, 18)
    assert plan_binding(topo, 4, 9) == [list(range(0, 9)), list(range(9, 18)), list(range(18, 27)),
                                        list(range(27, 36))]
    assert plan_binding(topo, 2, 18) == [list(range(18)), list(range(18, 36))]
    assert plan_binding(topo, 36, 1) == [[k] for k in range(36)]
    assert plan_binding(topo, 2, 1) == [[0], [18]]
    assert plan_binding(topo, 6, 6) == [list(range(6 * k, 6 * k + 6)) for k in range(6)]
    # 3 x 12 cannot avoid straddling (one rank of 12 fits a socket of 18): consecutive CPUs
    three = plan_binding(topo, 3, 12)
    _valid(three, topo, 3, 12)
    assert three == [list(range(0, 12)), list(range(12, 24)), list(range(24, 36))]
    # 1 x 36: one rank over both sockets
    assert plan_binding(topo, 1, 36) == [list(range(36))]


def test_smt_two_threads_a_core():
    """1 socket x 8 cores x 2 hardware threads (core c = CPUs c and c + 8): one hardware thread a
    core while P x T <= 8; beyond, a core's two siblings go to the same rank."""
    topo = described(1, 8, smt=2)
    assert [c.core for c in topo if c.id in (3, 11)] == [3, 3]
    assert plan_binding(topo, 4, 2) == [[0, 1], [2, 3], [4, 5], [6, 7]]
    assert plan_binding(topo, 1, 8) == [list(range(8))]
    assert plan_binding(topo, 4, 4) == [[0, 8, 1, 9], [2, 10, 3, 11], [4, 12, 5, 13], [6, 14, 7, 15]]
    assert plan_binding(topo, 16, 1) == [[0], [8], [1], [9], [2], [10], [3], [11], [4], [12], [5], [13],
                                         [6], [14], [7], [15]]


def test_two_cores():
    """The 2-core machines of development and CI: 2-2-1-1-1 gives {0} and {1}, 1-1-1-1-2 {0, 1}."""
    topo = described(1, 2)
    assert plan_binding(topo, 2, 1) == [[0], [1]]
    assert plan_binding(topo, 1, 2) == [[0, 1]]
    assert plan_binding(topo, 1, 1) == [[0]]


def test_a_subset_of_the_machine():
    """A process allowed CPUs {4-7} of a 16-core socket (a Slurm allocation): the plan uses those."""
    topo = [c for c in described(1, 16) if 4 <= c.id < 8]
    assert plan_binding(topo, 2, 2) == [[4, 5], [6, 7]]


def test_too_many_is_one_line():
    with pytest.raises(BindingError) as e:
        plan_binding(described(1, 2), 2, 2)
    assert str(e.value) == "--pin: 2 ranks x 2 threads need 4 CPUs; usable: 2 (1 socket, 2 cores)"
    assert "\n" not in str(e.value)


def test_read_topology_from_sys(tmp_path, monkeypatch):
    """Package and core ids as Linux gives them in /sys: 2 sockets x 2 cores x 2 threads, core ids
    repeating on each socket (they are unique only within a package)."""
    layout = {0: (0, 0), 1: (0, 1), 2: (1, 0), 3: (1, 1), 4: (0, 0), 5: (0, 1), 6: (1, 0), 7: (1, 1)}
    for cpu, (pkg, core) in layout.items():
        d = tmp_path / f"cpu{cpu}" / "topology"
        d.mkdir(parents=True)
        (d / "physical_package_id").write_text(f"{pkg}\n")
        (d / "core_id").write_text(f"{core}\n")
    import bench.run.binding as binding
    monkeypatch.setattr(binding, "SYS_CPU", str(tmp_path))
    topo = read_topology(range(8))
    assert [c.socket for c in topo] == [0, 0, 1, 1, 0, 0, 1, 1]
    assert len({c.core for c in topo}) == 4 and topo[0].core == topo[4].core != topo[2].core
    assert plan_binding(topo, 2, 2) == [[0, 1], [2, 3]]          # a socket each, no siblings
    assert plan_binding(topo, 2, 4) == [[0, 4, 1, 5], [2, 6, 3, 7]]  # siblings together
    # missing files: every CPU its own core on socket 0
    assert read_topology([99]) == [Cpu(99, 0, 0)]


def _rec(cpus, threads, host="h"):
    return {"host": host, "pid": 1, "cpus": cpus,
            "threads": [{"thread": k, "tid": 10 + k, "cpus": m, "ran_on": m[0] if m else -1}
                        for k, m in enumerate(threads)]}


def test_check_lost_cpus():
    """The 16-core bug this module fixes: a pinned 4-2-2-1-4 whose four ranks all got CPU 0."""
    recs = [_rec([0], [[0], [0], [0], [0]]) for _ in range(4)]
    line = check_binding(recs, 4, pinned=True, launcher_cpus=16)
    assert line == ("rank 0 on h got CPUs {0} for 4 threads (the launcher had 16): CPUs were lost between "
                    "the launcher and the rank")
    # oversubscribed on purpose (4 threads, 2 CPUs): each rank holding both is what it can have
    assert check_binding([_rec([0, 1], [[0, 1]] * 4)], 4, pinned=False, launcher_cpus=2) is None


def test_check_pinned():
    good = [_rec([0, 1], [[0], [1]]), _rec([2, 3], [[2], [3]])]
    assert check_binding(good, 2, pinned=True, launcher_cpus=4) is None
    shared = [_rec([0, 1], [[0], [1]]), _rec([1, 2], [[1], [2]])]
    assert check_binding(shared, 2, pinned=True, launcher_cpus=4) == (
        "ranks 0 and 1 on h share CPU 1 (rank 1: CPUs {1-2}; --pin gives each rank CPUs of its own)")
    # the same CPUs on two hosts are two CPUs
    assert check_binding([_rec([0, 1], [[0], [1]], "a"), _rec([0, 1], [[0], [1]], "b")], 2, True, None) is None
    loose = [_rec([0, 1], [[0, 1], [1]])]
    assert "thread 0 is bound to CPUs {0-1}, not to one CPU" in check_binding(loose, 2, True, 2)
    twice = [_rec([0, 1], [[0], [0]])]
    assert check_binding(twice, 2, True, 2) == "rank 0 on h: two threads bound to CPU 0 (--pin)"
    moved = [_rec([0, 1], [[0], [1]])]
    moved[0]["threads"][1]["ran_on"] = 0
    assert check_binding(moved, 2, True, 2) == "rank 0 on h: thread 1 bound to CPU 1 ran on CPU 0 (--pin)"


def test_format_and_binding_word():
    assert format_cpus([0, 1, 2, 3, 8, 10, 11]) == "{0-3,8,10-11}"
    assert format_cpus([]) == "{}"
    assert binding_word(None) == ""
    assert binding_word({"pinned": True, "held": True}) == "pinned"
    assert binding_word({"pinned": False, "held": True}) == "unpinned"
    assert binding_word({"pinned": True, "held": False}) == "lost"


two_cpus = pytest.mark.skipif(os.sched_getaffinity(0) != {0, 1}, reason="the expected sets are those of 2 CPUs")


@two_cpus
def test_pinned_ranks_get_a_cpu_each(tmp_path):
    """`bench run --mapping 2-2-1-1-1 --pin` on 2 CPUs: rank 0 on {0}, rank 1 on {1}, recorded at the
    start and after the run (run.json affinity), the binding held."""
    out = tmp_path / "p"
    res = bench("run", "--scene", "packed", "--particles", "300", "--steps", "5", "--mapping", "2-2-1-1-1",
                "--pin", "--out", str(out), timeout=600)
    assert res.returncode == 0, res.stderr
    aff = json.loads((out / "run.json").read_text())["affinity"]
    assert aff["pinned"] is True and aff["held"] is True and aff["launcher_cpus"] == 2
    for key in ("ranks", "after"):
        assert [(r["cpus"], [(t["cpus"], t["ran_on"]) for t in r["threads"]]) for r in aff[key]] == \
            [([0], [([0], 0)]), ([1], [([1], 1)])]


@two_cpus
def test_pin_beyond_the_cpus_is_one_line(tmp_path):
    """2 ranks x 2 threads pinned on 2 CPUs cannot give each thread a CPU of its own: refused before
    any rank starts, one line, exit 2."""
    res = bench("run", "--scene", "packed", "--particles", "300", "--steps", "5", "--mapping", "2-2-1-1-2",
                "--pin", "--out", str(tmp_path / "p"), timeout=600)
    assert res.returncode == 2, res.stderr
    lines = [l for l in res.stderr.splitlines() if l.strip()]
    assert lines == ["bench: error: --pin: 2 ranks x 2 threads need 4 CPUs; usable: 2 (1 socket, 2 cores)"]


@two_cpus
def test_launcher_under_omp_proc_bind_keeps_its_cpus(tmp_path):
    """OMP_PROC_BIND in the environment binds a process's main thread to one CPU as soon as it runs a
    parallel region, as `bench run` does to warm numba's cache before it starts the ranks; they
    inherited that one CPU (a pinned 4-2-2-1-4 ran its four ranks on CPU 0, issue 32). Now each
    rank of an unpinned 2-2-1-1-2 holds both CPUs."""
    out = tmp_path / "u"
    res = bench("run", "--scene", "packed", "--particles", "300", "--steps", "5", "--mapping", "2-2-1-1-2",
                "--out", str(out), env={"OMP_PROC_BIND": "close", "OMP_PLACES": "cores"}, timeout=600)
    assert res.returncode == 0, res.stderr
    aff = json.loads((out / "run.json").read_text())["affinity"]
    assert aff["pinned"] is False and aff["held"] is True
    assert [r["cpus"] for r in aff["ranks"]] == [[0, 1], [0, 1]]


@pytest.mark.skipif(shutil.which("taskset") is None or len(os.sched_getaffinity(0)) < 2,
                    reason="needs taskset and 2 CPUs")
def test_ranks_that_lost_cpus_stop_before_timing(tmp_path):
    """A starter that confines the ranks to one CPU (taskset -c 0) while each has 2 threads: the
    run stops before its first step with one line naming the rank and its CPUs, and run.json says
    failed with that reason."""
    mpiexec = os.path.join(os.path.dirname(sys.executable), "mpiexec")
    if not os.path.exists(mpiexec):
        mpiexec = shutil.which("mpiexec")
    out = tmp_path / "l"
    res = bench("run", "--scene", "packed", "--particles", "300", "--steps", "5", "--mapping", "2-2-1-1-2",
                "--mpi-starter", f"taskset -c 0 {mpiexec} -n 2", "--out", str(out), timeout=600)
    assert res.returncode != 0
    line = (f"rank 0 on {socket.gethostname()} got CPUs {{0}} for 2 threads: CPUs were lost between the "
            f"launcher and the rank")
    info = json.loads((out / "run.json").read_text())
    assert info["status"] == "failed" and info["reason"] == line
    assert f"bench: error: {line}" in res.stderr
    assert not (out / "steps.csv").exists() or len(pd.read_csv(out / "steps.csv")) == 0
