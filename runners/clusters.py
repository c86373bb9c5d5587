"""A sweep's workers as batch jobs of an HPC scheduler (Slurm, PBS), through dask-jobqueue.

``nrtraffic sweep ... --cluster slurm`` starts the Dask scheduler in the sweep's own process (on the
login node) and submits ``--jobs`` batch jobs; each job asks for ``--job-cores`` cores,
``--job-memory`` and ``--job-walltime`` and runs one Dask worker process per core (one simulation
at a time each: libsumo holds one simulation per process). The job script runs the same Python
as the sweep (``sys.executable``), from the same working directory and with the same
``PYTHONPATH``, so the compute nodes must see the Python environment, the scenario and the output
folder at the same paths: a shared file system.

Everything here is checked before a job is submitted: a bad flag is a ``SweepError`` (exit 2)
naming the flag and the fix.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path


KINDS = {"slurm": ("sbatch", "SLURMCluster"), "pbs": ("qsub", "PBSCluster")}  # submit command, dask-jobqueue class
INSTALL_HINT = {
    "slurm": "run the sweep on the cluster's login node, where Slurm's commands are; to try it on this machine, "
             "install Slurm (Debian/Ubuntu: apt-get install slurm-wlm) and start a one-node cluster "
             "(tests/slurm/setup.sh does both)",
    "pbs": "run the sweep on the cluster's login node, where PBS's commands (qsub, qstat, qdel) are",
}
DEFAULT_MEMORY_PER_CORE_GIB = 2  # [GiB] per worker process, when --job-memory is not given
MIN_MEMORY_PER_CORE = 256 * 2**20  # [bytes] less than this per worker process cannot hold a run
DEFAULT_WALLTIME = "01:00:00"
LIFETIME_MARGIN_S = 300.0  # [s] workers leave this long before the walltime ends (long walltimes only)
JOB_FLAGS = ("jobs", "job_cores", "job_memory", "job_walltime", "queue", "account", "job_directives", "interface")


@dataclass(frozen=True)
class BatchSpec:
    """The batch jobs of a sweep on an HPC scheduler."""

    kind: str  # "slurm" or "pbs"
    jobs: int  # batch jobs at once
    cores: int  # cores per job = worker processes per job
    memory_bytes: int  # memory per job [bytes]
    walltime_s: int  # walltime per job [s]
    queue: str | None = None  # Slurm partition or PBS queue
    account: str | None = None
    directives: tuple[str, ...] = ()  # extra #SBATCH / #PBS lines
    interface: str | None = None  # network interface of the scheduler and workers, e.g. ib0

    @property
    def walltime(self) -> str:
        """``HH:MM:SS`` (hours may exceed 24), the form both Slurm and PBS read."""
        h, rest = divmod(self.walltime_s, 3600)
        return f"{h:02d}:{rest // 60:02d}:{rest % 60:02d}"

    @property
    def memory(self) -> str:
        """Memory per job for dask-jobqueue, in MiB (rounded down: the request never exceeds the flag)."""
        return f"{self.memory_bytes // 2**20}MiB"


def parse_walltime(text: str) -> int:
    """``HH:MM:SS`` or ``D-HH:MM:SS`` -> seconds (> 0). Slurm reads a bare ``A:B`` as minutes and
    seconds, so two-field forms are refused rather than guessed."""
    m = re.fullmatch(r"\s*(?:(\d+)-)?(\d+):(\d{2}):(\d{2})\s*", text or "")
    if not m or int(m[3]) > 59 or int(m[4]) > 59:
        raise _error(f"--job-walltime {text!r}: expected HH:MM:SS or D-HH:MM:SS, e.g. 02:00:00 for two hours")
    s = int(m[1] or 0) * 86400 + int(m[2]) * 3600 + int(m[3]) * 60 + int(m[4])
    if s <= 0:
        raise _error(f"--job-walltime {text!r}: must be longer than zero, e.g. 02:00:00")
    return s


def parse_memory(text: str, cores: int) -> int:
    """``4GB``, ``16GiB``, ``500MB`` ... (memory per job) -> bytes; at least
    ``MIN_MEMORY_PER_CORE`` per worker process."""
    from dask.utils import parse_bytes

    try:
        n = int(parse_bytes(text.strip()))
    except (ValueError, TypeError, AttributeError):
        n = -1
    if n <= 0 or not re.search(r"[a-zA-Z]", text):
        raise _error(f"--job-memory {text!r}: expected a size with its unit, e.g. 8GB or 16GiB (per job)")
    if n < MIN_MEMORY_PER_CORE * cores:
        raise _error(f"--job-memory {text}: {cores} worker process(es) per job need at least "
                         f"{MIN_MEMORY_PER_CORE * cores // 2**20} MiB; give more, e.g. "
                         f"{DEFAULT_MEMORY_PER_CORE_GIB * cores}GiB")
    return n


def from_args(args) -> BatchSpec | None:
    """The batch jobs the command line asks for (``None``: no ``--cluster``). Raises
    ``SweepError`` for a bad flag, a job flag without ``--cluster``, a missing submit command
    or a missing dask-jobqueue."""
    kind = getattr(args, "cluster", None)
    if kind is None:
        given = [f for f in JOB_FLAGS if getattr(args, f, None) not in (None, [], ())]
        if given:
            flag = "--" + given[0].replace("_", "-").replace("job-directives", "job-directive")
            raise _error(f"{flag} sets a batch job: it needs --cluster slurm or --cluster pbs")
        return None
    if kind not in KINDS:
        raise _error(f"--cluster {kind!r}: expected one of {', '.join(KINDS)}")
    jobs = 1 if args.jobs is None else args.jobs
    if jobs < 1:
        raise _error(f"--jobs {jobs}: need at least one batch job")
    cores = 1 if args.job_cores is None else args.job_cores
    if cores < 1:
        raise _error(f"--job-cores {cores}: need at least one core per job")
    memory = (parse_memory(args.job_memory, cores) if args.job_memory is not None
              else DEFAULT_MEMORY_PER_CORE_GIB * cores * 2**30)
    walltime = parse_walltime(args.job_walltime if args.job_walltime is not None else DEFAULT_WALLTIME)
    directives = tuple(d.strip() for d in (args.job_directives or ()))
    for d in directives:
        if any(ord(c) < 32 for c in d):  # (a newline would end the header line: the rest would run as a command)
            raise _error(f"--job-directive {d!r}: holds a line break or control character; give one option per "
                         "--job-directive")
        if not d.startswith("-"):
            raise _error(f"--job-directive {d!r}: expected an option of the job script's header, e.g. "
                             f"--job-directive=--qos=short (it becomes '#SBATCH --qos=short')")
    submit, _ = KINDS[kind]
    if shutil.which(submit) is None:
        raise _error(f"--cluster {kind}: {submit} is not on PATH: {INSTALL_HINT[kind]}")
    try:
        _jobqueue()
    except ImportError:
        raise _error(f"--cluster {kind} needs dask-jobqueue: pip install dask-jobqueue") from None
    return BatchSpec(kind, jobs, cores, memory, walltime, args.queue, args.account, directives, args.interface)


def make_cluster(spec: BatchSpec, n_runs: int, log_dir: Path):
    """Submit the batch jobs (no more than the runs need, and a new one whenever one ends before
    the sweep does) and return the dask-jobqueue cluster; the job script is written to ``log_dir/job.sh`` and the jobs' output goes to ``log_dir``."""
    cluster = job_cluster(spec, log_dir)
    log_dir = Path(log_dir).resolve()
    (log_dir / "job.sh").write_text(cluster.job_script())
    if spec.kind == "slurm":  # the scheduler's own check of the script (partition, account, directives) first
        import subprocess

        try:
            proc = subprocess.run(["sbatch", "--test-only", str(log_dir / "job.sh")], capture_output=True, text=True,
                                  timeout=60)
        except (OSError, subprocess.TimeoutExpired) as exc:
            cluster.close()
            raise _error(f"--cluster slurm: sbatch --test-only could not check the job script: {exc}") from None
        if proc.returncode != 0:
            cluster.close()
            said = "; ".join(ln.strip() for ln in proc.stderr.splitlines() if ln.strip())[-400:]
            raise _error(f"--cluster slurm: Slurm refuses the job script ({log_dir / 'job.sh'}): {said} (check "
                         "--partition, --account, --job-directive, --job-memory, --job-walltime)")
    n_jobs = max(1, min(spec.jobs, math.ceil(n_runs / spec.cores)))
    # adaptive with a fixed size: a job that ends (its walltime, scancel, a node lost) is replaced by a new one,
    # and its run is retried on another worker
    cluster.adapt(minimum_jobs=n_jobs, maximum_jobs=n_jobs)
    watch = "squeue --name nrtraffic-sweep" if spec.kind == "slurm" else "qstat"
    print(f"nrtraffic: submitted {n_jobs} {spec.kind} job(s) of {spec.cores} core(s), {spec.memory}, walltime "
          f"{spec.walltime} (job script: {log_dir / 'job.sh'}); the runs start when the jobs do ({watch})",
          file=sys.stderr)
    return cluster


