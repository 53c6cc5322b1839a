"""Output folders committed as a whole: stage beside the target, then swap it in.

Every command that writes a folder of results (a dataset, a fit, an evaluation) goes through
`StagedDir`, so that at any moment, a `kill -9` included, the target holds either the previous
complete result or the new complete one, never a mix:

    with StagedDir(out, kind="evaluation") as st:
        write files under st.path ...
        st.commit()

- Files are written into a hidden sibling `.NAME.partial-PID-XXXX`; `commit()` swaps it with the
  target in one atomic rename (Linux renameat2 RENAME_EXCHANGE; two renames elsewhere).
- The folder records the top-level entries it wrote (`.platolidar-output.json`). On the next commit
  only those are replaced; anything else in the target (a user's notes.txt, another tool's folder)
  is carried into the new folder by hard link, so nothing the program did not write is lost.
- A non-empty target that is neither empty nor an earlier output of the same kind is refused.
- Leaving the block without `commit()` removes the staging folder; staging folders of processes
  that died (kill -9) are removed when the next run starts.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import fnmatch
import json
import os
import shutil
import uuid
from contextlib import contextmanager
from pathlib import Path

from ..errors import PlatolidarError

RECORD_NAME = ".platolidar-output.json"
_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


class OutputExistsError(PlatolidarError, FileExistsError):
    """The target folder holds files this program did not write there (a user error: exit 2)."""


def _exchange(a: Path, b: Path) -> bool:
    """Atomically swap two paths (Linux renameat2); False where the system cannot."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _link_tree(src: Path, dst: Path) -> None:
    """Copy src to dst by hard links (a real copy where links are impossible)."""
    def link(s, d):
        try:
            os.link(s, d)
        except OSError:
            shutil.copy2(s, d)
    if src.is_dir() and not src.is_symlink():
        shutil.copytree(src, dst, copy_function=link, symlinks=True)
    elif src.is_symlink():
        os.symlink(os.readlink(src), dst)
    else:
        link(src, dst)


