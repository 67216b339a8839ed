"""A fake serial instrument on a pseudo-terminal (POSIX only)."""
from __future__ import annotations

import os
import select
import threading
import tty


class PtyDevice:
    """Plays an instrument on the master side of a pty; drivers open :attr:`port`.

    Subclasses implement :meth:`feed` (called with every chunk the driver wrote) and answer
    with :meth:`send`. :meth:`disconnect` (from :meth:`feed`) closes the master side, which the
    driver sees as an unplugged cable (EIO). ``received`` holds every byte the driver sent;
    ``errors`` collects exceptions raised inside :meth:`feed` (tests assert it is empty).
    """

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        self.received = bytearray()
        self.errors: list[BaseException] = []
        self.disconnected = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=type(self).__name__, daemon=True)

    def start(self) -> "PtyDevice":
        self._thread.start()
        return self

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def feed(self, data: bytes) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def send(self, data: bytes) -> None:
        view = memoryview(data)
        while view and not self.disconnected and not self._stop.is_set():
            try:
                _, writable, _ = select.select([], [self.master], [], 0.05)
                if writable:
                    view = view[os.write(self.master, view):]
            except OSError:
                return

    def disconnect(self) -> None:
        if not self.disconnected:
            self.disconnected = True
            os.close(self.master)

    def _loop(self) -> None:
        while not self._stop.is_set() and not self.disconnected:
            try:
                ready, _, _ = select.select([self.master], [], [], 0.02)
                if not ready:
                    continue
                data = os.read(self.master, 65536)
            except OSError:
                break
            if not data:
                break
            self.received += data
            try:
                self.feed(data)
            except Exception as exc:  # noqa: BLE001 - reported to the test
                self.errors.append(exc)

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2.0)
        if not self.disconnected:
            self.disconnected = True
            os.close(self.master)
        try:
            os.close(self.slave)
        except OSError:
            pass
