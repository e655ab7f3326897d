"""Many recordings in one command: one task per recording, in process or on Dask.

A fleet is a list of recordings (rosbag2 directories, ``.mcap``/``.db3`` files, CSV/Parquet
tables) found from the paths, directories and globs a user gives (:func:`expand_paths`). Each
recording is one task that opens its own file and returns a :class:`RecordingOutcome`: its
status, the exit code it would have had alone, and the JSON document the single-recording
command writes. The tasks run in this process (:func:`run_serial`, the reference) or on
``dask.distributed`` (:func:`run_dask`: an embedded ``LocalCluster`` on 127.0.0.1, or an
existing scheduler); they come back as they finish. :func:`run_fleet` writes one JSON per
recording as it arrives, then the summary table (``summary.csv``) and the figure
(``fleet.png``: every recording's β_total and alarm timeline per model, recordings with
an alarm first).

What a task does is a use case's typed job (:class:`~twotank_validation.usecases.ValidateJob`,
:class:`~twotank_validation.usecases.DiagnoseJob`: a picklable frozen dataclass): each task
runs ``job.at(path).run()`` and keeps its outcome; this module only runs, collects and
summarises.
"""

from __future__ import annotations

import contextlib
import glob
import logging
import math
import os
import re
import signal
from collections.abc import Callable, Generator, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from multiprocessing import resource_tracker
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from twotank_validation import tables
from twotank_validation.errors import (
    ExitCode,
    Interrupted,
    TwotankError,
    held_interrupts,
    interruption,
)
from twotank_validation.usecases import Outcome, Status
from twotank_validation.usecases.outcome import write_json

_SIGNAL_OF_CODE: dict[int, int] = {
    ExitCode.INTERRUPTED: signal.SIGINT,
    ExitCode.TERMINATED: signal.SIGTERM,
}

if TYPE_CHECKING:
    import pandas as pd

BAG_SUFFIXES = (".mcap", ".db3")
"""Storage files read as bags (a plain MCAP file, or the storage file of a rosbag2 bag)."""
RECORDING_SUFFIXES = BAG_SUFFIXES + tuple(tables.TABLE_SUFFIXES)
"""File suffixes taken as recordings when a directory is searched."""

STATUS_COMPLETE = Status.COMPLETE.value
"""Read completely and every model judged (a diagnosis: diagnosed)."""
STATUS_NOT_JUDGED = Status.NOT_JUDGED.value
"""Read completely, but a model had no judged window (a diagnosis: nothing diagnosed)."""
STATUS_INCOMPLETE = Status.INCOMPLETE.value
"""Not read completely (damage, a topic missing); windows before the damage are judged."""
STATUS_UNREADABLE = Status.UNREADABLE.value
"""Nothing could be read (not a recording, empty, unusable settings): the error says why."""
STATUS_FAILED = "failed"
"""The task itself failed (an unexpected error or a lost worker): the error says which."""
STATUS_INTERRUPTED = Status.INTERRUPTED.value
"""Not finished: the run was stopped by SIGINT or SIGTERM (what a task had judged in this
process is kept in its JSON)."""
STATUS_SKIPPED = "skipped"
"""A file in a searched directory that is not a recording (listed, not judged)."""

_ORDER = {
    STATUS_COMPLETE: 0,
    STATUS_NOT_JUDGED: 1,
    STATUS_INCOMPLETE: 2,
    STATUS_UNREADABLE: 3,
    STATUS_FAILED: 3,
    STATUS_INTERRUPTED: 3,
    STATUS_SKIPPED: 4,
}

WORKER_ENV = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
"""Set in every embedded worker's environment (with this process's ``ROS_DOMAIN_ID``)."""


class FleetError(TwotankError, ValueError):
    """The paths name no recording, or the fleet settings cannot be used (says the fix)."""


