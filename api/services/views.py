"""Per-study views serialised once: the Pareto front is read by every open dashboard every few
seconds but changes once per generation, so its JSON is kept and served as bytes until the study
row changes.

The version of a view is one of the study's change numbers: every write that can change the
front (``save_generation``: Pareto flags, objectives and the generation, in one transaction) also
changes the study row, and the row is read anyway to check that the caller may see it. Each
server process keeps its own cache; they agree because the version comes from the database.

A view is built once per version, whatever the number of requests asking for it meanwhile
(single flight): 50 dashboards polling a study whose identifiability takes seconds to compute
would otherwise compute it 50 times at once and starve every other request. A view that may lag
(``stale_ok``: progress and identifiability, which change once per batch) is served from its
previous version while the new one is built in the background, so a poll never waits for a build
it could do without; and only one such build per view and study runs at a time: versions that
come faster than a build ends would otherwise each start one, and the builds would pile up until
they took every core (the next poll after a build ends starts the one for the latest version).

A view may also keep an object between its builds (``kept``): progress folds only the batches
completed since its previous build, the study read counts only the trials written since. They are
kept per study, for the ``max_kept_studies`` studies polled last (``DEMCAL_VIEW_KEPT_STUDIES``):
a study past it is read whole again at its next build (2 s of CPU for progress of a study of
10,000 trials, against 1.3 ms kept), and with one limit of 32 (view, study) pairs, 16 studies
polled in turn missed at every build (benchmarks/README.md, API session 8, part 2).

A background build may also be made to rest (``rest``): after a build that took t seconds, the
next one of that view and study starts no sooner than ``rest * t`` after it ended, so the view
never takes more than 1 / (1 + rest) of a core however fast the versions come. Identifiability
(seconds of CPU for a long study) rests 9 times its build: built after every batch of 20 quick
trials it took two thirds of a core of a 2-core machine that also served 50 dashboards
(``benchmarks/README.md``, session 5). ``serve`` says whether what it answers is the current
version or a stale one, so that a client knows to ask again (``X-Demcal-View``), and, for a view
that rests, when a newer version can be ready at the earliest (``Retry-After``: the rest left plus
one build's duration; while it builds, what is left of a build as long as its previous one): a page
asking every poll for a view that rests was a third of the requests of 50 polling dashboards
(session 6), and asking every poll while identifiability built was 84-915 requests a benchmark run
(session 8).

A view's ETag is its version, a number the database hands out (the study's change numbers,
``api/models.py``), and a digest of its bytes (``etag``). A client that holds the current version
(``If-None-Match``) is answered before the cache is even looked at (``serve(..., held=)``), by any
server process. One that holds an older version whose bytes are those of the current one (the
study row changed, the view did not: a recommendation, ~100 kB, after a batch was queued) is
answered from the digest, and its 304 carries the new ETag, which the client keeps: with the version
alone, such views were sent again after every change of the study (benchmarks/README.md,
sessions 7 and 8).

Where a view is built: the polled views that cost milliseconds of CPU a version (the
recommendation, progress, the Pareto front) are built by ``builder``, in a view-building process
(``offload.ViewProcesses``, ``DEMCAL_VIEW_PROCESSES``, the default of ``demcal serve``) that reads
the database itself, while the request's thread waits without the GIL; built on the server's
threads, their bursts after each batch held the GIL while every page asked for them, and the event
loop stalled 222-245 ms (benchmarks/README.md, API session 8, part 2). Versions, ETags, single
flight, stale answers and rests are this cache's, wherever the bytes were built; a view's ``kept``
objects live where it is built (a process keeps its own).

What it must not do: decide what a view contains (``api/services/trials.py`` does).
"""

from __future__ import annotations

import hashlib
import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import TypeVar

T = TypeVar("T")

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Served:
    """A view's bytes, and whether they are of the version asked for (False: an older one, served
    while the asked version builds or its build rests); for a stale one of a view that rests, the
    seconds before a newer version can be ready. ``not_modified``: the client holds these bytes
    (``held``), the answer is a 304 with no body."""

    body: bytes
    current: bool
    retry_after_s: float | None = None
    etag: str = ""
    not_modified: bool = False


