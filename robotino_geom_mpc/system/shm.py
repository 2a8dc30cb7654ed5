"""Fast DDS shared-memory segments left behind by processes that died without closing them (SIGKILL).

Each Fast DDS participant on the shared-memory transport creates a segment
``/dev/shm/fastrtps_<16 hex digits>`` (about 0.5 MB) and holds an exclusive
``flock`` on its lock file ``..._el`` while it lives. A clean exit removes
both; a killed process leaves them, and they stay in RAM until someone
removes them. This is the segment half of ``fastdds shm clean`` (Fast DDS's
``tools/fastdds/shm/clean.py``), limited to segments created since a given
time: a segment whose lock nobody holds is a zombie. Fast DDS takes the lock
before it creates the segment and retries if a cleaner removed the lock file
in between, so removing under the lock is safe beside live participants.

Ports (``fastrtps_port<N>``, about 50 KB each) are left alone, although the
tool removes those too: their number comes back with the domain and the
participant index (a restarted node reopens its own), Fast DDS resets a
zombie port in place when it is reopened, and a live writer keeps the port
it opened mapped, so unlinking it would cut that writer off from the
restarted node.
"""

from __future__ import annotations

import fcntl
import os
import re
from pathlib import Path

__all__ = ["SHM_DIR", "held_segments", "remove_zombie_segments", "zombie_segments"]

SHM_DIR = Path("/dev/shm")
_SEGMENT_LOCK = re.compile(r"^fastrtps_[0-9a-z]{16}_el$")


def _unlocked(lock_file: Path) -> bool:
    """Whether no process holds the lock file's flock (tried without waiting, released at once)."""
    try:
        fd = os.open(lock_file, os.O_RDONLY)
    except OSError:  # gone meanwhile
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    finally:
        os.close(fd)  # releases the flock if taken
    return True


def zombie_segments(since: float, directory: Path = SHM_DIR) -> list[Path]:
    """Lock files of the zombie segments in `directory` created at or after `since` (seconds since the epoch)."""
    try:
        names = os.listdir(directory)
    except OSError:  # no shared-memory directory (not Linux): nothing to clean
        return []
    zombies = []
    for name in names:
        if not _SEGMENT_LOCK.match(name):
            continue
        lock_file = directory / name
        try:
            created = lock_file.stat().st_mtime  # the lock file is created empty and never written
        except OSError:
            continue
        if created >= since and _unlocked(lock_file):
            zombies.append(lock_file)
    return sorted(zombies)


def remove_zombie_segments(since: float, directory: Path = SHM_DIR) -> int:
    """Remove the zombie segments created since `since` (each segment and its lock file); the bytes freed."""
    freed = 0
    for lock_file in zombie_segments(since, directory):
        segment = lock_file.with_name(lock_file.name[: -len("_el")])
        for path in (segment, lock_file):
            try:
                freed += path.stat().st_size
                path.unlink()
            except OSError:  # removed meanwhile (another cleaner)
                pass
    return freed


def held_segments(pid: int, directory: Path = SHM_DIR) -> set[str]:
    """The Fast DDS segments (``fastrtps_<16 hex>``) whose lock file process `pid` holds: its own."""
    held = set()
    for line in Path("/proc/locks").read_text().splitlines():
        fields = line.split()
        if len(fields) > 5 and fields[1] == "FLOCK" and fields[4] == str(pid):
            held.add(int(fields[5].rsplit(":", 1)[1]))
    segments = set()
    for name in os.listdir(directory):
        if _SEGMENT_LOCK.match(name):
            try:
                if os.stat(directory / name).st_ino in held:
                    segments.add(name[: -len("_el")])
            except OSError:
                continue
    return segments