@dataclass(frozen=True)
class RecordingOutcome:
    """What one task found in one recording.

    Attributes:
        path: the recording as it was given to the task.
        status: one of the ``STATUS_*`` values.
        code: the exit code the single-recording command would have returned.
        document: the JSON the single-recording command writes (``validate --json``,
            ``diagnose --json``), or None where it writes none.
        timeline: the replay's ``replay.summary_json`` (windows per model: start, end,
            beta, alarm; s from the recording start), or None where nothing was read.
        messages: the warnings and errors the single-recording command prints on stderr,
            each with its ``WARNING:``/``ERROR:`` prefix.
    """

    path: str
    status: str
    code: int
    document: dict[str, Any] | None = None
    timeline: dict[str, Any] | None = None
    messages: tuple[str, ...] = ()

    @property
    def problem(self) -> str:
        """The first error, else the first warning, without its prefix ("" if none).

        A recording the run did not finish: that it was not finished.
        """
        for prefix in ("ERROR: ", "WARNING: "):
            for m in self.messages:
                if m.startswith(prefix):
                    return m[len(prefix) :]
        if self.status == STATUS_INTERRUPTED:
            return "not finished: the run was interrupted"
        return ""

    def alarms(self) -> dict[str, float]:
        """Model -> time of its first alarm (s from the recording start), models with one."""
        if self.timeline is None:
            return {}
        return {
            name: float(e["first_alarm"])
            for name, e in self.timeline["models"].items()
            if e["first_alarm"] is not None
        }

    @classmethod
    def of(cls, path: str, outcome: Outcome) -> RecordingOutcome:
        """The outcome of a job on the recording ``path``, in a fleet's plain terms."""
        return cls(
            path,
            outcome.status.value,
            int(outcome.code),
            outcome.document,
            outcome.summary,
            outcome.said(),
        )


class Job(Protocol):
    """A use case's job (picklable): the same job on another recording, and its run."""

    def at(self, path: str) -> Job:
        """The job on the recording ``path``, writing nothing of its own."""
        ...

    def run(self) -> Outcome:
        """Its outcome."""
        ...


# --------------------------------------------------------------------------- finding recordings


@dataclass(frozen=True)
class Expansion:
    """The recordings found in the paths, and the files passed over.

    Attributes:
        recordings: paths of recordings, in the order given (a directory's and a glob's
            sorted), each once.
        skipped: (path, why) of files in searched directories that are not recordings.
    """

    recordings: tuple[str, ...]
    skipped: tuple[tuple[str, str], ...] = ()


def is_bag_dir(path: Path) -> bool:
    """A rosbag2 directory: it holds ``metadata.yaml`` (one recording, however many files)."""
    return (path / "metadata.yaml").is_file()


def is_fleet_dir(path: Path) -> bool:
    """A directory of recordings (not itself a bag), holding at least one recording."""
    return path.is_dir() and not is_bag_dir(path) and bool(_search(path)[0])


def _has_magic(text: str) -> bool:
    return glob.has_magic(text)


def is_single(paths: Sequence[str]) -> bool:
    """One recording named directly: the single-recording command's case.

    That is one path that exists or is no glob pattern (a missing path is the single
    command's error), and is not a directory of recordings.
    """
    if len(paths) != 1:
        return False
    p = Path(paths[0])
    if _has_magic(paths[0]) and not p.exists():
        return False
    return not is_fleet_dir(p)


def _search(root: Path) -> tuple[list[str], list[tuple[str, str]]]:
    """Recordings under a directory (sorted, recursive; a bag directory is not entered)."""
    found: list[str] = []
    skipped: list[tuple[str, str]] = []
    for p in sorted(root.iterdir()):
        if p.name.startswith("."):
            continue
        if p.is_dir():
            if is_bag_dir(p):
                found.append(str(p))
            else:
                inner, passed = _search(p)
                found += inner
                skipped += passed
        elif p.suffix.lower() in RECORDING_SUFFIXES:
            found.append(str(p))
        else:
            skipped.append(
                (
                    str(p),
                    f"not a recording (suffix not one of {', '.join(RECORDING_SUFFIXES)}, and "
                    "not a bag directory)",
                )
            )
    return found, skipped


