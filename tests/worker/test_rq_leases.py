"""Study leases in Redis (``api.service.RedisLeases``): one ``demcal serve`` replica drives a
study at a time, a dead replica's studies are taken over after the lease expires, and a holder
takes its leases back after Redis was flushed."""

from __future__ import annotations

import time

import pytest
import redis

from api.service import RedisLeases

pytestmark = pytest.mark.redis


@pytest.fixture
def connection(redis_url):
    client = redis.Redis.from_url(redis_url)
    yield client
    client.close()


def test_only_one_replica_holds_a_study(connection):
    first, second = RedisLeases(connection, "serve-a"), RedisLeases(connection, "serve-b")

    taken = [first.acquire("st-1"), second.acquire("st-1")]

    assert taken == [True, False]
    assert second.holder("st-1") == "serve-a"


def test_a_replica_cannot_renew_or_release_a_lease_it_does_not_hold(connection):
    holder, other = RedisLeases(connection, "serve-a"), RedisLeases(connection, "serve-b")
    holder.acquire("st-1")

    renewed = other.renew("st-1")
    other.release("st-1")

    assert renewed is False
    assert holder.holder("st-1") == "serve-a"


def test_the_lease_of_a_dead_replica_expires_and_another_takes_the_study(connection):
    dead, alive = RedisLeases(connection, "serve-a", ttl_s=0.3), RedisLeases(connection, "serve-b")
    dead.acquire("st-1")

    time.sleep(0.5)
    taken = alive.acquire("st-1")

    assert taken is True
    assert dead.renew("st-1") is False


def test_the_holder_takes_its_lease_back_after_a_flush(connection):
    holder, other = RedisLeases(connection, "serve-a"), RedisLeases(connection, "serve-b")
    holder.acquire("st-1")

    connection.flushdb()  # stands for FLUSHALL
    renewed = holder.renew("st-1")

    assert renewed is True
    assert other.acquire("st-1") is False


def test_a_released_study_is_free_for_the_next_replica(connection):
    first, second = RedisLeases(connection, "serve-a"), RedisLeases(connection, "serve-b")
    first.acquire("st-1")

    first.release("st-1")

    assert second.acquire("st-1") is True
