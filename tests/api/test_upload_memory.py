"""Uploads side by side do not multiply the server's memory: meshes are parsed and clumped one at
a time on one thread (``api.services.shapes.MESH_WORK``). Measured in a fresh process with the real
app and 82k-face meshes, as the largest resident size during the uploads above the size before
them (sampled; the high-water mark would include a cold numba cache's compile): six uploads at once
raise it by less than three times what one raised it. Measured: 2.05-2.8 times one upload's
(one upload 197-253 MB) with MESH_WORK on one thread; 3.5-3.9 times with six threads."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import trimesh

SCRIPT = textwrap.dedent(
    """
    import os, sys, tempfile, threading, time
    from pathlib import Path
    from fastapi.testclient import TestClient
    from api.app import create_app
    from api.auth import create_key
    from api.db import create_db_engine, upgrade_database
    from api.settings import load_settings
    from api.store import SqlStore

    PAGE_MB = os.sysconf("SC_PAGE_SIZE") / 2**20

    def rss_mb():
        with open("/proc/self/statm") as statm:
            return int(statm.read().split()[1]) * PAGE_MB

    def peak_above_start(work):
        # The largest resident size while work runs, above the size before it, sampled every
        # 2 ms: the process's own high-water mark would include whatever came before it (a cold
        # numba cache compiling the clumping kernels set it above one upload's need).
        start, peak, done = rss_mb(), [0.0], threading.Event()

        def sample():
            while not done.is_set():
                peak[0] = max(peak[0], rss_mb())
                time.sleep(0.002)

        sampler = threading.Thread(target=sample)
        sampler.start()
        try:
            work()
        finally:
            done.set()
            sampler.join()
        return max(peak[0], rss_mb()) - start

    folder = tempfile.mkdtemp()
    url = f"sqlite:///{folder}/m.db"
    upgrade_database(url)
    engine = create_db_engine(url)
    store = SqlStore(engine)
    with store.session() as session:
        _, token = create_key(session, "u")
    settings = load_settings(database_url=url, data_dir=f"{folder}/data", max_upload_bytes=100_000_000)
    client = TestClient(create_app(settings, engine=engine))

    def upload(data, k):
        response = client.post(
            "/api/v1/shapes", files={"file": (f"m{k}.stl", data)}, data={"mass": "0.1"},
            headers={"Authorization": f"Bearer {token}"},
        )
        assert response.status_code == 201, response.text

    meshes = [path.read_bytes() for path in sorted(Path(sys.argv[1]).glob("m*.stl"))]
    upload(Path(sys.argv[1], "warm.stl").read_bytes(), 0)  # imports and compiles first
    def six_at_once():
        threads = [threading.Thread(target=upload, args=(meshes[k], k + 1)) for k in range(1, 7)]
        [thread.start() for thread in threads]
        [thread.join() for thread in threads]

    one = peak_above_start(lambda: upload(meshes[0], 1))
    print(one, peak_above_start(six_at_once))
    """
)


def _write_meshes(folder: Path) -> None:
    """The meshes are made here, not in the measured process: building seven 82k-face spheres
    there could set its peak before the first upload and hide what an upload costs."""
    trimesh.creation.icosphere(subdivisions=2, radius=0.03).export(folder / "warm.stl")
    for k in range(1, 8):
        trimesh.creation.icosphere(subdivisions=6, radius=0.03 + 0.001 * k).export(folder / f"m{k}.stl")


def test_six_uploads_at_once_raise_the_peak_memory_less_than_three_times_one(tmp_path):
    _write_meshes(tmp_path)
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(tmp_path)], capture_output=True, text=True, timeout=600
    )

    assert proc.returncode == 0, proc.stderr
    one, six = (float(v) for v in proc.stdout.split())
    assert one > 100  # a large mesh: parsing and clumping it takes hundreds of MB
    assert six < 3 * one, f"one upload raised the peak by {one:.0f} MB, six at once by {six:.0f} MB"