def expand_paths(paths: Iterable[str]) -> Expansion:
    """The recordings named by paths, directories and glob patterns.

    A bag directory (``metadata.yaml`` inside), a file named directly (a ``.mcap``/``.db3``
    file, a table; a file that is not a recording is judged unreadable, with the reason) is
    one recording; another directory is searched recursively for bag directories and files
    with a recording's suffix (other files are listed as skipped); a pattern (``*``, ``?``,
    ``[``; ``**`` for any depth) names what it matches.

    Raises:
        FleetError: a path that does not exist, a pattern that matches nothing, or no
            recording at all.
    """
    found: list[str] = []
    skipped: list[tuple[str, str]] = []
    for text in paths:
        p = Path(text)
        if p.exists():
            names = [text]
        elif _has_magic(text):
            names = sorted(glob.glob(text, recursive=True))
            if not names:
                raise FleetError(f"the pattern {text!r} matches nothing: check it (quote it)")
        else:
            raise FleetError(f"{text} does not exist: check the path")
        for name in names:
            q = Path(name)
            if q.is_dir() and not is_bag_dir(q):
                inner, passed = _search(q)
                found += inner
                skipped += passed
            else:
                found.append(name)
    seen: set[str] = set()
    unique = []
    for name in found:
        key = os.path.realpath(name)
        if key not in seen:
            seen.add(key)
            unique.append(name)
    if not unique:
        given = ", ".join(paths)
        raise FleetError(
            f"no recording found in {given}: give bag directories, .mcap/.db3 files or "
            "CSV/Parquet tables, or a directory holding them"
        )
    return Expansion(tuple(unique), tuple(skipped))


def output_names(paths: Sequence[str]) -> dict[str, str]:
    """Recording -> a file stem unique among them (its path below their common folder).

    ``day1/run3`` -> ``day1__run3``; a file keeps its suffix (``a.mcap`` -> ``a.mcap``) so a
    file and a directory of the same stem do not collide.
    """
    real = [os.path.realpath(p) for p in paths]
    parents = [os.path.dirname(r) for r in real]
    base = os.path.commonpath(parents) if parents else ""
    out: dict[str, str] = {}
    used: set[str] = set()
    for p, r in zip(paths, real, strict=True):
        rel = os.path.relpath(r, base) if base else os.path.basename(r)
        stem = re.sub(r"[^\w.+-]", "_", rel.replace(os.sep, "__"))
        name, k = stem, 1
        while name in used:
            k += 1
            name = f"{stem}~{k}"
        used.add(name)
        out[p] = name
    return out


# --------------------------------------------------------------------------- running


def run_task(job: Job, path: str) -> RecordingOutcome:
    """``job.at(path).run()``; an unexpected error becomes a failed outcome (the others go on)."""
    try:
        return RecordingOutcome.of(path, job.at(path).run())
    except Exception as err:  # one recording's bug must not stop the fleet
        return failed(path, f"{type(err).__name__}: {err}")


def failed(path: str, why: str) -> RecordingOutcome:
    """The outcome of a task that did not finish (a bug or a lost worker)."""
    return RecordingOutcome(
        path,
        STATUS_FAILED,
        -1,
        messages=(f"ERROR: the task failed ({why}); please report it with the recording",),
    )


def run_serial(job: Job, paths: Sequence[str]) -> Generator[RecordingOutcome, None, None]:
    """The tasks one after the other in this process (the reference of every other way)."""
    for path in paths:
        yield run_task(job, path)


@dataclass(frozen=True)
class TlsFiles:
    """This client's TLS files for a ``tls://`` scheduler (PEM paths).

    The same files as the ``--tls-ca-file``, ``--tls-cert`` and ``--tls-key`` options of
    ``dask scheduler`` and ``dask worker``, so one set of options serves all three.

    Attributes:
        ca_file: the certificate authority the scheduler's certificate must be signed by.
        cert: this client's certificate (the scheduler checks it against its own CA file).
        key: this client's private key; None: ``cert`` holds it.
    """

    ca_file: str
    cert: str
    key: str | None = None


@dataclass(frozen=True)
class DaskSettings:
    """Where the tasks run on Dask.

    Attributes:
        workers: processes of the embedded cluster (one thread each); 0: as many as cores.
        scheduler: address of an existing scheduler (``tcp://host:port`` or
            ``tls://host:port``); None: start an embedded ``LocalCluster`` on 127.0.0.1 (no
            dashboard).
        env: extra environment of the embedded workers (``WORKER_ENV`` and this process's
            ``ROS_DOMAIN_ID`` are always set).
        tls: the files for a ``tls://`` scheduler; None: distributed's own configuration
            (``distributed.comm.tls.*``), as ``dask`` reads it.
    """

    workers: int = 0
    scheduler: str | None = None
    env: Mapping[str, str] = field(default_factory=dict)
    tls: TlsFiles | None = None


