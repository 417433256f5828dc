"""A simulated 2-node Slurm cluster on this one machine (tests/bench/slurm/multinode.sh, as root):
slurmctld and a private munged in the host's namespaces, each node's slurmd in its own network, UTS,
IPC and mount namespace, with its own hostname and address on a private bridge through a veth pair.

- both nodes register and are idle (sinfo);
- a job step on both nodes runs in each node's own namespaces (hostname, address, IPC, /dev/shm);
- 2 MPI ranks (mpi4py, the mpich wheel, srun --mpi=pmi2) on the two nodes send 4 MiB from one to
  the other: the hostnames differ and the veths' byte counters grew by at least the message, so the
  bytes crossed the simulated network (TCP), not shared memory; the same 2 ranks on one node move
  next to nothing over the veths;
- stop leaves no daemon, namespace, bridge, veth or mount of the cluster behind, and stopping again
  is harmless.

Skips only where the cluster cannot be made here: not root, or the script's exit 3 (slurm-wlm,
munge or iproute2 missing and not installable, or namespaces not allowed), with the script's line.
Ports, names and state differ from tests/bench/slurm/cluster.sh's single-node cluster, which may be
up at the same time (its session fixture): every command here names this cluster's SLURM_CONF.
"""
import os
import re
import subprocess
import sys
import time

import pytest

from tests.helpers import ROOT, processes_naming

SCRIPT = os.path.join(ROOT, "tests", "bench", "slurm", "multinode.sh")
NODES = 4  # the 8-rank point runs on all four
MESSAGE = 4 * 2**20  # bytes rank 0 sends to rank 1

PROG = f"""
import socket
import numpy as np
from mpi4py import MPI
comm = MPI.COMM_WORLD
rank = comm.Get_rank()
print(f"rank {{rank}} of {{comm.Get_size()}} on {{socket.gethostname()}}", flush=True)
n = {MESSAGE} // 8
buf = np.arange(n, dtype=np.float64) if rank == 0 else np.zeros(n)
comm.Barrier()
if rank == 0:
    comm.Send(buf, dest=1, tag=7)
elif rank == 1:
    comm.Recv(buf, source=0, tag=7)
    print(f"received {{buf.nbytes}} bytes, intact {{bool((buf == np.arange(n)).all())}}", flush=True)
comm.Barrier()
"""


def run(args, env, timeout=60):
    return subprocess.run(args, capture_output=True, text=True, env=env, timeout=timeout)


def logs(state):
    text = ""
    for name in sorted(os.listdir(os.path.join(state, "log"))):
        if name.endswith(".log"):
            text += f"\n--- {name}\n" + open(os.path.join(state, "log", name)).read()[-2000:]
    return text


def counters(veths):
    """{veth: (tx_bytes, rx_bytes)} of the host-side veths, as the host's sysfs counts them."""
    out = {}
    for v in veths:
        stats = f"/sys/class/net/{v}/statistics"
        out[v] = tuple(int(open(f"{stats}/{k}_bytes").read()) for k in ("tx", "rx"))
    return out


