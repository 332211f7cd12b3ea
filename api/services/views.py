"""Per-study views serialised once: the Pareto front is read by every open dashboard every few
seconds but changes once per generation, so its JSON is kept and served as bytes until the study
row changes.

The version of a view is the study row's ``(updated_at, generation)``: every write that can change
the front (``save_generation``: Pareto flags, objectives and the generation, in one transaction)
also updates the study row, and the row is read anyway to check that the caller may see it. Each
server process keeps its own cache; they agree because the version comes from the database.

What it must not do: decide what a view contains (``api/services/trials.py`` does).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable


class StudyViewCache:
    """Serialised views by (view, study id), each valid for one version; least recently used out."""

    def __init__(self, max_entries: int = 512) -> None:
        self.max_entries = max_entries
        self._entries: OrderedDict[tuple[str, str], tuple[Hashable, bytes]] = OrderedDict()
        self._lock = threading.Lock()

    def get_or_build(self, view: str, study_id: str, version: Hashable, build: Callable[[], bytes]) -> bytes:
        key = (view, study_id)
        with self._lock:
            entry = self._entries.get(key)
            if entry is not None and entry[0] == version:
                self._entries.move_to_end(key)
                return entry[1]
        # Built outside the lock: two requests may build the same view once each, never wrongly.
        body = build()
        with self._lock:
            self._entries[key] = (version, body)
            self._entries.move_to_end(key)
            while len(self._entries) > self.max_entries:
                self._entries.popitem(last=False)
        return body