def client_security(address: str, tls: TlsFiles | None) -> Any:
    """The ``distributed.security.Security`` to reach ``address`` with (FleetError if none fits).

    With ``tls`` the files given (encryption required); without, distributed's configuration,
    as a ``Client`` would read it. A ``tls://`` address needs a client TLS context (a CA and
    a certificate); a configuration that requires encryption refuses a ``tcp://`` address.
    """
    from distributed.security import Security  # noqa: PLC0415

    try:
        if tls is not None:
            security = Security(
                tls_ca_file=tls.ca_file,
                tls_client_cert=tls.cert,
                tls_client_key=tls.key,
                require_encryption=True,
            )
        else:
            security = Security()
        context = security.get_connection_args("client")["ssl_context"]
    except (OSError, ValueError) as err:  # ssl.SSLError is an OSError
        raise FleetError(
            f"cannot use the TLS files for {address} ({err}): give PEM files, the client's "
            "certificate and key matching (--tls-cert, --tls-key)"
        ) from err
    if address.startswith("tls://") and context is None:
        raise FleetError(
            f"the scheduler {address} speaks TLS: give --tls-ca-file CA and --tls-cert CERT "
            "(and --tls-key KEY unless CERT holds it), or set distributed.comm.tls.ca-file "
            "and distributed.comm.tls.client.cert in Dask's configuration"
        )
    if security.require_encryption and not address.startswith("tls://"):
        raise FleetError(
            f"Dask's configuration requires encryption but {address} is not a tls:// "
            "address: give the scheduler's tls:// address"
        )
    return security


def worker_env(extra: Mapping[str, str] | None = None) -> dict[str, str]:
    """The embedded workers' environment: loopback DDS, this domain, single-threaded BLAS."""
    env = dict(WORKER_ENV)
    env["ROS_DOMAIN_ID"] = os.environ.get("ROS_DOMAIN_ID", "77")
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env[var] = "1"  # one core per worker: the cluster is sized to the cores
    env.update(extra or {})
    return env


def local_cluster(workers: int = 0, env: Mapping[str, str] | None = None) -> Any:
    """The embedded ``distributed.LocalCluster``: processes of one thread on 127.0.0.1.

    Args:
        workers: worker processes; 0: as many as cores.
        env: extra environment of the workers (:func:`worker_env`).

    Returns:
        The cluster, started (close it, or use it as a context manager). No dashboard; the
        workers' statistical profiler is off (it samples the task thread every 10 ms, taking
        the GIL from the replay, for a dashboard nobody looks at).
    """
    import dask  # noqa: PLC0415
    from distributed import LocalCluster  # noqa: PLC0415

    quiet = {  # given to the workers too
        "distributed.worker.profile.enabled": False,
        # the housekeeping loops of every process, at rates a dashboard would want: each
        # wakes its process (and the GIL) while a replay runs on the worker's one thread
        "distributed.admin.system-monitor.interval": "2s",
        "distributed.admin.tick.interval": "200ms",
        "distributed.worker.memory.monitor-interval": "1s",
        # tasks of one kind, one per recording: nothing to rebalance
        "distributed.scheduler.work-stealing": False,
        "distributed.scheduler.active-memory-manager.start": False,
    }
    cluster = None
    try:
        with dask.config.set(quiet), _workers_without_sigint():
            cluster = LocalCluster(
                n_workers=workers or os.cpu_count() or 1,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address=None,
                # no dashboard; the scheduler's health and metrics routes on loopback, any port
                scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"},
                silence_logs=40,
                env=worker_env(env),
            )
    except KeyboardInterrupt:  # a signal held while it started: stop it again
        if cluster is not None:
            cluster.close()
        raise
    return cluster


