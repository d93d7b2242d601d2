"""A run's clip: rendered on demand, cached beside the store (never in it), refused cleanly without OpenGL."""

import re
import subprocess
import sys
import time
import urllib.error
import urllib.request

import pytest

from .conftest import snapshot


@pytest.mark.slow
def test_a_clip_is_rendered_once_and_cached_in_the_dashboards_own_cache(server, store_path, tmp_path):
    before = snapshot(store_path)
    t0 = time.perf_counter()
    with urllib.request.urlopen(f"{server.url}/clips/run1.mp4", timeout=300) as r:
        assert r.headers["content-type"] == "video/mp4"
        first = r.read()
    rendered_s = time.perf_counter() - t0
    assert first[4:8] == b"ftyp" and len(first) > 10_000
    (cached,) = (tmp_path / "clips").iterdir()  # the server fixture's cache_dir, never beside the store
    assert cached.name.startswith("run1-") and cached.read_bytes() == first
    assert (tmp_path / "clips").stat().st_mode & 0o777 == 0o700 and cached.stat().st_nlink == 1
    t0 = time.perf_counter()
    with urllib.request.urlopen(f"{server.url}/clips/run1.mp4", timeout=60) as r:
        assert r.read() == first
    assert time.perf_counter() - t0 < min(1.0, rendered_s)  # from the cache
    assert snapshot(store_path) == before


@pytest.mark.slow
def test_no_opengl_backend_is_a_clear_refusal(store_path):
    proc = subprocess.Popen([sys.executable, "-m", "cmrt.cli", "dashboard", "--store", str(store_path), "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**__import__("os").environ, "MUJOCO_GL": "nonesuch", "CMRT_MUJOCO_GL": "nonesuch",
                                 "XDG_CACHE_HOME": str(store_path.parent / "cache")})
    try:
        url = re.search(r"http://[\d.]+:\d+", proc.stdout.readline()).group(0)
        with pytest.raises(urllib.error.HTTPError) as caught:
            urllib.request.urlopen(f"{url}/clips/run1.mp4", timeout=120)
        assert caught.value.code == 503
        body = caught.value.read().decode()
        assert "cannot render" in body and "nonesuch" in body and "Traceback" not in body
    finally:
        proc.terminate()
        proc.communicate(timeout=30)
    clips = store_path.parent / "cache" / "cmrt" / "dashboard-clips"
    assert not clips.exists() or not any(clips.iterdir())  # no half-made clip left
    assert sorted(p.name for p in store_path.parent.iterdir()) == ["cache", "cmrt.sqlite"]