def etag(version: Hashable, digest: str) -> str:
    """The ETag of a view's ``version`` (a number, or a tuple of them) whose bytes have ``digest``.
    Weak: two server processes may build one version at moments a little apart, and their bytes
    need not be equal; both are of that version, which is what a conditional GET asks."""
    parts = version if isinstance(version, tuple) else (version,)
    return 'W/"' + "-".join(str(part) for part in parts) + "." + digest + '"'


DIGEST_CHARS = 16  # hex


def _digest(body: bytes) -> str:
    return hashlib.blake2b(body, digest_size=DIGEST_CHARS // 2).hexdigest()


def _held_at(held: str, version: Hashable) -> str | None:
    """The ETag in ``held`` (an ``If-None-Match``) that names ``version``, if any (it is sent back:
    only a well-formed one)."""
    prefix = etag(version, "")[:-1]  # W/"<version>.
    start = held.find(prefix)
    if start < 0:
        return None
    tag = held[start:start + len(prefix) + DIGEST_CHARS + 1]
    digest = tag[len(prefix):-1]
    if tag.endswith('"') and len(digest) == DIGEST_CHARS and all(c in "0123456789abcdef" for c in digest):
        return tag
    return None


class StudyViewCache:
    """Serialised views by (view, study id), each valid for one version; least recently used out."""

    def __init__(self, max_entries: int = 512, max_kept_studies: int = 64, processes=None) -> None:
        self.max_entries = max_entries
        self.processes = processes  # offload.ViewProcesses, or None: views are built on this thread
        self.max_kept_studies = max_kept_studies  # progress keeps a study's records: large
        # (view, study id) -> (version, bytes, their digest)
        self._entries: OrderedDict[tuple[str, str], tuple[Hashable, bytes, str]] = OrderedDict()
        self._building: dict[tuple[str, str, Hashable], Future] = {}
        self._refreshing: set[tuple[str, str]] = set()  # (view, study id) built in the background
        self._kept: OrderedDict[str, dict[str, object]] = OrderedDict()  # study id -> view -> object
        self._resting: dict[tuple[str, str], float] = {}  # (view, study id) -> monotonic time it may build
        self._took: dict[tuple[str, str], float] = {}  # (view, study id) -> its last build's seconds
        self._started: dict[tuple[str, str], float] = {}  # (view, study id) -> monotonic start of its refresh
        self._lock = threading.Lock()

    def builder(
        self, view: str, fn: Callable[..., bytes], store, study_id: str, *args
    ) -> Callable[[], bytes]:
        """A build of ``view``: ``fn(store, views, study_id, *args)`` (``views`` for ``kept``), in a
        view-building process (``processes``, on a store of the same database, with its own
        ``kept`` objects) if there is one and it can open the database, else on the calling
        thread with this cache. ``fn`` and ``args`` must pickle; the bytes are the same."""
        from api.services.offload import shared_database

        url = store.engine.url
        if self.processes is None or not shared_database(url):
            return lambda: fn(store, self, study_id, *args)
        rendered = url.render_as_string(hide_password=False)
        return lambda: self.processes.build(view, fn, rendered, study_id, *args)

    def close(self) -> None:
        """End the view-building processes, if any (with the app)."""
        if self.processes is not None:
            self.processes.close()

    def get_or_build(
        self, view: str, study_id: str, version: Hashable, build: Callable[[], bytes], stale_ok: bool = False
    ) -> bytes:
        return self.serve(view, study_id, version, build, stale_ok).body

    def serve(
        self, view: str, study_id: str, version: Hashable, build: Callable[[], bytes], stale_ok: bool = False,
        rest: float = 0.0, held: str | None = None,
    ) -> Served:
        """The view at ``version``: cached, or built now (requests for one version wait for one
        build); with ``stale_ok`` and an older version cached, that one, while the asked version
        builds in the background, ``rest`` times the previous build's duration after it ended.
        ``held``, a client's ``If-None-Match``: if it names ``version``, no view at all (the client
        has it, the answer is a 304 with the ETag it sent); if it names the digest of the bytes
        served, a 304 with their ETag."""
        if held is not None:
            tag = _held_at(held, version)
            if tag is not None:
                return Served(b"", True, etag=tag, not_modified=True)
        key = (view, study_id)
        with self._lock:
            entry = self._entries.get(key)
            if entry is not None and entry[0] == version:
                self._entries.move_to_end(key)
                return self._served(entry, True, None, held)
            if stale_ok and entry is not None:
                now = time.monotonic()
                resting_s = self._resting.get(key, 0.0) - now
                refresh = key not in self._refreshing and resting_s <= 0
                if refresh:
                    self._refreshing.add(key)
                    self._started[key] = now
                retry_after_s = self._retry_after(key, now, resting_s) if rest > 0 else None
            else:
                pending = self._building.get((*key, version))
                mine = pending is None
                if mine:
                    pending = self._building[(*key, version)] = Future()
        if stale_ok and entry is not None:
            if refresh:
                threading.Thread(
                    target=self._refresh, args=(key, version, build, rest), name=f"view-{view}", daemon=True
                ).start()
            return self._served(entry, False, retry_after_s, held)
        if mine:
            self._build(key, version, build, pending)
        return self._served(pending.result(), True, None, held)

    @staticmethod
    def _served(
        entry: tuple[Hashable, bytes, str], current: bool, retry_after_s: float | None, held: str | None
    ) -> Served:
        version, body, digest = entry
        same = held is not None and "." + digest + '"' in held
        return Served(b"" if same else body, current, retry_after_s, etag(version, digest), same)

    def _retry_after(self, key: tuple[str, str], now: float, resting_s: float) -> float | None:
        """Seconds before a newer version of a resting view can be ready: the rest left and one
        build; while one builds, what is left of it if it takes as long as the previous one
        (called under the lock)."""
        took = self._took.get(key)
        if took is None:
            return None
        if resting_s > 0:
            return resting_s + took
        return max(0.0, took - (now - self._started[key]))

    def kept(self, view: str, study_id: str, make: Callable[[], T]) -> T:
        """The object ``view`` keeps for ``study_id`` between builds (made on first use); past
        ``max_kept_studies`` the least recently used study's objects are forgotten (its next
        builds start afresh). Builds of one view and study may overlap (two versions asked for
        before either is cached): the object must lock itself."""
        with self._lock:
            objects = self._kept.get(study_id)
            if objects is None:
                objects = self._kept[study_id] = {}
                while len(self._kept) > self.max_kept_studies:
                    self._kept.popitem(last=False)
            self._kept.move_to_end(study_id)
            if view not in objects:
                objects[view] = make()
            return objects[view]

    def _build(
        self, key: tuple[str, str], version: Hashable, build: Callable[[], bytes], done: Future
    ) -> None:
        """Build outside the lock; store it; hand it (or the error) to every request waiting for it."""
        started = time.monotonic()
        try:
            body = build()
        except BaseException as exc:
            done.set_exception(exc)
            with self._lock:
                self._building.pop((*key, version), None)
            return
        entry = (version, body, _digest(body))
        took = time.monotonic() - started
        with self._lock:
            self._store(key, entry)
            self._took[key] = took
            self._building.pop((*key, version), None)
        done.set_result(entry)

    def _refresh(
        self, key: tuple[str, str], version: Hashable, build: Callable[[], bytes], rest: float
    ) -> None:
        """Build in the background; no request waits: an error is logged, the stale view stays and
        the next poll tries again (after the rest)."""
        started = time.monotonic()
        try:
            body = build()
        except Exception:
            log.exception("building view %s of study %s failed", *key)
            body = None
        entry = None if body is None else (version, body, _digest(body))
        ended = time.monotonic()
        with self._lock:
            if entry is not None:
                self._store(key, entry)
            if rest > 0:
                self._resting[key] = ended + rest * (ended - started)
            self._took[key] = ended - started
            self._refreshing.discard(key)
            self._started.pop(key, None)

    def _store(self, key: tuple[str, str], entry: tuple[Hashable, bytes, str]) -> None:
        self._entries[key] = entry
        self._entries.move_to_end(key)
        while len(self._entries) > self.max_entries:
            evicted, _ = self._entries.popitem(last=False)
            self._resting.pop(evicted, None)
            self._took.pop(evicted, None)