@contextlib.contextmanager
def _workers_without_sigint() -> Iterator[None]:
    """The worker processes started inside never act on SIGINT.

    Ctrl-C reaches the terminal's whole process group: the workers would each stop with a
    traceback. SIGINT is blocked in this thread while they start (the threads that start
    them, and they, inherit the blocked signal), and a SIGINT or SIGTERM to this process is
    held until the cluster has started (:func:`held_interrupts`); this process then stops the
    run and closes the cluster, which ends the workers.
    """
    # started first: starting it unblocks SIGINT in the thread that does (which would be the
    # one that starts the workers)
    resource_tracker.ensure_running()
    with held_interrupts():
        previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            yield
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def run_dask(
    job: Job, paths: Sequence[str], settings: DaskSettings
) -> Generator[RecordingOutcome, None, None]:
    """The tasks on Dask, one per recording (it opens its own file), as they finish.

    A task that raises or whose worker is lost gives a failed outcome for its recording.
    """
    from distributed import Client, as_completed  # noqa: PLC0415

    cluster = None
    security = None
    if settings.scheduler is None:
        cluster = local_cluster(settings.workers, settings.env)
    else:
        security = client_security(settings.scheduler, settings.tls)
    try:
        client = Client(cluster if cluster is not None else settings.scheduler, security=security)
    except (OSError, TimeoutError) as err:
        if cluster is not None:
            cluster.close()
        plain = (settings.scheduler or "").startswith("tcp://")
        raise FleetError(
            f"cannot reach the Dask scheduler {settings.scheduler} ({err}): start one "
            "(`dask scheduler --host 127.0.0.1`, docs/fleet.md) or drop --scheduler"
            + (
                "; a scheduler that listens with TLS drops plain connections: give its "
                "tls:// address and --tls-ca-file/--tls-cert/--tls-key"
                if plain
                else ""
            )
        ) from err
    try:
        futures = {
            client.submit(run_task, job, path, key=f"twotank-recording-{i}", pure=False): path
            for i, path in enumerate(paths)
        }
        for fut in as_completed(futures):
            if fut.status == "finished":
                yield fut.result()
            else:
                why: BaseException | None
                try:
                    why = fut.exception()
                except Exception as lost:  # cancelled: the reason is its text
                    why = lost
                yield failed(futures[fut], f"{type(why).__name__}: {why}")
            fut.release()
    except BaseException:  # interrupted (or closed early): the tasks in flight are dropped
        with _quiet_shutdown():
            _close(client, cluster)
        raise
    _close(client, cluster)


def _close(client: Any, cluster: Any) -> None:
    """Close the client, then the embedded cluster (if any), which ends its workers."""
    try:
        client.close()
    finally:
        if cluster is not None:
            cluster.close()


@contextlib.contextmanager
def _quiet_shutdown() -> Iterator[None]:
    """Distributed's own log quiet while a run stopped early shuts down.

    Tasks and workers cut off mid-way make its nannies log the cancellations of their
    shutdown as errors; the run says itself that it was interrupted.
    """
    log = logging.getLogger("distributed")
    level = log.level
    log.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        log.setLevel(level)


# --------------------------------------------------------------------------- the fleet


@dataclass(frozen=True)
class FleetResult:
    """A fleet run: the outcomes in summary order, the table, the files written."""

    outcomes: tuple[RecordingOutcome, ...]
    skipped: tuple[tuple[str, str], ...]
    table: pd.DataFrame
    code: int
    written: tuple[Path, ...]
    model_names: tuple[str, ...] = ()
    interrupted: Interrupted | None = None

    def said(self) -> list[str]:
        """The lines for stderr: each recording's warnings and errors, the files skipped."""
        lines = []
        for o in self.outcomes:
            for line in o.messages:
                kind, sep, text = line.partition(": ")
                if kind in ("WARNING", "ERROR") and sep:
                    lines.append(f"{kind}: {o.path}: {text}")
        lines += [f"note: skipped {path}: {why}" for path, why in self.skipped]
        return lines

    def text(self, out_dir: Path) -> list[str]:
        """The lines for stdout: the summary table and the counts."""
        shown = self.table.drop(columns=["json"], errors="ignore")
        counts: dict[str, int] = {}
        for o in self.outcomes:
            counts[o.status] = counts.get(o.status, 0) + 1
        told = ", ".join(f"{n} {status}" for status, n in counts.items())
        names = self.model_names or tuple(
            dict.fromkeys(m for o in self.outcomes for m in o.alarms())
        )
        per_model = ", ".join(
            f"model {m} on {sum(1 for o in self.outcomes if m in o.alarms())}" for m in names
        )
        return [
            shown.to_string(index=False, max_colwidth=48, float_format=lambda x: f"{x:.3f}"),
            f"{len(self.outcomes)} recording(s): {told}; alarms: {per_model or 'none'}; "
            f"written to {out_dir.resolve()} (summary.csv, fleet.png, one JSON each)",
        ]


