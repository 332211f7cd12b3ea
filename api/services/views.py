"""Per-study views serialised once: the Pareto front is read by every open dashboard every few
seconds but changes once per generation, so its JSON is kept and served as bytes until the study
row changes.

The version of a view is the study row's ``(updated_at, generation)``: every write that can change
the front (``save_generation``: Pareto flags, objectives and the generation, in one transaction)
also updates the study row, and the row is read anyway to check that the caller may see it. Each
server process keeps its own cache; they agree because the version comes from the database.

A view is built once per version, whatever the number of requests asking for it meanwhile
(single flight): 50 dashboards polling a study whose identifiability takes seconds to compute
would otherwise compute it 50 times at once and starve every other request. A view that may lag
one version (``stale_ok``: progress and identifiability, which change once per batch) is served
from its previous version while the new one is built in the background, so a poll never waits
for a build it could do without.

What it must not do: decide what a view contains (``api/services/trials.py`` does).
"""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from concurrent.futures import Future

log = logging.getLogger(__name__)


class StudyViewCache:
    """Serialised views by (view, study id), each valid for one version; least recently used out."""

    def __init__(self, max_entries: int = 512) -> None:
        self.max_entries = max_entries
        self._entries: OrderedDict[tuple[str, str], tuple[Hashable, bytes]] = OrderedDict()
        self._building: dict[tuple[str, str, Hashable], Future] = {}
        self._lock = threading.Lock()

    def get_or_build(
        self, view: str, study_id: str, version: Hashable, build: Callable[[], bytes], stale_ok: bool = False
    ) -> bytes:
        key = (view, study_id)
        with self._lock:
            entry = self._entries.get(key)
            if entry is not None and entry[0] == version:
                self._entries.move_to_end(key)
                return entry[1]
            pending = self._building.get((*key, version))
            mine = pending is None
            if mine:
                pending = self._building[(*key, version)] = Future()
        stale = entry[1] if stale_ok and entry is not None else None
        if stale is not None:
            if mine:
                threading.Thread(
                    target=self._build, args=(key, version, build, pending, True), name=f"view-{view}",
                    daemon=True,
                ).start()
            return stale
        if mine:
            self._build(key, version, build, pending)
        return pending.result()

    def _build(
        self, key: tuple[str, str], version: Hashable, build: Callable[[], bytes], done: Future,
        background: bool = False,
    ) -> None:
        """Build outside the lock; store it; hand it (or the error) to every request waiting for it."""
        try:
            body = build()
        except BaseException as exc:
            if background:  # no request receives the error: the stale view stays, the next poll retries
                log.exception("building view %s of study %s failed", *key)
            done.set_exception(exc)
            with self._lock:
                self._building.pop((*key, version), None)
            return
        with self._lock:
            self._entries[key] = (version, body)
            self._entries.move_to_end(key)
            while len(self._entries) > self.max_entries:
                self._entries.popitem(last=False)
            self._building.pop((*key, version), None)
        done.set_result(body)
