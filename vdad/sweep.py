"""Resumable parallel parameter sweeps: :func:`run_sweep` over a :class:`ResultStore`.

A sweep maps a function ``fn(config) -> dict`` over a list of configurations,
each a JSON-serialisable dict (a threshold, a distance, a method name...). Every
configuration is identified by :func:`config_key`, a hash of its canonical JSON
text, so key order inside a dict does not matter. Configurations run serially,
on local processes (joblib) or on a Dask cluster (``scheduler=``).

Resume guarantee: the calling process writes each result into the store as soon
as it arrives, one file ``<folder>/<key>.json`` per configuration, atomically (a
temporary file in the same folder, then :func:`os.replace`). A sweep killed at
any moment therefore leaves only complete records, and the same call run again
computes exactly the configurations whose records are missing: those that had
not started and those that were in flight.

Damaged records: a record that cannot be used counts as missing and is
recomputed, with one line on stderr that names its file and what is wrong: a
file that cannot be read (permission denied), a folder in its place (moved aside
under a new name, never deleted, so that the new record can be written), a file
that does not parse (written by other means, truncated), a record that lacks its
key, configuration or result dict, and a result that the caller's ``validate``
rejects (incomplete: a consumer's key missing, or of the wrong type).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import pickle
import sys
import time
import traceback
import uuid
import warnings
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import NamedTuple

from .errors import InputError, VdadError

_CLUSTER_HINT = 'pip install "vdad[cluster]"'
# Joblib warns when a result generator is closed early; on a failed configuration
# that is deliberate (the sweep stops and the SweepError says why).
_JOBLIB_EARLY_EXIT = r".*(tasks have been successfully executed|tasks which were still being)"


class SweepError(VdadError, RuntimeError):
    """A configuration of a sweep failed; the message names it and the original error."""


@dataclass
class SweepReport:
    """Outcome of :func:`run_sweep`.

    results: list of result dicts, one per entry of ``configs``, in that order
    (duplicate configurations share one result). computed: keys of the
    configurations computed by this call; reused: keys of those loaded from the
    store. Both lists hold each key once, in the order of first appearance in
    ``configs``. damaged: {key: what was wrong} of the computed configurations
    whose stored record could not be used (see :meth:`ResultStore.inspect`).
    """

    results: list[dict]
    computed: list[str]
    reused: list[str]
    damaged: dict[str, str] = field(default_factory=dict)


class _Outcome(NamedTuple):
    """What a worker sends back for one configuration (index into the missing list)."""

    index: int
    result: object
    seconds: float
    error: BaseException | None
    trace: str


def config_key(config):
    """Stable key of a configuration: the first 16 hex digits of the SHA-1 of its JSON text.

    config: a JSON-serialisable dict, canonicalised with sorted keys and no spaces,
    so ``{"a": 1, "b": 2}`` and ``{"b": 2, "a": 1}`` share a key (as do a tuple and
    the list with the same items). Returns a str of 16 characters. Raises
    :class:`InputError` for a non-dict or a dict that JSON cannot encode.
    """
    if not isinstance(config, dict):
        raise InputError(f"a sweep configuration must be a dict, got {type(config).__name__}: "
                         f"{config!r}")
    try:
        text = json.dumps(config, sort_keys=True, separators=(",", ":"))
    except (TypeError, ValueError) as exc:
        raise InputError(f"sweep configuration {config!r} is not JSON-serialisable: {exc}") from exc
    return hashlib.sha1(text.encode("utf-8")).hexdigest()[:16]


class ResultStore:
    """Folder of finished configurations: one JSON file ``<key>.json`` per configuration.

    Each file holds the record ``{"key", "config", "result", "seconds", "finished"}``
    (``seconds``: wall time of ``fn`` in the worker; ``finished``: ISO 8601 UTC
    time of the save). The folder is created if needed. Files that cannot be
    read or parsed, or whose content does not match their name, count as missing
    (:meth:`inspect` says why).
    """

    def __init__(self, folder):
        self.folder = Path(folder)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
        except (FileExistsError, NotADirectoryError) as exc:
            raise InputError(f"result store {str(self.folder)!r} is not a folder: {exc}") from exc

    def __repr__(self):
        return f"ResultStore({str(self.folder)!r})"

    def path(self, config):
        """Path of the record file of ``config``: ``<folder>/<config_key(config)>.json``."""
        return self.folder / f"{config_key(config)}.json"

    def has(self, config):
        """Whether a valid record of ``config`` is stored (a corrupt file counts as absent)."""
        return self._read(self.path(config)) is not None

    def load(self, config):
        """Stored result dict of ``config``; :class:`InputError` if no valid record exists."""
        path = self.path(config)
        record = self._read(path)
        if record is None:
            raise InputError(f"no stored result for configuration {config!r} "
                             f"(no valid record {str(path)!r})")
        return record["result"]

    def save(self, config, result, seconds):
        """Store ``result`` (a JSON-serialisable dict) of ``config``, atomically.

        seconds: wall time the computation took. The record is written to a
        temporary file in the store's folder, flushed to disk, then renamed over
        ``path(config)``, so a reader (or a restarted sweep) never sees half a
        record. Returns the record as it will be read back (JSON round trip).
        Raises :class:`InputError`, naming ``config``, for a result that is not a
        dict or that JSON cannot encode.
        """
        key = config_key(config)
        if not isinstance(result, dict):
            raise InputError(f"the result of sweep configuration {config!r} must be a dict, "
                             f"got {type(result).__name__}")
        record = {"key": key, "config": config, "result": result, "seconds": float(seconds),
                  "finished": datetime.now(timezone.utc).isoformat(timespec="milliseconds")}
        try:
            text = json.dumps(record, indent=2)
        except (TypeError, ValueError) as exc:
            raise InputError(f"the result of sweep configuration {config!r} is not "
                             f"JSON-serialisable: {exc}") from exc
        temporary = self.folder / f".{key}.{uuid.uuid4().hex}.tmp"
        target = self.folder / f"{key}.json"
        try:
            with open(temporary, "x", encoding="utf-8") as handle:
                handle.write(text)
                handle.flush()
                os.fsync(handle.fileno())
            try:
                os.replace(temporary, target)
            except IsADirectoryError:               # a folder in the record's place
                self.set_aside(target)
                os.replace(temporary, target)
        except BaseException:
            with contextlib.suppress(OSError):
                temporary.unlink()
            raise
        return json.loads(text)

    def records(self):
        """List of all valid stored records (dicts as in the class docstring), sorted by key."""
        found = (self._read(path) for path in sorted(self.folder.glob("*.json")))
        return [record for record in found if record is not None]

    def __iter__(self):
        """Iterate over :meth:`records`."""
        return iter(self.records())

    def inspect(self, config, validate=None):
        """Stored record of ``config`` and what makes it unusable: ``(record, problem)``.

        Returns ``(record, None)`` for a usable record, ``(None, None)`` when no
        file is stored, and ``(None, problem)`` for a damaged one, ``problem``
        being a phrase that completes "the stored record is ...": ``"a folder,
        not a record file"``, ``"unreadable (Permission denied)"``, ``"corrupt
        (not JSON: ...)"``, ``"incomplete (no 'result')"``, ``"invalid (its
        result is a list, not a dict)"``... validate: None, or a callable
        ``validate(result) -> str | None`` that returns None for a usable result
        dict and otherwise such a phrase, e.g. ``"incomplete (no 'ms_per_step')"``.
        """
        return self._inspect(self.path(config), validate)

    def set_aside(self, path):
        """Rename ``path`` (a folder in a record's place) to a free name that is not a record.

        The new name, ``<key>.json.<8 hex digits>.aside`` in the store's folder,
        is not matched by ``*.json``, so the store ignores it; nothing is deleted.
        Returns the new path; :class:`InputError` naming both if the rename fails.
        """
        path = Path(path)
        aside = self.folder / f"{path.name}.{uuid.uuid4().hex[:8]}.aside"
        try:
            os.rename(path, aside)
        except OSError as exc:
            raise InputError(f"cannot move {str(path)!r}, which is in the place of a stored "
                             f"record, aside to {str(aside)!r}: {exc}") from exc
        return aside

    @staticmethod
    def _inspect(path, validate=None):
        """:meth:`inspect` of the record file at ``path``."""
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            return None, None
        except IsADirectoryError:
            return None, "a folder, not a record file"
        except OSError as exc:
            if path.is_dir():
                return None, "a folder, not a record file"
            return None, f"unreadable ({exc.strerror or exc})"
        try:
            record = json.loads(data.decode("utf-8"))
        except ValueError as exc:                   # a JSONDecodeError or UnicodeDecodeError
            return None, f"corrupt (not JSON: {exc})"
        if not isinstance(record, dict):
            return None, f"not a record (a JSON {type(record).__name__}, not an object)"
        missing = [name for name in ("key", "config", "result") if name not in record]
        if missing:
            return None, f"incomplete (no {', '.join(map(repr, missing))})"
        if record["key"] != path.stem:
            return None, f"the record of another configuration (key {record['key']!r})"
        if not isinstance(record["result"], dict):
            return None, (f"invalid (its result is a {type(record['result']).__name__}, "
                          f"not a dict)")
        problem = None if validate is None else validate(record["result"])
        if problem is None:
            return record, None
        return None, " ".join(str(problem).split())          # one line, whatever validate says

    @classmethod
    def _read(cls, path):
        """Record stored at ``path``, or None when it is absent or damaged (:meth:`inspect`)."""
        return cls._inspect(path)[0]


def run_sweep(fn, configs, store, jobs=1, scheduler=None, progress=True, desc="sweep",
              validate=None):
    """Resumable sweep: ``fn(config)`` for every configuration not yet in ``store``.

    fn: picklable module-level function ``fn(config) -> dict`` (JSON-serialisable).
    configs: list of JSON-serialisable dicts; duplicates (same :func:`config_key`)
    are computed once. store: a :class:`ResultStore` or a folder path.
    jobs: 1 runs serially in this process; any other nonzero int runs on that many
    joblib worker processes (``-1``: all cores, ``-2``: all but one, as in joblib).
    scheduler: a Dask scheduler address (``"tcp://host:8786"``) or a
    ``distributed.Client``; when given, configurations run on that cluster and
    ``jobs`` is ignored (a client built from an address is closed at the end, a
    given client is left open). progress: show a tqdm bar (on stderr) over the
    missing configurations, described by ``desc`` and the number reused.
    validate: None, or ``validate(result) -> str | None``, the check of a stored
    result dict before it is reused (None: usable; otherwise what is wrong, see
    :meth:`ResultStore.inspect`), so that a record a consumer cannot read is
    recomputed. Each damaged record is reported in one line on stderr, whatever
    ``progress``: ``"<desc>: stored record <path> is <problem>; recomputing it"``;
    a folder in a record's place is first moved aside (:meth:`ResultStore.set_aside`).

    Each result is saved into ``store`` by this process as it arrives, with the
    seconds ``fn`` took in its worker, so an interrupted sweep loses only the
    configurations in flight. The first configuration whose ``fn`` raises stops
    the sweep (unstarted ones are cancelled) with a :class:`SweepError` naming it,
    chained to the original error; a result that is not a dict raises
    :class:`InputError`. Returns a :class:`SweepReport`.
    """
    from tqdm import tqdm

    if not callable(fn):
        raise InputError(f"fn must be a callable fn(config) -> dict, got {type(fn).__name__}")
    if not isinstance(configs, (list, tuple)):
        raise InputError(f"configs must be a list of dicts, got {type(configs).__name__}")
    for index, config in enumerate(configs):
        if not isinstance(config, dict):
            raise InputError(f"configs[{index}] must be a dict, got {type(config).__name__}: "
                             f"{config!r}")
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs == 0:
        raise InputError(f"jobs must be a nonzero int (1: serial, -1: all cores), got {jobs!r}")
    if not isinstance(store, ResultStore):
        if not isinstance(store, (str, os.PathLike)):
            raise InputError(f"store must be a ResultStore or a folder path, "
                             f"got {type(store).__name__}")
        store = ResultStore(store)
    if scheduler is not None:
        check_scheduler(scheduler)
    if validate is not None and not callable(validate):
        raise InputError(f"validate must be None or a callable validate(result) -> str | None, "
                         f"got {type(validate).__name__}")

    keys = [config_key(config) for config in configs]
    unique = {}
    for key, config in zip(keys, configs, strict=True):
        unique.setdefault(key, config)
    results, reused, missing, damaged = {}, [], [], {}
    for key, config in unique.items():
        record, problem = store.inspect(config, validate)
        if record is not None:
            results[key] = record["result"]
            reused.append(key)
            continue
        if problem is not None:
            path = store.path(config)
            if path.is_dir() and not path.is_symlink():
                problem += f" (moved aside to {store.set_aside(path).name})"
            damaged[key] = problem
            tqdm.write(f"{desc}: stored record {path} is {problem}; recomputing it",
                       file=sys.stderr)
        missing.append((key, config))

    if missing:
        todo = [config for _, config in missing]
        if scheduler is not None:
            outcomes = _run_dask(fn, todo, scheduler)
        elif jobs != 1:
            outcomes = _run_joblib(fn, todo, jobs)
        else:
            outcomes = (_timed_call(fn, index, config) for index, config in enumerate(todo))
        with contextlib.closing(outcomes), tqdm(total=len(missing), unit="config",
                                                desc=f"{desc} ({len(reused)} reused)",
                                                disable=not progress) as bar:
            for outcome in outcomes:
                key, config = missing[outcome.index]
                if outcome.error is not None:
                    trace = f"\nworker traceback:\n{outcome.trace}" if outcome.trace else ""
                    raise SweepError(f"{desc}: configuration {config!r} failed with "
                                     f"{type(outcome.error).__name__}: {outcome.error}{trace}"
                                     ) from outcome.error
                results[key] = store.save(config, outcome.result, outcome.seconds)["result"]
                bar.update()

    computed = [key for key, _ in missing]
    return SweepReport(results=[results[key] for key in keys], computed=computed, reused=reused,
                       damaged=damaged)


def _timed_call(fn, index, config, remote=False):
    """Run ``fn(config)`` in a worker: an :class:`_Outcome` with its wall seconds or its error.

    remote: the outcome travels back by pickle, so an error that does not survive
    a pickle round trip is replaced by a RuntimeError with its text, and the
    traceback goes along as text.
    """
    start = time.perf_counter()
    try:
        result = fn(config)
    except Exception as error:
        seconds = time.perf_counter() - start
        if not remote:
            return _Outcome(index, None, seconds, error, "")
        try:
            pickle.loads(pickle.dumps(error))
        except Exception:
            error = RuntimeError(f"{type(error).__name__}: {error}")
        return _Outcome(index, None, seconds, error, traceback.format_exc())
    return _Outcome(index, result, time.perf_counter() - start, None, "")


def _run_joblib(fn, configs, jobs):
    """Outcomes of ``configs`` on ``jobs`` joblib workers, yielded as they finish."""
    from joblib import Parallel, delayed

    parallel = Parallel(n_jobs=jobs, return_as="generator_unordered", batch_size=1)
    outputs = parallel(delayed(_timed_call)(fn, index, config, True)
                       for index, config in enumerate(configs))
    try:
        # Not `yield from`: it would close `outputs` outside the warnings filter below.
        for outcome in outputs:  # noqa: UP028
            yield outcome
    finally:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=_JOBLIB_EARLY_EXIT, category=UserWarning)
            outputs.close()


def _import_distributed():
    """The ``distributed`` module, or :class:`InputError` with the install hint."""
    try:
        import distributed
    except ImportError as exc:
        raise InputError(f"a Dask scheduler needs dask.distributed ({exc}): "
                         f"{_CLUSTER_HINT}") from exc
    return distributed


def check_scheduler(scheduler):
    """Validate ``scheduler``: a non-empty address string or a ``distributed.Client``."""
    distributed = _import_distributed()
    if isinstance(scheduler, str):
        if not scheduler.strip():
            raise InputError("scheduler must be a Dask scheduler address such as "
                             "'tcp://127.0.0.1:8786', got an empty string")
    elif not isinstance(scheduler, distributed.Client):
        raise InputError(f"scheduler must be a Dask scheduler address or a distributed.Client, "
                         f"got {type(scheduler).__name__}")


def _run_dask(fn, configs, scheduler):
    """Outcomes of ``configs`` on a Dask cluster, yielded as they finish.

    Unfinished tasks are cancelled when the generator is closed early; a client
    made here from an address is closed at the end.
    """
    distributed = _import_distributed()
    if isinstance(scheduler, str):
        try:
            client = distributed.Client(scheduler, set_as_default=False)
        except OSError as exc:
            raise InputError(f"cannot connect to the Dask scheduler {scheduler!r}: {exc}") from exc
    else:
        client = scheduler
    futures = []
    try:
        futures = [client.submit(_timed_call, fn, index, config, True, pure=False)
                   for index, config in enumerate(configs)]
        index_of = {future.key: index for index, future in enumerate(futures)}
        # as_completed looks up the default client unless given its loop
        for future in distributed.as_completed(futures, loop=client.loop):
            try:
                outcome = future.result()
            except Exception as exc:
                outcome = _Outcome(index_of[future.key], None, 0.0, exc, "")
            yield outcome
    finally:
        client.cancel([future for future in futures if not future.done()])
        if client is not scheduler:
            client.close()
