"""API keys: create, verify, list and revoke the bearer tokens that guard the REST API.

A token is ``dcl_`` + 32 random bytes (url-safe base64) from ``secrets``; only its sha256 is
stored, so a leaked database does not leak usable keys. Lookup is by the hash (an index), and
the found hash is compared again with ``hmac.compare_digest`` so the check takes the same time
whatever the input. A key belongs to an owner; an admin key sees every owner's objects.

Every request carries a key, so a verified key is remembered for a moment (``KeyCache``,
``DEMCAL_API_KEY_CACHE_S``, default 1 s): a revoked key keeps working in a running server for at
most that long. Only valid keys are cached, by their hash; an unknown token always goes to the
database.

What it must not do: know about routes or HTTP (``api/deps.py`` turns headers into a Principal).
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import threading
import time
from dataclasses import dataclass

import sqlalchemy as sa
from sqlalchemy.orm import Session

from api.errors import AuthenticationError, InvalidInputError, NotFoundError
from api.models import ApiKeyRow, utcnow

TOKEN_PREFIX = "dcl_"
OWNER_MAX_LENGTH = 100


@dataclass(frozen=True)
class Principal:
    """Who is calling: the owner of the key and whether it is an admin key."""

    key_id: int
    owner: str
    admin: bool

    @property
    def visible_to(self) -> str | None:
        """The owner filter for queries: None (no filter) for an admin."""
        return None if self.admin else self.owner


def hash_token(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def create_key(session: Session, owner: str, name: str = "", admin: bool = False) -> tuple[ApiKeyRow, str]:
    """A new key for ``owner``; returns the row and the token, which is shown only this once."""
    owner = owner.strip()
    if not owner or len(owner) > OWNER_MAX_LENGTH:
        raise InvalidInputError(f"owner must be 1 to {OWNER_MAX_LENGTH} characters, e.g. 'alice'")
    token = TOKEN_PREFIX + secrets.token_urlsafe(32)
    row = ApiKeyRow(
        name=name, owner=owner, prefix=token[: len(TOKEN_PREFIX) + 6], token_sha256=hash_token(token),
        admin=admin,
    )
    session.add(row)
    session.flush()
    return row, token


def authenticate(session: Session, token: str | None) -> Principal:
    """The principal of a valid, unrevoked token; AuthenticationError otherwise."""
    if not token:
        raise AuthenticationError(
            "missing API key: send 'Authorization: Bearer <key>' (create one with `demcal apikey create`)"
        )
    digest = hash_token(token)
    row = session.scalars(sa.select(ApiKeyRow).where(ApiKeyRow.token_sha256 == digest)).one_or_none()
    if row is None or not hmac.compare_digest(row.token_sha256, digest):
        raise AuthenticationError(
            "unknown API key: check the token, or create one with `demcal apikey create`"
        )
    if row.revoked_at is not None:
        raise AuthenticationError("this API key was revoked: ask for a new one (`demcal apikey create`)")
    return Principal(key_id=row.id, owner=row.owner, admin=row.admin)


def list_keys(session: Session, owner: str | None = None) -> list[ApiKeyRow]:
    query = sa.select(ApiKeyRow).order_by(ApiKeyRow.id)
    if owner is not None:
        query = query.where(ApiKeyRow.owner == owner)
    return list(session.scalars(query))


def revoke_key(session: Session, key_id: int) -> ApiKeyRow:
    """Revoke a key by id (shown by ``demcal apikey list``); revoking twice is harmless."""
    row = session.get(ApiKeyRow, key_id)
    if row is None:
        raise NotFoundError(f"no API key with id {key_id}; `demcal apikey list` shows them")
    if row.revoked_at is None:
        row.revoked_at = utcnow()
    return row


class KeyCache:
    """Principals of recently verified tokens, each kept ``ttl_s`` seconds (0: no caching).

    Why: checking the key was a database round trip on every request, as much as the request's
    own work for small reads. The bound on entries keeps memory flat whatever clients send.
    """

    def __init__(self, ttl_s: float, max_entries: int = 10_000) -> None:
        self.ttl_s = ttl_s
        self.max_entries = max_entries
        self._entries: dict[str, tuple[float, Principal]] = {}
        self._lock = threading.Lock()

    def get(self, token: str) -> Principal | None:
        if self.ttl_s <= 0:
            return None
        entry = self._entries.get(hash_token(token))
        if entry is None or entry[0] < time.monotonic():
            return None
        return entry[1]

    def put(self, token: str, principal: Principal) -> None:
        if self.ttl_s <= 0:
            return
        with self._lock:
            if len(self._entries) >= self.max_entries:
                now = time.monotonic()
                self._entries = {k: v for k, v in self._entries.items() if v[0] >= now}
                if len(self._entries) >= self.max_entries:
                    self._entries.clear()
            self._entries[hash_token(token)] = (time.monotonic() + self.ttl_s, principal)
