"""Disk space for a recording that must end complete: a reserve the writer holds from the start and gives
back when the filesystem runs low, so that everything handed over so far, the summary and the footer still
fit (hardware/recording/writer_process.py). A disk filling mid-run then costs the rest of the run's
recording, not the last flush interval before it.

    r = SpaceReserve(path)        # the Recorder: .NAME.reserve beside path, min(RESERVE_BYTES, free / 4)
    r = SpaceReserve(path, create=False)   # the writer process: that file
    r.low()                       # checked before every pass: free < LOW_SPACE_BYTES -> finish the file
    f = io.BufferedWriter(ReserveBackedFile(fd, r))   # the write that finds the disk full gives the reserve
                                                      # back and goes on (r.full is set): no race with a
                                                      # disk that fills between the check and the write,
                                                      # and the reserve is held as long as it can be
"""

from __future__ import annotations

import errno
import io
import os
import threading
from pathlib import Path

RESERVE_BYTES = 2 << 20  # B held back per recording (a flush interval of samples and frames, the summary)
LOW_SPACE_BYTES = 512 << 10  # B free below which the writer finishes the file and stops


def free_bytes(folder) -> int:
    st = os.statvfs(folder)
    return st.f_bavail * st.f_frsize


class SpaceReserve:
    def __init__(self, path, create: bool = True):
        """create: make the reserve file now (the Recorder, as it opens the file: the reserve exists before
        the writer process starts); False: the one made for this path (the writer, which gives it back)."""
        p = Path(path)
        self.path = p.parent / f".{p.name}.reserve"
        self.size = 0
        if not create:
            self.size = self.path.stat().st_size if self.path.exists() else 0
            return
        try:
            size = min(RESERVE_BYTES, free_bytes(p.parent) // 4)
            fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            try:
                os.posix_fallocate(fd, 0, max(size, 1))
                self.size = size
            finally:
                os.close(fd)
        except OSError:  # no reserve (a filesystem without fallocate, already full): the writer goes on
            self.release()

    def low(self) -> int | None:
        """The free bytes when below LOW_SPACE_BYTES, else None."""
        try:
            free = free_bytes(self.path.parent)
        except OSError:
            return None
        return free if free < LOW_SPACE_BYTES else None

    def release(self) -> None:
        try:
            self.path.unlink()
        except OSError:
            pass
        self.size = 0


class ReserveBackedFile(io.RawIOBase):
    """The recording's file descriptor for the writer: a write that fails with ENOSPC while the reserve is
    held gives the reserve back, sets `full` and is tried again (a disk can fill between the writer's
    look at the free space and its next write: another process filled it). Without a reserve left, ENOSPC
    is raised as before."""

    def __init__(self, fd: int, reserve: SpaceReserve):
        super().__init__()
        self._fd, self._reserve = fd, reserve
        self.full = threading.Event()

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def fileno(self) -> int:
        return self._fd

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        return os.lseek(self._fd, offset, whence)

    def tell(self) -> int:
        return os.lseek(self._fd, 0, os.SEEK_CUR)

    def write(self, b) -> int:
        try:
            return os.write(self._fd, b)
        except OSError as e:
            if e.errno != errno.ENOSPC or not self._reserve.size:
                raise
            self._reserve.release()
            self.full.set()
            return os.write(self._fd, b)

    def close(self) -> None:
        if not self.closed:
            try:
                os.close(self._fd)
            finally:
                super().close()
