"""pybullet, imported and connected without its C banners on stdout.

pybullet's C code prints ``pybullet build time: …`` when imported and ``argv[0]=…`` when it connects, with C
stdio, so the lines land in qomni's own output (at exit, when stdout is a pipe). The import and the
connection run with file descriptors 1 and 2 pointed at /dev/null and C's buffers flushed before they are
restored; a failure still raises its Python exception afterwards.
"""
from __future__ import annotations

import contextlib
import ctypes
import functools
import os
import sys


@contextlib.contextmanager
def _c_stdout_silenced():
    try:
        libc = ctypes.CDLL(None)
    except OSError:                                   # no C library to flush (e.g. Windows): leave stdout
        yield
        return
    sys.stdout.flush()
    sys.stderr.flush()
    saved = {fd: os.dup(fd) for fd in (1, 2)}
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        for fd in saved:
            os.dup2(devnull, fd)
        yield
    finally:
        libc.fflush(None)
        for fd, copy in saved.items():
            os.dup2(copy, fd)
            os.close(copy)
        os.close(devnull)


with _c_stdout_silenced():
    import pybullet  # noqa: E402
    from pybullet_utils.bullet_client import BulletClient as _BulletClient  # noqa: E402


class _BoundClient(_BulletClient):
    """pybullet_utils' client with each pybullet function bound to the client id once.

    ``BulletClient.__getattr__`` builds a new ``functools.partial`` (after ``inspect.isbuiltin``) at every
    call, a few µs each on a path that calls PyBullet several times per 1 ms physics step. Here the partial
    is kept in the instance on first use, so later look-ups never reach ``__getattr__``. ``disconnect``
    is not kept: looking it up marks the client gone (the base class) and drops the kept functions, so no
    later call reaches a client that reuses the id.
    """

    def __getattr__(self, name):
        attribute = super().__getattr__(name)
        if name == "disconnect":
            for kept in [k for k, v in vars(self).items() if isinstance(v, functools.partial)]:
                del self.__dict__[kept]
        elif isinstance(attribute, functools.partial):
            self.__dict__[name] = attribute
        return attribute


def bullet_client(gui: bool = False) -> _BulletClient:
    """A new PyBullet client of its own (DIRECT, or GUI with a display), banner-free."""
    with _c_stdout_silenced():
        return _BoundClient(connection_mode=pybullet.GUI if gui else pybullet.DIRECT)


__all__ = ["pybullet", "bullet_client"]
