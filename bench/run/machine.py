"""Facts of the machine a run, a sweep or a sweep's job records (bench.run.records.environment,
bench.sweep.records.manifest, bench.sweep.job.node_info). Standard library only: a Slurm job
calls it before anything else starts."""
import os


def cpu_facts():
    """The CPUs of this machine: cpu_count (os.cpu_count(), the node's logical CPUs), usable (the
    CPUs this process may run on, os.sched_getaffinity; None where the platform has no affinity)
    and cpu_model (the first 'model name' of /proc/cpuinfo; None where there is none). Each record
    names and keeps them its own way."""
    facts = {"cpu_count": os.cpu_count(), "usable": None, "cpu_model": None}
    try:
        facts["usable"] = len(os.sched_getaffinity(0))
    except AttributeError:
        pass
    try:
        with open("/proc/cpuinfo") as fh:
            facts["cpu_model"] = next((l.split(":", 1)[1].strip() for l in fh if l.startswith("model name")), None)
    except OSError:
        pass
    return facts
