"""The test harness reaches the real services it promises (PostgreSQL and Redis)."""

import uuid

import redis
import sqlalchemy as sa


def test_postgres_fixture_gives_a_fresh_writable_database(postgres_url):
    engine = sa.create_engine(postgres_url)
    with engine.begin() as conn:
        conn.execute(sa.text("CREATE TABLE probe (id integer primary key, note text)"))
        conn.execute(sa.text("INSERT INTO probe VALUES (1, 'hello')"))
        note = conn.execute(sa.text("SELECT note FROM probe WHERE id = 1")).scalar_one()
        name = conn.execute(sa.text("SELECT current_database()")).scalar_one()
    engine.dispose()
    assert note == "hello"
    assert name.startswith("demcal_test_")


def test_redis_fixture_gives_an_empty_dedicated_database(redis_url):
    client = redis.Redis.from_url(redis_url)
    key = f"probe:{uuid.uuid4().hex}"
    assert client.dbsize() == 0
    client.set(key, "hello")
    assert client.get(key) == b"hello"
    client.close()