def job_cluster(spec: BatchSpec, log_dir: Path):
    """The dask-jobqueue cluster of ``spec`` (its scheduler runs in this process), no job submitted
    yet: its ``job_script()`` is what each job runs."""
    import dask

    dask_jobqueue = _jobqueue()

    log_dir = Path(log_dir).resolve()
    log_dir.mkdir(parents=True, exist_ok=True)
    # the site's dask-jobqueue configuration (~/.config/dask/jobqueue.yaml: module loads, say) comes first
    def site(key: str) -> list[str]:
        return list(dask.config.get(f"jobqueue.{spec.kind}.{key}", None) or [])

    prologue = site("job-script-prologue") + [f"cd {_quote(os.getcwd())}"]
    if os.environ.get("PYTHONPATH"):
        prologue.append(f"export PYTHONPATH={_quote(os.environ['PYTHONPATH'])}")
    worker_args = site("worker-extra-args")
    if spec.walltime_s > 4 * LIFETIME_MARGIN_S:
        # a worker leaves before the scheduler kills its job, so that its run is not counted as a failure
        worker_args += ["--lifetime", f"{int(spec.walltime_s - LIFETIME_MARGIN_S)}s"]
    cls = getattr(dask_jobqueue, KINDS[spec.kind][1])
    return cls(
        cores=spec.cores, processes=spec.cores, memory=spec.memory, walltime=spec.walltime,
        queue=spec.queue, account=spec.account, job_extra_directives=list(spec.directives),
        interface=spec.interface, python=sys.executable, job_name="nrtraffic-sweep",
        job_script_prologue=prologue, worker_extra_args=worker_args, log_directory=str(log_dir),
        scheduler_options={"dashboard_address": ":0"})