def written_entries(folder: Path) -> set | None:
    """Top-level names the program wrote into `folder` (its record), None without a record."""
    try:
        rec = json.loads((Path(folder) / RECORD_NAME).read_text())
        return set(rec["entries"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


class StagedDir:
    """A results folder written in a hidden staging folder and swapped in by `commit()`.

    kind: what the folder holds (messages, the record). legacy: glob patterns of top-level names an
    earlier version of this output wrote, used when the target has no record (then `marker`, a file
    that such outputs always hold, must be there). keep: names carried over from the target even
    though the program wrote them (e.g. a checkpoint written straight into the target).
    """

    def __init__(self, target, kind: str, legacy: tuple = (), marker: str | None = None, keep: tuple = ()):
        self.target = Path(target).absolute()
        self.kind, self.legacy, self.marker, self.keep = kind, tuple(legacy), marker, tuple(keep)
        self.committed = False
        self._check_target()
        self.target.parent.mkdir(parents=True, exist_ok=True)
        self._remove_stale()
        self.path = self.target.parent / f".{self.target.name}.partial-{os.getpid()}-{uuid.uuid4().hex[:6]}"
        self.path.mkdir()

    @classmethod
    def check(cls, target, kind: str, legacy: tuple = (), marker: str | None = None, keep: tuple = ()) -> None:
        """The refusals of the constructor, without creating anything (to refuse before hours of work)."""
        obj = cls.__new__(cls)
        obj.target = Path(target).absolute()
        obj.kind, obj.legacy, obj.marker, obj.keep = kind, tuple(legacy), marker, tuple(keep)
        obj._check_target()

    # ---------------------------------------------------------------- checks
    def _ours(self) -> set | None:
        """Names in the target this program wrote (None: the target is not an output of this kind)."""
        rec = written_entries(self.target)
        if rec is not None:
            return rec
        names = {p.name for p in self.target.iterdir()}
        if self.marker is not None and self.marker in names:
            return {n for n in names if any(fnmatch.fnmatch(n, pat) for pat in self.legacy)}
        return None

    def _check_target(self):
        t = self.target
        if not t.exists():
            return
        if not t.is_dir():
            raise OutputExistsError(f"{t}: exists and is not a folder; choose another output folder")
        names = [p.name for p in t.iterdir() if p.name not in self.keep]
        if names and self._ours() is None:
            shown = ", ".join(sorted(names)[:4]) + (", ..." if len(names) > 4 else "")
            raise OutputExistsError(f"{t}: not empty ({shown}) and not a {self.kind} folder written by this "
                                    f"program; refusing to write into it (choose an empty or new folder)")

    def _remove_stale(self):
        """Staging folders of runs that died (kill -9) beside the target."""
        for p in self.target.parent.glob(f".{self.target.name}.partial-*"):
            try:
                pid = int(p.name.rsplit(".partial-", 1)[1].split("-")[0])
            except ValueError:
                continue
            if pid != os.getpid() and not _pid_alive(pid):
                shutil.rmtree(p, ignore_errors=True)
        if self.target.exists():     # old folders of an interrupted two-rename swap
            for p in self.target.parent.glob(f".{self.target.name}.old-*"):
                shutil.rmtree(p, ignore_errors=True)

    # ---------------------------------------------------------------- use
    def file(self, rel: str) -> Path:
        """Path of `rel` inside the staging folder (parent folders created)."""
        p = self.path / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        return p

    def final(self, staged) -> Path:
        """Where a staged path will be after commit."""
        return self.target / Path(staged).absolute().relative_to(self.path)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        self.discard()
        return False

    def discard(self):
        if not self.committed:
            shutil.rmtree(self.path, ignore_errors=True)

    def commit(self) -> Path:
        """Swap the staged folder in; the user's files in the old target come along."""
        entries = sorted(p.name for p in self.path.iterdir() if p.name != RECORD_NAME)
        (self.path / RECORD_NAME).write_text(json.dumps({"kind": self.kind, "entries": entries}) + "\n")
        if self.target.exists():
            ours = self._ours() or set()
            for p in self.target.iterdir():
                if p.name == RECORD_NAME or (self.path / p.name).exists():
                    continue
                if p.name in ours and p.name not in self.keep:
                    continue
                _link_tree(p, self.path / p.name)
            if not _exchange(self.path, self.target):
                old = self.target.parent / f".{self.target.name}.old-{uuid.uuid4().hex[:6]}"
                os.replace(self.target, old)
                os.replace(self.path, self.target)
                self.committed = True
                shutil.rmtree(old, ignore_errors=True)
                return self.target
            self.committed = True
            shutil.rmtree(self.path, ignore_errors=True)    # now the old folder
        else:
            os.replace(self.path, self.target)
            self.committed = True
        return self.target


class terminate_as_interrupt:
    """SIGTERM (and SIGHUP) handled like Ctrl-C inside the block: whatever SIGINT does runs (by default a
    KeyboardInterrupt), so staging folders and temporary files are cleaned up on the way out."""

    SIGNALS = ("SIGTERM", "SIGHUP")

    def __enter__(self):
        import signal
        import threading
        self._old = {}
        if threading.current_thread() is not threading.main_thread():
            return self
        for name in self.SIGNALS:
            sig = getattr(signal, name, None)
            if sig is not None:
                self._old[sig] = signal.signal(sig, self._handler)
        return self

    @staticmethod
    def _handler(signum, frame):
        import signal
        h = signal.getsignal(signal.SIGINT)
        if callable(h) and h is not terminate_as_interrupt._handler:
            h(signal.SIGINT, frame)
        else:
            raise KeyboardInterrupt

    def __exit__(self, *exc):
        import signal
        for sig, h in self._old.items():
            signal.signal(sig, h)
        return False


class InterruptGuard:
    """Ctrl-C and SIGTERM remembered as well as raised, for code that runs inside Blender renders.

    Cycles runs Python's signal handler inside its render callback, where a KeyboardInterrupt is
    caught and printed by Blender (a traceback) and the render returns as if finished, with a partial
    image. So renders run inside `deferring()`: the signal is remembered, the render ends, and the
    KeyboardInterrupt is raised right after it, before its image is used.
    """

    requested = False
    _old: dict = {}

    @classmethod
    def install(cls):
        import signal
        import threading
        if threading.current_thread() is not threading.main_thread():
            return
        for name in ("SIGINT", "SIGTERM", "SIGHUP"):
            sig = getattr(signal, name, None)
            if sig is not None:
                cls._old[sig] = signal.signal(sig, cls._handler)

    @classmethod
    def uninstall(cls):
        import signal
        for sig, h in cls._old.items():
            signal.signal(sig, h)
        cls._old = {}

    deferred = False

    @classmethod
    def _handler(cls, signum, frame):
        cls.requested = True
        if not cls.deferred:
            raise KeyboardInterrupt

    @classmethod
    @contextmanager
    def deferring(cls):
        """Inside: a signal is only remembered (a render runs to its end); after: raised if one came."""
        old, cls.deferred = cls.deferred, True
        try:
            yield
        finally:
            cls.deferred = old
        cls.check()

    @classmethod
    def check(cls):
        if cls.requested:
            raise KeyboardInterrupt
