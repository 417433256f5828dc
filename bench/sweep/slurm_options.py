"""The Slurm options of a sweep (`bench sweep --launcher slurm`): their names, types and checks.

Plain Python (no numba, no numpy): bench.cli reads this table to build its flags before numba
starts. The same names are the keys of a sweep file's `[sweep.slurm]` table (flags win over the
file). Every bad value is refused in one line naming the field (ValueError).

| name | sbatch | jobs |
|---|---|---|
| partition, account, qos, constraint | --partition, --account, --qos, --constraint | every job |
| time | --time (minutes, MM:SS, HH:MM:SS, D-HH, D-HH:MM, D-HH:MM:SS) | every job; none: the partition's default |
| mem | --mem (per node, e.g. 4G) | every job |
| exclusive, hint | --exclusive, --hint | the points |
| nodes | --nodes | points with P > 1 (at most P); other points --nodes=1 |
| ntasks_per_node | --ntasks-per-node | points with P > 1: min(P, n) a node, --nodes = ceil(P / n) |
| mpi | how the ranks start: `srun --mpi=<mpi>` (default pmi2: what the mpich wheel needs; pmix makes it abort, none starts P one-rank runs), or `hydra`: the Python's own mpiexec inside the allocation (SLURM_MPI_TYPE=none exported, so a pmix site default does not reach Hydra's proxies) | points with P > 1 |
| extra | extra lines, each `#SBATCH ...` | every job |
"""  # noqa: E501
import re

DEFAULT_MPI = "pmi2"

# name: (kind, flag help); kinds: str, time, int, bool, mpi, lines
FIELDS = {
    "partition": ("str", "partition of every job (sbatch --partition)"),
    "account": ("str", "account charged (sbatch --account)"),
    "qos": ("str", "quality of service (sbatch --qos)"),
    "time": ("time", "time limit of every job: minutes, MM:SS, HH:MM:SS or D-HH[:MM[:SS]] (sbatch --time; "
                     "default: the partition's); a job killed at it is recorded as timeout"),
    "mem": ("str", "memory per node of every job, e.g. 4G (sbatch --mem)"),
    "nodes": ("int", "nodes of each point with P > 1 (sbatch --nodes, at most P)"),
    "ntasks_per_node": ("int", "ranks per node of each point with P > 1 (sbatch --ntasks-per-node)"),
    "exclusive": ("bool", "whole nodes for the points (sbatch --exclusive)"),
    "constraint": ("str", "node features of every job (sbatch --constraint)"),
    "hint": ("str", "placement hint of the points, e.g. nomultithread (sbatch --hint)"),
    "mpi": ("mpi", f"how ranks start: an srun --mpi type (default {DEFAULT_MPI}; the mpich wheel needs pmi2) "
                   "or hydra (mpiexec inside the allocation)"),
    "extra": ("lines", "extra '#SBATCH ...' lines of every job (sweep file only)"),
}

_TIME = re.compile(r"\d+|\d+:\d{1,2}|\d+:\d{1,2}:\d{1,2}|\d+-\d+|\d+-\d+:\d{1,2}|\d+-\d+:\d{1,2}:\d{1,2}")
_TOKEN = re.compile(r"[^\s'\"\\]+")  # one word on an #SBATCH line: no blanks, quotes or backslashes
_MPI = re.compile(r"[a-z][a-z0-9_]*")


def check_field(name, value, where="--slurm"):
    """The value of Slurm option `name` as the job scripts use it; ValueError (one line naming the
    field and `where` it came from) when it is not one."""
    if name not in FIELDS:
        raise ValueError(f"unknown Slurm option {name!r} in {where} (allowed: {', '.join(FIELDS)})")
    kind = FIELDS[name][0]
    if kind == "bool":
        if not isinstance(value, bool):
            raise ValueError(f"slurm.{name} in {where} must be true or false, got {value!r}")
        return value
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"slurm.{name} in {where} must be a positive integer, got {value!r}")
        return value
    if kind == "lines":
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise ValueError(f"slurm.{name} in {where} must be a list of '#SBATCH ...' strings, got {value!r}")
        for line in value:
            if not re.fullmatch(r"#SBATCH\s+-\S.*", line) or "\n" in line or "\r" in line:
                raise ValueError(f"slurm.{name} in {where}: {line!r} is not one '#SBATCH --option' line")
        return list(value)
    if kind == "time":
        if isinstance(value, int) and not isinstance(value, bool) and value >= 1:
            return str(value)  # minutes
        if not isinstance(value, str) or not (_TIME.fullmatch(value) or value.lower() in ("unlimited", "infinite")) \
                or value.strip("0:-") == "":
            raise ValueError(f"slurm.time in {where} must be minutes, MM:SS, HH:MM:SS or D-HH[:MM[:SS]], got {value!r}")
        return value
    if not isinstance(value, str) or not value:
        raise ValueError(f"slurm.{name} in {where} must be a non-empty string, got {value!r}")
    if kind == "mpi":
        if not _MPI.fullmatch(value):
            raise ValueError(f"slurm.mpi in {where} must be an srun --mpi type (pmi2, pmix, none, ...) or hydra, "
                             f"got {value!r}")
        return value
    if not _TOKEN.fullmatch(value):
        raise ValueError(f"slurm.{name} in {where} must be one word (no blanks or quotes), got {value!r}")
    return value


def check_options(table, where):
    """A dict of checked Slurm options from a mapping of names to values (a sweep file's
    [sweep.slurm] table, or the flags given)."""
    if not isinstance(table, dict):
        raise ValueError(f"slurm in {where} must be a table ([sweep.slurm]), got {table!r}")
    return {k: check_field(k, v, where) for k, v in table.items()}