def run_fleet(
    job: Job,
    expansion: Expansion,
    out_dir: Path,
    model_names: Sequence[str],
    *,
    dask: DaskSettings | None = None,
    progress: Callable[[RecordingOutcome], None] | None = None,
    figure: bool = True,
) -> FleetResult:
    """Run the job on every recording and write what it found.

    Writes ``out_dir/<name>.json`` per recording with a document (as it arrives),
    ``summary.csv`` (:func:`summary_table`) and ``fleet.png`` (:func:`plot_fleet`).

    Args:
        job: the use case's job (picklable for Dask); each task runs ``job.at(path)``.
        expansion: the recordings (:func:`expand_paths`).
        out_dir: folder to write into (made if missing).
        model_names: the models, in the table's and the figure's order.
        dask: where to run on Dask; None: serially in this process.
        progress: called with each outcome as it arrives.
        figure: write ``fleet.png``.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    names = output_names(expansion.recordings)
    paths = list(expansion.recordings)
    runs = run_serial(job, paths) if dask is None else run_dask(job, paths, dask)
    got: dict[str, RecordingOutcome] = {}
    written: list[Path] = []
    stop: Interrupted | None = None
    try:
        with contextlib.closing(runs):  # closed on an interrupt: Dask's workers shut down
            for outcome in runs:
                got[outcome.path] = outcome
                if outcome.document is not None:
                    target = out_dir / f"{names[outcome.path]}.json"
                    write_json(target, outcome.document)
                    written.append(target)
                if progress is not None:
                    progress(outcome)
                if outcome.status == STATUS_INTERRUPTED:  # a task in this process saw it
                    stop = Interrupted(_SIGNAL_OF_CODE.get(outcome.code, signal.SIGINT))
                    break
    except KeyboardInterrupt as err:  # SIGINT or SIGTERM: summarise what finished
        stop = interruption(err)
    for path in paths:  # a result that never came back is not lost silently
        if stop is not None:
            got.setdefault(path, RecordingOutcome(path, STATUS_INTERRUPTED, stop.exit_code))
        got.setdefault(path, failed(path, "no result came back"))
    ordered = order_outcomes([got[p] for p in paths])
    table = summary_table(ordered, model_names, names, expansion.skipped)
    csv = out_dir / "summary.csv"
    table.to_csv(csv, index=False)
    written.append(csv)
    if figure:
        png = out_dir / "fleet.png"
        plot_fleet(ordered, model_names, png, names)
        written.append(png)
    return FleetResult(
        tuple(ordered),
        expansion.skipped,
        table,
        fleet_exit_code(ordered) if stop is None else int(stop.exit_code),
        tuple(written),
        tuple(model_names),
        stop,
    )


def order_outcomes(outcomes: Iterable[RecordingOutcome]) -> list[RecordingOutcome]:
    """Recordings with an alarm first, then judged ones, then the rest; each group by path."""

    def key(o: RecordingOutcome) -> tuple[int, int, str]:
        return (0 if o.alarms() else 1, _ORDER[o.status], o.path)

    return sorted(outcomes, key=key)


EXIT_CODE_ORDER = (0, 4, 3, 5, 6)
"""Fleet exit codes, least to most severe (the fleet's is its most severe recording's; 6,
an alarm with ``--fail-on-alarm``, is the answer a pipeline asked for)."""
EXIT_UNREADABLE = int(ExitCode.UNREADABLE)
"""Some recording could not be read at all (or its task failed); the others were judged."""


def fleet_exit_code(outcomes: Iterable[RecordingOutcome]) -> int:
    """The most severe code: 6 alarm > 5 unreadable or failed > 3 incomplete > 4 not judged > 0.

    0 only when every recording was read completely and judged; a fleet of which nothing was
    judged never gets 0 (each such recording is 3, 4 or 5). 6 only with ``--fail-on-alarm``
    (a recording's own code is then 6 where an alarm rose).
    """
    codes = [0]
    for o in outcomes:
        if o.status == STATUS_SKIPPED:
            continue
        if o.code == ExitCode.ALARM:
            codes.append(int(ExitCode.ALARM))
        if o.status in (STATUS_UNREADABLE, STATUS_FAILED):
            codes.append(EXIT_UNREADABLE)
        elif o.status == STATUS_INCOMPLETE:
            codes.append(3)
        elif o.status == STATUS_NOT_JUDGED:
            codes.append(4)
    return max(codes, key=EXIT_CODE_ORDER.index)


def _num(x: object) -> float:
    return math.nan if x is None else float(x)  # type: ignore[arg-type]


def summary_table(
    outcomes: Sequence[RecordingOutcome],
    model_names: Sequence[str],
    names: Mapping[str, str] | None = None,
    skipped: Sequence[tuple[str, str]] = (),
) -> pd.DataFrame:
    """One row per recording (and per skipped file), in the given order.

    Columns: ``recording``, ``status``, ``code`` (the single command's exit code),
    ``messages`` (messages or rows read), per model ``<M> judged``, ``<M> not judged``,
    ``<M> beta_max``, ``<M> first_alarm_s`` (NaN: none), ``json`` (the file written, "" if
    none) and ``problem`` (the first error or warning).
    """
    import pandas as pd  # noqa: PLC0415 (imported on first use)

    rows = []
    for o in outcomes:
        row: dict[str, Any] = {
            "recording": o.path,
            "status": o.status,
            "code": o.code,
            "messages": o.timeline["messages"] if o.timeline is not None else 0,
        }
        for m in model_names:
            e = (o.timeline or {}).get("models", {}).get(m)
            row[f"{m} judged"] = e["judged"] if e else 0
            row[f"{m} not judged"] = e["not_judged"] if e else 0
            row[f"{m} beta_max"] = _num(e["beta_max"]) if e else math.nan
            row[f"{m} first_alarm_s"] = _num(e["first_alarm"]) if e else math.nan
        row["json"] = f"{names[o.path]}.json" if names and o.document is not None else ""
        row["problem"] = o.problem
        rows.append(row)
    for path, why in skipped:
        rows.append({"recording": path, "status": STATUS_SKIPPED, "code": 0, "problem": why})
    frame = pd.DataFrame(rows)
    counts = ["code", "messages"] + [f"{m} {k}" for m in model_names for k in _COUNTS]
    return frame.astype({c: "Int64" for c in counts if c in frame})  # blank where skipped


_COUNTS = ("judged", "not judged")


def plot_fleet(
    outcomes: Sequence[RecordingOutcome],
    model_names: Sequence[str],
    out: Path,
    names: Mapping[str, str] | None = None,
) -> Path:
    """Write :func:`fleet_figure` to ``out`` (PNG)."""
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig = fleet_figure(outcomes, model_names, names)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def window_beta_total(w: Mapping[str, Any]) -> float | None:
    """A window's β_total: what the verdict and the alarm use (as a report's alarm timeline).

    ``beta_total`` (the dynamics and the operating point, ``sqrt(beta² + beta_op²)``), else
    ``beta`` where the operating point was not checked; None where the window was not judged.
    """
    total = w.get("beta_total")
    return float(total) if total is not None and w["beta"] is not None else w["beta"]


def fleet_figure(
    outcomes: Sequence[RecordingOutcome],
    model_names: Sequence[str],
    names: Mapping[str, str] | None = None,
) -> Any:
    """Every recording's β_total and alarm timeline, one panel per model, a row per recording.

    Each report holds from its time (its window's end) to the next report's: a bar coloured
    by β_total (:func:`window_beta_total`, what the verdict and the alarm use: white at 1,
    blue below, red above; the bars' collection has the gid ``"beta_total"``), grey where
    the window was not judged; a black line under the row where the alarm was at ERROR, a
    triangle at the first alarm. Recordings with an alarm are at the top (the order given); a
    recording that could not be read shows its status.

    Returns:
        The matplotlib figure (Agg), not closed.
    """
    import matplotlib as mpl  # noqa: PLC0415

    mpl.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.collections import LineCollection  # noqa: PLC0415
    from matplotlib.colors import TwoSlopeNorm  # noqa: PLC0415

    n = max(len(outcomes), 1)
    betas = [
        b
        for o in outcomes
        if o.timeline is not None
        for e in o.timeline["models"].values()
        for w in e["windows"]
        if (b := window_beta_total(w)) is not None
    ]
    top = max([2.0, *(b for b in betas if math.isfinite(b))])
    norm = TwoSlopeNorm(vmin=0.0, vcenter=1.0, vmax=top)
    cmap = plt.get_cmap("coolwarm")
    cols = max(len(model_names), 1)
    fig, axes = plt.subplots(
        1,
        cols,
        figsize=(5.5 * cols + 1.5, min(max(0.32 * n + 1.9, 3.6), 120.0)),  # < 2**16 px
        sharey=True,
        squeeze=False,
        layout="constrained",
    )
    labels = [
        (names or {}).get(o.path, Path(o.path).name)
        + ("" if o.status in (STATUS_COMPLETE,) else f" ({o.status})")
        for o in outcomes
    ]
    for ax, model in zip(axes[0], model_names, strict=False):
        judged_segs, judged_b, grey_segs, alarm_segs, firsts = [], [], [], [], []
        for row, o in enumerate(outcomes):
            e = (o.timeline or {}).get("models", {}).get(model)
            if not e:
                continue
            for t0, t1, w in _report_spans(e["windows"]):
                seg = [(t0, row), (t1, row)]
                beta = window_beta_total(w)
                if beta is not None:
                    judged_segs.append(seg)
                    judged_b.append(beta)
                else:
                    grey_segs.append(seg)
                if w["alarm"] == "ERROR":
                    alarm_segs.append([(t0, row + 0.32), (t1, row + 0.32)])
            if e["first_alarm"] is not None:
                firsts.append((e["first_alarm"], row))
        ax.add_collection(LineCollection(grey_segs, colors="0.8", linewidths=7))
        bars = LineCollection(judged_segs, cmap=cmap, norm=norm, linewidths=7, gid="beta_total")
        bars.set_array(judged_b)
        ax.add_collection(bars)
        ax.add_collection(LineCollection(alarm_segs, colors="k", linewidths=1.5))
        if firsts:
            ax.scatter(*zip(*firsts, strict=True), marker="v", color="k", s=30, zorder=3)
        ax.autoscale_view()
        ax.set_xlim(left=0.0)
        ax.set_title(f"model {model}")
        ax.set_xlabel("time in the recording (s)")
    fig.colorbar(
        plt.cm.ScalarMappable(norm=norm, cmap=cmap),
        ax=axes[0].tolist(),
        label="β_total (dimensionless; 1: the limit)",
        fraction=0.03,
        pad=0.01,
    )
    axes[0][0].set_yticks(range(len(outcomes)), labels, fontsize=8)
    axes[0][0].set_ylim(len(outcomes) - 0.5, -0.5)
    axes[0][0].set_ylabel("recording")
    fig.suptitle(
        f"{len(outcomes)} recording(s): β_total = √(β² + β_op²), what the verdict and the "
        "alarm use\ngrey: not judged; black: alarm at ERROR (▼ the first); alarms on top",
        fontsize=9,
    )
    return fig


def _report_spans(
    windows: Sequence[Mapping[str, Any]],
) -> Iterator[tuple[float, float, Mapping[str, Any]]]:
    """``(from, to, window)``: each report from its window's end to the next report's end.

    The last holds for as long as the step before it (a lone report: an eighth of its
    window), so that every report is seen.
    """
    ends = [float(w["end"]) for w in windows]
    for i, w in enumerate(windows):
        if i + 1 < len(ends):
            to = ends[i + 1]
        elif i > 0:
            to = ends[i] + (ends[i] - ends[i - 1])
        else:
            to = ends[i] + (ends[i] - float(w["start"])) / 8
        yield ends[i], to, w