def leftovers(cl):
    """What of the cluster still exists: processes, namespaces, links, the /run/netns mount."""
    found = [f"process {p}" for p in processes_naming(cl["state"])]
    netns = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    links = subprocess.run(["ip", "-o", "link", "show"], capture_output=True, text=True).stdout
    link_names = {m.split("@")[0] for m in re.findall(r"^\d+: (\S+):", links, re.M)}
    for node in cl["nodes"].values():
        if re.search(rf"^{re.escape(node['netns'])}\b", netns, re.M):
            found.append(f"netns {node['netns']}")
        if node["veth"] in link_names:
            found.append(f"link {node['veth']}")
    if cl["bridge"] in link_names:
        found.append(f"bridge {cl['bridge']}")
    if not cl["runnetns_before"] and os.path.ismount("/run/netns") and not os.listdir("/run/netns"):
        found.append("mount /run/netns")
    return found


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """The 4-node cluster for this module, stopped in teardown (again, if a test stopped it)."""
    if os.geteuid() != 0:
        pytest.skip("the simulated multi-node Slurm needs root (network namespaces, a bridge, slurmd)")
    state = str(tmp_path_factory.mktemp("slurm-multinode"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("SLURM_")}  # not the single-node one
    env["SLURM_CONF"] = os.path.join(state, "slurm.conf")
    runnetns_before = os.path.ismount("/run/netns")
    t0 = time.time()
    try:  # stopped whatever happens, a start that timed out included
        res = run(["bash", SCRIPT, "start", str(NODES), state], env, timeout=900)  # apt-get when missing
        if res.returncode == 3:
            pytest.skip(res.stderr.strip().splitlines()[-1])
        assert res.returncode == 0, res.stdout + res.stderr + logs(state)
        started = time.time() - t0
        print(f"multi-node cluster started in {started:.1f} s:\n{res.stdout.strip()}")
        nodes = {}
        for line in open(os.path.join(state, "nodes")):
            name, addr, veth, netns = line.split()
            nodes[name] = {"addr": addr, "veth": veth, "netns": netns}
        conf = dict(l.strip().split("=", 1) for l in open(os.path.join(state, "cluster.env")) if "=" in l)
        yield {"state": state, "env": env, "nodes": nodes, "bridge": conf["TAG"] + "-br",
               "runnetns_before": runnetns_before}
    finally:
        stop = run(["bash", SCRIPT, "stop", state], env, timeout=120)
        print(stop.stdout + stop.stderr)


def test_every_node_idle(cluster):
    """sinfo: node1 .. node4, all idle, each at its own address on the bridge."""
    res = run(["sinfo", "-h", "-N", "-o", "%N %T %o"], cluster["env"])
    assert res.returncode == 0, res.stderr
    rows = sorted(res.stdout.split("\n")[:-1])
    assert rows == [f"node{i} idle {cluster['nodes'][f'node{i}']['addr']}" for i in range(1, NODES + 1)], res.stdout
    assert len({n["addr"] for n in cluster["nodes"].values()}) == NODES


def test_each_node_has_its_own_namespaces(cluster):
    """A step on both nodes: each has its hostname and its address (its only one), its own IPC and UTS
    namespace (neither the host's nor the other node's) and its own /dev/shm (a tmpfs of its own)."""
    probe = ('echo "$(hostname) $(hostname -I) $(readlink /proc/self/ns/ipc) $(readlink /proc/self/ns/uts) '
             '$(findmnt -n -o SOURCE /dev/shm | tail -n 1)"')
    res = run(["srun", "--mpi=none", "-N", "2", "-n", "2", "sh", "-c", probe], cluster["env"])
    assert res.returncode == 0, res.stdout + res.stderr + logs(cluster["state"])
    rows = sorted(l.split() for l in res.stdout.splitlines())
    assert [r[0] for r in rows] == ["node1", "node2"], res.stdout
    for host, addr, ipc, uts, shm in rows:
        assert addr == cluster["nodes"][host]["addr"]
        assert shm == f"{host}-shm"
    host_ipc, host_uts = os.readlink("/proc/self/ns/ipc"), os.readlink("/proc/self/ns/uts")
    assert len({r[2] for r in rows} | {host_ipc}) == 3 and len({r[3] for r in rows} | {host_uts}) == 3


def test_mpi_ranks_on_two_nodes_talk_over_the_veths(cluster):
    """srun --mpi=pmi2 -N 2 -n 2: rank 0 on one node sends 4 MiB to rank 1 on the other; the bytes
    arrive intact and the host-side veths count them: the receiving node's veth sent (tx) and the
    sending node's veth received (rx) at least 4 MiB more than before. The same two ranks on one
    node (-N 1) leave the veths almost idle: within a node the bytes go through shared memory."""
    env, veths = cluster["env"], [n["veth"] for n in cluster["nodes"].values()]
    before = counters(veths)
    res = run(["srun", "--mpi=pmi2", "-N", "2", "-n", "2", sys.executable, "-c", PROG], env, timeout=120)
    after = counters(veths)
    assert res.returncode == 0, res.stdout + res.stderr + logs(cluster["state"])
    hosts = dict(re.findall(r"^rank (\d) of 2 on (\S+)$", res.stdout, re.M))
    assert sorted(hosts) == ["0", "1"] and hosts["0"] != hosts["1"], res.stdout
    assert {hosts["0"], hosts["1"]} == {"node1", "node2"}
    assert f"received {MESSAGE} bytes, intact True" in res.stdout, res.stdout
    sender, receiver = cluster["nodes"][hosts["0"]]["veth"], cluster["nodes"][hosts["1"]]["veth"]
    delta = {v: (after[v][0] - before[v][0], after[v][1] - before[v][1]) for v in veths}
    print(f"veth bytes during the 2-node job (tx, rx): {delta}")
    assert delta[receiver][0] >= MESSAGE, delta  # bridge -> receiving node
    assert delta[sender][1] >= MESSAGE, delta    # sending node -> bridge

    before = counters(veths)
    res = run(["srun", "--mpi=pmi2", "-N", "1", "-n", "2", sys.executable, "-c", PROG], env, timeout=120)
    after = counters(veths)
    assert res.returncode == 0, res.stdout + res.stderr + logs(cluster["state"])
    assert len(set(re.findall(r"^rank \d of 2 on (\S+)$", res.stdout, re.M))) == 1, res.stdout
    assert f"received {MESSAGE} bytes, intact True" in res.stdout, res.stdout
    moved = sum(after[v][0] - before[v][0] + after[v][1] - before[v][1] for v in veths)
    print(f"veth bytes during the 1-node job (tx + rx, all veths): {moved}")
    assert moved < MESSAGE // 8


SCENE = ("--scene", "packed", "--particles", "500")


def bench(cl, *args, timeout=300):
    return run([sys.executable, "-m", "bench", *args], cl["env"], timeout=timeout)


def wait_queue_empty(cl, folder, limit=600):
    """Wait until none of the sweep's jobs (folder/jobs.json) is in the queue."""
    import json
    jobs = json.load(open(os.path.join(folder, "jobs.json")))
    ids = {jobs["prepare"]["job_id"], jobs["collect"]["job_id"]} | {p["job_id"] for p in jobs["points"].values()}
    deadline = time.time() + limit
    while time.time() < deadline:
        queue = run(["squeue", "-h", "-o", "%F"], cl["env"]).stdout.split()
        if not ids & set(queue):
            return
        time.sleep(2)
    raise AssertionError(f"jobs {sorted(ids)} still queued after {limit} s: " + run(["squeue"], cl["env"]).stdout)


@pytest.fixture(scope="module")
def node_sweeps(cluster, tmp_path_factory):
    """Two sweeps through `bench sweep --launcher slurm --nodes K` (issue 37's CI target): on 2
    nodes two 4-rank MPI points (4-2-2-1-1; 4-4-1-1-1, whose end blocks have no neighbour on the
    other node) and a hybrid point of 2 ranks x 2 threads (2-2-1-1-2),
    on 4 nodes an 8-rank MPI point (8-2-2-2-1), each beside the serial reference the sweep adds."""
    base = tmp_path_factory.mktemp("node-sweeps")
    out = {}
    for k, mappings in ((2, "4-2-2-1-1,4-4-1-1-1,2-2-1-1-2"), (4, "8-2-2-2-1")):
        folder = str(base / f"nodes{k}")
        res = bench(cluster, "sweep", *SCENE, "--steps", "12", "--warmup", "2", "--mappings", mappings,
                    "--launcher", "slurm", "--nodes", str(k), "--out", folder)
        assert res.returncode == 0, res.stdout + res.stderr
        out[k] = folder
    for folder in out.values():
        wait_queue_empty(cluster, folder)
    return out


def _points(folder):
    import pandas as pd
    runs = pd.read_csv(os.path.join(folder, "runs.csv"))
    return {r["mapping"]: r for _, r in runs.iterrows()}


def test_sweeps_across_nodes_done_and_bit_identical(node_sweeps):
    """Every point of both sweeps is done, and the final state of each MPI and hybrid point,
    whose ranks ran on K hosts that talked over the simulated network, equals the serial
    reference's bit for bit (np.array_equal: DESIGN.md, Determinism)."""
    import json
    import numpy as np
    for k, folder in node_sweeps.items():
        points = _points(folder)
        assert all(r["status"] == "done" for r in points.values()), {m: r["reason"] for m, r in points.items()}
        ref = np.load(os.path.join(folder, points["1-1-1-1-1"]["point"], "rep0", "state.npz"))
        for mapping, r in points.items():
            if mapping == "1-1-1-1-1":
                continue
            rep = os.path.join(folder, r["point"], "rep0")
            got = np.load(os.path.join(rep, "state.npz"))
            for key in ref.files:  # id, pos, quat, vel, omega, axes, shape
                assert np.array_equal(ref[key], got[key]), (mapping, key)
            info = json.load(open(os.path.join(rep, "run.json")))
            assert len(info["nodes"]) == k and int(r["nodes"]) == k, (mapping, info["nodes"])


def test_ranks_placed_by_node_and_traffic_split(node_sweeps):
    """run.json `placement`: consecutive ranks share a node, each node the same count (P / K),
    so each node holds a contiguous run of blocks in row-major order: on 2 nodes 4-2-2-1-1 puts
    the x = 0 slab on one node and x = 1 on the other. A rank's neighbours_internode are exactly
    its neighbours on another host. steps.csv: bytes_internode > 0 exactly for the ranks with a
    neighbour on another node (0 for the others), and within-node bytes (bytes_sent -
    bytes_internode) > 0 exactly for the ranks with a neighbour on their own; runs.csv
    wire_internodeT is > 0 and at most wireT."""
    import json
    import pandas as pd
    for k, folder in node_sweeps.items():
        for mapping, r in _points(folder).items():
            if mapping == "1-1-1-1-1":
                continue
            rep = os.path.join(folder, r["point"], "rep0")
            info = json.load(open(os.path.join(rep, "run.json")))
            place = info["placement"]
            procs = len(place)
            hosts = [place[str(q)]["host"] for q in range(procs)]
            per = procs // k
            assert all(hosts[q] == hosts[(q // per) * per] for q in range(procs)), hosts
            assert len(set(hosts)) == k
            if mapping == "4-2-2-1-1":
                assert [place[str(q)]["block"][0] for q in range(4)] == [0, 0, 1, 1]
            if mapping == "4-4-1-1-1":  # ranks 0 and 3 talk only within their node
                assert [place[str(q)]["neighbours_internode"] for q in range(4)] == [[], [2], [1], []]
            steps = pd.read_csv(os.path.join(rep, "steps.csv"))
            sent = steps.groupby("rank")[["bytes_sent", "bytes_internode", "msgs_internode"]].sum()
            for q in range(procs):
                p = place[str(q)]
                other = sorted(n for n in p["neighbours"] if hosts[n] != hosts[q])
                assert p["neighbours_internode"] == other, (mapping, q)
                assert (sent.loc[q, "bytes_internode"] > 0) == bool(other), (mapping, q, sent.loc[q])
                own = [n for n in p["neighbours"] if hosts[n] == hosts[q]]
                within = sent.loc[q, "bytes_sent"] - sent.loc[q, "bytes_internode"]
                assert (within > 0) == bool(own), (mapping, q, sent.loc[q])
            assert 0 < r["wire_internodeT"] <= r["wireT"], (mapping, r["wire_internodeT"], r["wireT"])


def test_too_many_ranks_a_node_refused_before_submission(cluster, tmp_path):
    """8 ranks on --nodes 2 is 4 a node, where sinfo says a node has 2 CPUs: refused in one line
    before any job is submitted (no jobs.json), as is a 2-rank point on --nodes 4."""
    for mappings, nodes, words in (("8-2-2-2-1", "2", "needs 4 CPUs on a node"), ("2-2-1-1-1", "4", "has only 2")):
        folder = tmp_path / f"refused{nodes}"
        res = bench(cluster, "sweep", *SCENE, "--steps", "5", "--mappings", mappings, "--launcher", "slurm",
                    "--nodes", nodes, "--out", str(folder))
        lines = res.stderr.strip().splitlines()
        assert res.returncode == 2 and len(lines) == 1 and words in lines[0], res.stdout + res.stderr
        assert not (folder / "jobs.json").exists()


def test_sweep_on_hosts_without_slurm(cluster, tmp_path):
    """`bench sweep --hosts node1,node2` (the local launcher, mpiexec -hosts; issue 37 part 2):
    Hydra reaches the nodes through tests/bench/slurm/nodessh (as ssh would), the 4-rank point runs
    two consecutive ranks a node, x slab by slab, and ends bit-identical to the serial reference."""
    import json
    import numpy as np
    env = dict(cluster["env"], MULTINODE_STATE=cluster["state"], HYDRA_LAUNCHER="ssh",
               HYDRA_LAUNCHER_EXEC=os.path.join(os.path.dirname(SCRIPT), "nodessh"))
    folder = str(tmp_path / "hosts")
    res = run([sys.executable, "-m", "bench", "sweep", *SCENE, "--steps", "12", "--warmup", "2", "--mappings",
               "4-2-2-1-1", "--hosts", "node1,node2", "--out", folder], env, timeout=600)
    assert res.returncode == 0, res.stdout + res.stderr
    points = _points(folder)
    assert points["4-2-2-1-1"]["status"] == "done" and int(points["4-2-2-1-1"]["nodes"]) == 2
    ref = np.load(os.path.join(folder, points["1-1-1-1-1"]["point"], "rep0", "state.npz"))
    rep = os.path.join(folder, points["4-2-2-1-1"]["point"], "rep0")
    got = np.load(os.path.join(rep, "state.npz"))
    assert all(np.array_equal(ref[k], got[k]) for k in ref.files)
    place = json.load(open(os.path.join(rep, "run.json")))["placement"]
    assert [(place[str(q)]["host"], place[str(q)]["block"][0]) for q in range(4)] == \
        [("node1", 0), ("node1", 0), ("node2", 1), ("node2", 1)]


def test_a_lost_node_is_named(cluster, tmp_path):
    """A node lost mid-run: the slurmd of a node holding ranks of a running 4-rank point and every
    process on that node are killed (SIGKILL). The run ends with one line naming the node and its
    ranks (2 and 3: consecutive ranks share a node); the point reads `failed` with that reason; the
    steps already written are kept.
    (Runs last but one: the node stays down until the cluster stops.)"""
    folder = str(tmp_path / "lost")
    res = bench(cluster, "sweep", *SCENE, "--steps", "40000", "--warmup", "2", "--mappings", "4-2-2-1-1",
                "--launcher", "slurm", "--nodes", "2", "--out", folder)
    assert res.returncode == 0, res.stdout + res.stderr
    import glob
    import json
    deadline = time.time() + 300
    rep = None
    while time.time() < deadline:  # until the 4-rank point has written steps
        found = glob.glob(os.path.join(folder, "4-2-2-1-1-*", "rep0", "steps.rank*.csv"))
        if found and os.path.getsize(found[0]) > 2000:
            rep = os.path.dirname(found[0])
            break
        time.sleep(1)
    assert rep, "the 4-rank point did not start writing steps"
    place = None
    while time.time() < deadline and place is None:
        try:
            place = json.load(open(os.path.join(rep, "run.json"))).get("placement")
        except (OSError, ValueError):
            time.sleep(1)
    victim = place["3"]["host"]  # the node of the last ranks
    netns = cluster["nodes"][victim]["netns"]
    pids = subprocess.run(["ip", "netns", "pids", netns], capture_output=True, text=True).stdout.split()
    assert pids
    subprocess.run(["kill", "-9", *pids], check=False)
    status = {}
    try:  # until the job wrapper on the surviving node records the outcome
        while time.time() < deadline:
            status = json.load(open(os.path.join(rep, "status.json")))
            if status.get("status") not in (None, "running"):
                break
            time.sleep(1)
    finally:
        bench(cluster, "sweep", "--cancel", folder)
    assert status["status"] == "failed", status
    reason = status["reason"]
    # whichever sees it first: Slurm (SlurmdTimeout, 15 s here: bench.sweep.job) or the run's heartbeat
    # watchdog (30 s without a step: bench.run.supervise)
    assert "\n" not in reason and re.search(rf"node {victim} with ranks 2, 3 lost mid-run|rank [23] \(pid \d+ on "
                                             rf"{victim}\) stopped responding", reason), reason
    rows = open(os.path.join(rep, "steps.csv")).read().splitlines()
    assert len(rows) > 10 and rows[0].startswith("step,rank")  # the steps written before the loss, merged
    collect = bench(cluster, "collect", folder)  # what the collect job would write (it was cancelled)
    assert collect.returncode == 4, collect.stdout + collect.stderr
    runs = _points(folder)
    assert runs["4-2-2-1-1"]["status"] == "failed" and victim in runs["4-2-2-1-1"]["reason"]


def test_stop_leaves_nothing(cluster):
    """stop: no slurmd, slurmctld or munged of the cluster runs, and no namespace, veth, bridge or
    /run/netns mount that start made is left; a second stop finds nothing to do and succeeds."""
    env, state = cluster["env"], cluster["state"]
    pids = [int(open(os.path.join(state, f)).read()) for f in
            ["run/slurmctld.pid", "munge/munged.pid"] + [f"run/slurmd.{n}.pid" for n in cluster["nodes"]]]
    assert processes_naming(state), "the cluster's daemons should be running before stop"
    t0 = time.time()
    res = run(["bash", SCRIPT, "stop", state], env, timeout=120)
    print(f"stopped in {time.time() - t0:.1f} s:\n{res.stdout}")
    assert res.returncode == 0, res.stdout + res.stderr
    # (the node lost in test_a_lost_node_is_named has no slurmd left to stop)
    assert len(re.findall(r"slurmd\.node\d \d+", res.stdout)) >= NODES - 1, res.stdout
    assert re.search(r"stopped slurmctld \d+, munged \d+", res.stdout), res.stdout
    for pid in pids:
        stat = f"/proc/{pid}/stat"
        assert not os.path.exists(stat) or open(stat).read().rsplit(")", 1)[1].split()[0] == "Z", pid
    assert leftovers(cluster) == []
    again = run(["bash", SCRIPT, "stop", state], env, timeout=60)
    assert again.returncode == 0 and again.stdout == "", again.stdout + again.stderr
    assert leftovers(cluster) == []
