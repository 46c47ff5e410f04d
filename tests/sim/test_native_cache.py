"""The compiled input limit's cache: nothing loaded from a place others can write.

Each case plants or damages files under a temporary ``XDG_CACHE_HOME`` and checks that what
gets loaded is the library this user built (its constructor-free bytes), that a planted
library's constructor never runs, and that the hardware profile's numbers do not depend on
what the cache held.
"""

from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from testbed.sim import native

pytestmark = pytest.mark.skipif(
    (os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")) is None,
    reason="no C compiler: the Python hook is the only input limit")

_PLANT = r"""
#include <stdio.h>
__attribute__((constructor)) static void planted(void) {
  FILE* f = fopen("MARKER", "w");
  if (f) { fputs("ran", f); fclose(f); }
}
void testbed_act_window(void* m, void* d) {}
"""


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setattr(native, "_warned", False)
    return tmp_path / "xdg" / "testbed"


def _name() -> str:
    import hashlib

    import mujoco

    key = hashlib.sha256(
        f"{native._SOURCE}{mujoco.__version__}{sys.platform}".encode()).hexdigest()
    return f"{native._PREFIX}{key[:16]}"


def _plant(directory: Path, marker: Path, *, digest: bool = True) -> Path:
    """A library with a constructor that writes ``marker``, under the cache's name, with a
    matching digest file beside it (so only ownership and mode can refuse it)."""
    directory.mkdir(parents=True, exist_ok=True)
    src = directory.parent / "plant.c"
    src.write_text(_PLANT.replace("MARKER", str(marker)))
    lib = directory / f"{_name()}.so"
    subprocess.run([shutil.which("cc") or "gcc", "-shared", "-fPIC", str(src), "-o", str(lib)],
                   check=True)
    if digest:
        (directory / f"{_name()}.sha256").write_text(native._digest(lib.read_bytes()))
    return lib


def _own_build_loads(cache: Path) -> None:
    """``_load`` gives a library with the callback, built by this user, mode 0700/0600."""
    lib = native._load()
    assert lib is not None and hasattr(lib, "testbed_act_window")
    assert stat.S_IMODE(os.lstat(cache).st_mode) == 0o700
    built = cache / f"{_name()}.so"
    assert stat.S_IMODE(os.lstat(built).st_mode) == 0o700
    assert stat.S_IMODE(os.lstat(cache / f"{_name()}.sha256").st_mode) == 0o600
    assert os.lstat(built).st_uid == os.getuid()
    assert native._digest(built.read_bytes()) == (
        cache / f"{_name()}.sha256").read_text().strip()


def test_umask_000_gives_a_0700_directory_and_private_files(cache):
    old = os.umask(0)
    try:
        _own_build_loads(cache)
    finally:
        os.umask(old)


@pytest.mark.parametrize("damage", ["truncated", "empty", "foreign", "digest", "symlink"])
def test_a_damaged_or_foreign_library_is_rebuilt(cache, tmp_path, damage, capsys):
    _own_build_loads(cache)
    lib = cache / f"{_name()}.so"
    marker = tmp_path / "ran"
    if damage == "truncated":
        lib.write_bytes(lib.read_bytes()[:100])
    elif damage == "empty":
        lib.write_bytes(b"")
    elif damage == "foreign":  # another library under the name; the old digest stays
        _plant(cache, marker, digest=False)
    elif damage == "digest":
        (cache / f"{_name()}.sha256").write_text("0" * 64)
    else:  # the name points elsewhere, to a planted library with a matching digest
        elsewhere = _plant(tmp_path / "elsewhere", marker)
        digest = native._digest(elsewhere.read_bytes())
        lib.unlink()
        lib.symlink_to(elsewhere)
        (cache / f"{_name()}.sha256").write_text(digest)
    _own_build_loads(cache)
    assert not marker.exists()
    assert not lib.is_symlink()
    assert capsys.readouterr().err == ""  # a rebuild is silent


def test_a_planted_world_writable_library_is_never_loaded(cache, tmp_path):
    marker = tmp_path / "ran"
    cache.mkdir(parents=True)
    lib = _plant(cache, marker)
    os.chmod(lib, 0o777)
    os.chmod(cache, 0o777)
    _own_build_loads(cache)
    assert not marker.exists()


@pytest.mark.skipif(os.getuid() != 0, reason="planting a file of another user needs root")
def test_a_library_or_directory_of_another_user_is_never_loaded(cache, tmp_path, capsys):
    marker = tmp_path / "ran"
    lib = _plant(cache, marker)
    os.chmod(cache, 0o700)
    os.chown(lib, 65534, 65534)  # nobody's, with a matching digest beside it
    _own_build_loads(cache)
    assert not marker.exists()
    os.chown(cache, 65534, 65534)  # now the directory itself is someone else's
    assert native._load() is None
    assert "not a private directory" in capsys.readouterr().err
    assert not marker.exists()


def _run_hardware(tmp_path: Path, env: dict[str, str], name: str) -> dict:
    out = tmp_path / f"{name}.json"
    subprocess.run([sys.executable, "-m", "testbed", "run", "helicopter", "--profile",
                    "hardware", "--duration", "1", "--seed", "0", "--json", str(out)],
                   check=True, env=env, capture_output=True, cwd=tmp_path)
    result = json.loads(out.read_text())
    result.pop("wall_s", None)
    return result


def test_the_hardware_profile_gives_the_same_numbers_whatever_the_cache_held(tmp_path):
    """The issue's acceptance: a planted world-writable library with a constructor, then a
    truncated one, then the Python hook: the same JSON, and the constructor never ran."""
    xdg = tmp_path / "xdg"
    env = {**os.environ, "XDG_CACHE_HOME": str(xdg)}
    env.pop("TESTBED_NO_NATIVE", None)
    marker = tmp_path / "ran"
    cache = xdg / "testbed"
    lib = _plant(cache, marker)
    os.chmod(lib, 0o777)
    planted = _run_hardware(tmp_path, env, "planted")
    assert not marker.exists()
    built = cache / f"{_name()}.so"
    built.write_bytes(built.read_bytes()[:200])
    truncated = _run_hardware(tmp_path, env, "truncated")
    python_hook = _run_hardware(tmp_path, {**env, "TESTBED_NO_NATIVE": "1"}, "python")
    assert planted == truncated == python_hook
    assert not marker.exists()