def _jobqueue():
    """dask_jobqueue, imported with the command's own Ctrl-C handling kept (importing it replaces
    the SIGINT handler with one that exits with status 0, skipping what the command does on Ctrl-C)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        import dask_jobqueue

        return dask_jobqueue
    before = signal.getsignal(signal.SIGINT)
    try:
        import dask_jobqueue
    finally:
        signal.signal(signal.SIGINT, before)
    return dask_jobqueue


def _error(message: str) -> Exception:
    from runners.sweep import SweepError  # (imported here: the command line builds its parser without pandas)

    return SweepError(message)


def _quote(text: str) -> str:
    import shlex

    return shlex.quote(text)


def add_arguments(p, where) -> None:
    """The batch job flags of sweep and robustness; ``--cluster`` joins the ``where`` group
    (``--workers`` | ``--scheduler``)."""
    where.add_argument("--cluster", choices=sorted(KINDS), default=None,
                       help="run the workers as batch jobs of an HPC scheduler (needs sbatch or qsub on PATH, "
                            "and a file system that the compute nodes share: the same Python, scenario and DIR paths)")
    g = p.add_argument_group("batch jobs (with --cluster)")
    g.add_argument("--jobs", type=int, default=None, metavar="N", help="batch jobs at once (default 1)")
    g.add_argument("--job-cores", type=int, default=None, metavar="N",
                   help="cores per job; each runs one worker process, one simulation at a time (default 1)")
    g.add_argument("--job-memory", default=None, metavar="SIZE",
                   help=f"memory per job, e.g. 16GB or 16GiB (default {DEFAULT_MEMORY_PER_CORE_GIB} GiB per core)")
    g.add_argument("--job-walltime", default=None, metavar="HH:MM:SS",
                   help=f"walltime per job (default {DEFAULT_WALLTIME}); a job that ends before the sweep is "
                        f"replaced, and over {4 * LIFETIME_MARGIN_S / 60:g} min its workers leave "
                        f"{LIFETIME_MARGIN_S / 60:g} min before it ends")
    g.add_argument("--queue", "--partition", dest="queue", default=None, metavar="NAME",
                   help="Slurm partition or PBS queue (default: the scheduler's)")
    g.add_argument("--account", default=None, metavar="NAME", help="account to charge (default: the scheduler's)")
    g.add_argument("--job-directive", dest="job_directives", action="append", default=None, metavar="OPTION",
                   help="an extra header line of the job script, e.g. --job-directive=--qos=short (repeatable)")
    g.add_argument("--interface", default=None, metavar="NAME",
                   help="network interface the workers reach the scheduler by, e.g. ib0 (default: the host name's)")
