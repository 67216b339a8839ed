"""A run's PNG figures (``output.figures: png``) drawn beside the fit, by two forked helper
processes (Linux). The default SVG figures need none: they are drawn in the run's process
(:mod:`~mbus_framework.pipeline.svg`).

Importing matplotlib and drawing six figures costs about as much CPU as the rest of a run.
``mbus-run`` forks a helper as it starts (:func:`prestart`; a run from Python forks it in
:func:`start`, once the config says the run will plot); the helper imports matplotlib (and loads
its fonts) while the parent imports the rest, reads the config, acquires and fits. :meth:`Helpers.submit` sends
it the :class:`~mbus_framework.pipeline.figures.FitData` (pickled, over a pipe that never blocks
the parent); the helper forks
once more and the two draw half of the figures each, so on two cores the figures cost about half
their CPU time in wall time, and the parent never imports matplotlib. The figures that need no fit
(:data:`~mbus_framework.pipeline.figures.BEFORE_FIT`: the excitation spectrum) are sent before the
solver starts (:meth:`Helpers.draw_early`) and drawn while the parent fits. Each PNG comes back
over a pipe as soon as it is drawn, byte for byte what
:func:`~mbus_framework.pipeline.figures.render_all` makes in the parent.

Used only where forking is safe: Linux, a process with a single thread (not a notebook kernel, a
Dask worker or a threaded BLAS), and not switched off with ``MBUS_FIGURE_WORKERS=0``. A helper
that cannot start, dies, sends something unreadable or stays silent for :data:`SILENCE` seconds
costs only time: the parent draws the missing figures itself (and a figure that fails to draw
fails there, as it would without helpers).
"""
from __future__ import annotations

import gc
import io
import os
import pickle
import selectors
import signal
import sys
import struct
from typing import TYPE_CHECKING, Callable, Sequence

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.pipeline.figures import FitData

#: Environment switch: ``0`` draws every figure in the run's own process.
ENV = "MBUS_FIGURE_WORKERS"
#: Seconds without a figure from the helpers after which the parent stops waiting and draws.
SILENCE = 300.0
#: Relative CPU cost of drawing each figure, to split them evenly (CPU ms per figure of the potato
#: run, measured in a warm helper: log axes and many ticks cost most).
WEIGHT = {"frequency_response": 210.0, "convergence": 205.0, "fit": 165.0, "excitation": 150.0,
          "correlation": 140.0, "dispersion": 130.0}


def threads() -> int:
    """Threads of this process as the kernel counts them (Python's and native ones)."""
    try:
        return len(os.listdir("/proc/self/task"))
    except OSError:
        return 0  # unknown: treated as unsafe


def available() -> bool:
    """True where forking is safe and wanted: Linux, one thread, ``MBUS_FIGURE_WORKERS`` not 0."""
    return (sys.platform.startswith("linux") and hasattr(os, "fork") and os.environ.get(ENV, "1") != "0"
            and threads() == 1)


def split(names: Sequence[str]) -> tuple[list[str], list[str]]:
    """The figures in the two groups whose costlier one costs least (every partition is tried:
    there are at most a handful of figures), the costlier group first: the helper draws it, its
    fork (which first pays for copying the helper's memory pages it touches) the other."""
    names = list(names)
    cost = [WEIGHT.get(n, 150.0) for n in names]
    total = sum(cost)

    def heavier(mask: int) -> float:
        part = sum(c for i, c in enumerate(cost) if mask >> i & 1)
        return max(part, total - part)

    best = min(range(1 << len(names)), key=heavier)  # the first of equals: deterministic
    groups = ([n for i, n in enumerate(names) if best >> i & 1], [n for i, n in enumerate(names) if not best >> i & 1])
    load = [sum(WEIGHT.get(n, 150.0) for n in g) for g in groups]
    return groups if load[0] >= load[1] else (groups[1], groups[0])


class Helpers:
    """The forked helper (and, once it has the data, its own fork); see the module docstring."""

    def __init__(self, pid: int, data_fd: int, out_fds: tuple[int, int]) -> None:
        self.pid, self.data_fd, self.out_fds = pid, data_fd, out_fds
        self.pending = bytearray()  # messages not yet taken by the helper (the data pipe does not block)
        self.early: dict[str, int] = {}  # figures sent by draw_early -> their dpi
        self.submitted: tuple["FitData", int] | None = None  # the data and dpi sent by submit

    def draw_early(self, d: "FitData", dpi: int = 100) -> None:
        """Send the figures of ``d`` that need no fit (:data:`~mbus_framework.pipeline.figures.BEFORE_FIT`;
        ``d`` may be :meth:`~mbus_framework.pipeline.figures.FitData.before_fit`): the helper draws
        them while the run fits; :meth:`render` collects them. Never blocks."""
        from mbus_framework.pipeline.figures import BEFORE_FIT, applicable

        names = [n for n in applicable(d) if n in BEFORE_FIT and n not in self.early]
        if names and self.data_fd >= 0:
            try:
                self._send(("early", d, dpi, names))
            except OSError:
                return  # the helper is gone: render draws everything here
            self.early.update(dict.fromkeys(names, dpi))

    def submit(self, d: "FitData", dpi: int = 100) -> None:
        """Send the data of the figures not drawn early: the helpers start drawing while the run
        writes its results; :meth:`render` (with the same ``d``) collects. Never blocks."""
        from mbus_framework.pipeline.figures import applicable

        names = [n for n in applicable(d) if self.early.get(n) != dpi]  # early ones: same record, same dpi
        self.submitted = (d, dpi)
        if self.data_fd >= 0:
            try:
                self._send(("final", d, dpi, split(names)))
            except OSError:
                pass  # the helper is gone: render draws everything here

    def render(self, d: "FitData", dpi: int = 100,
               deliver: Callable[[str, bytes], None] | None = None) -> dict[str, bytes]:
        """PNG bytes of every figure that applies, in :data:`~mbus_framework.pipeline.figures.FIGURES`
        order; ``deliver(name, png)`` is called for each as it arrives (the run saves it while the
        others are drawn)."""
        from mbus_framework.pipeline.figures import applicable, render_all

        names = applicable(d)
        if self.submitted is None or self.submitted[0] is not d or self.submitted[1] != dpi:
            self.submit(d, dpi)
        pngs: dict[str, bytes] = {}

        def arrived(name: str, drawn_at: int, png: bytes) -> None:
            if name in names and name not in pngs and drawn_at == dpi:
                if deliver is not None:
                    deliver(name, png)  # if it fails, the figure counts as missing (and fails again below)
                pngs[name] = png

        finished = False
        if self.data_fd >= 0:
            try:
                data_fd, self.data_fd = self.data_fd, -1  # _exchange closes it
                finished = _exchange(data_fd, self.pending, self.out_fds, arrived)
            except OSError:
                pass  # a helper went away: the parent draws what is missing
        self.close(wait=finished)
        for name in names:
            if name not in pngs:
                arrived(name, dpi, render_all(d, dpi, [name])[name])
        return {n: pngs[n] for n in names}

    def _send(self, message: tuple) -> None:
        """Queue ``message`` for the helper and write what the pipe takes now; a helper that is
        gone ends these helpers (the parent then draws everything)."""
        self.pending += pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
        try:
            while self.pending:
                del self.pending[:os.write(self.data_fd, self.pending)]
        except BlockingIOError:
            pass  # the rest goes when the helper reads (render waits for it)
        except OSError:
            self.close()
            raise

    def close(self, wait: bool = False) -> None:
        """Close the pipes and reap the helper: ``wait`` for it when it has sent everything (it
        only reaps its own fork then), else end it first (idempotent)."""
        for fd in (self.data_fd, *self.out_fds):
            if fd >= 0:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self.data_fd, self.out_fds = -1, (-1, -1)
        self.pending.clear()
        if self.pid > 0:
            try:
                if wait:  # both pipes closed: it is only reaping its fork
                    os.waitpid(self.pid, 0)
                elif os.waitpid(self.pid, os.WNOHANG) == (0, 0):
                    os.kill(self.pid, signal.SIGKILL)
                    os.waitpid(self.pid, 0)
            except (OSError, ChildProcessError):
                pass
            self.pid = 0

    def __enter__(self) -> "Helpers":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: A helper forked by ``mbus-run`` before its own imports (:func:`prestart`), for the run's :func:`start`.
_early: list[Helpers] = []


def prestart() -> None:
    """Fork the helper now, at the command line's start: it imports numpy and matplotlib while the
    run imports scipy and reads its config; the run's :func:`start` takes it. :func:`discard`
    ends it if no run does."""
    if not _early:
        helpers = start()
        if helpers is not None:
            _early.append(helpers)


def discard() -> None:
    """End a :func:`prestart` helper that no run took."""
    while _early:
        _early.pop().close()


def start() -> Helpers | None:
    """The helper forked by :func:`prestart`, or a new one (it starts importing matplotlib at
    once); None where :func:`available` is false."""
    if _early:
        return _early.pop()
    if not available():
        return None
    data_r, data_w = os.pipe()
    out = [os.pipe(), os.pipe()]
    parent = os.getpid()
    try:
        pid = os.fork()
    except OSError:
        for fd in (data_r, data_w, *out[0], *out[1]):
            os.close(fd)
        return None
    if pid == 0:  # the helper: never returns
        _helper(data_r, (out[0][1], out[1][1]), closing=(data_w, out[0][0], out[1][0]), parent=parent)
    for fd in (data_r, out[0][1], out[1][1]):
        os.close(fd)
    os.set_blocking(data_w, False)  # Helpers._send never waits for the helper
    return Helpers(pid, data_w, (out[0][0], out[1][0]))


def _die_with_parent(parent: int) -> None:
    """End this process when ``parent`` ends (Linux ``PR_SET_PDEATHSIG``), even when it is killed."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # 1: PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:  # it ended before the request
        os._exit(1)


def _helper(data_fd: int, out_fds: tuple[int, int], closing: tuple[int, ...], parent: int) -> None:
    """Body of the forked helper: warm matplotlib, then read messages: draw an ``early`` one's
    figures at once; at the ``final`` one fork, the two draw a half each, and exit (os._exit).
    The end of the data before a final message (the run ended without figures) ends it too."""
    status = 1
    try:
        for s in (signal.SIGINT, signal.SIGTERM):
            signal.signal(s, signal.SIG_DFL)  # Ctrl-C or kill ends a helper quietly; the parent cleans up
        _die_with_parent(parent)
        for fd in closing:
            os.close(fd)
        _warm()
        gc.freeze()  # what is loaded now lives to the end: collections between figures skip it
        with os.fdopen(data_fd, "rb") as data, os.fdopen(out_fds[0], "wb") as out:
            while True:
                try:
                    kind, d, dpi, names = pickle.load(data)
                except EOFError:  # no (more) figures wanted
                    os._exit(0)
                if kind == "early":
                    _draw(d, dpi, names, out)
                    continue
                mine, theirs = names
                helper = os.getpid()
                pid = os.fork()
                if pid == 0:
                    _die_with_parent(helper)
                    os.close(out_fds[0])
                    with os.fdopen(out_fds[1], "wb") as theirs_out:
                        _draw(d, dpi, theirs, theirs_out)
                    os._exit(0)
                os.close(out_fds[1])
                _draw(d, dpi, mine, out)
                break
        os.waitpid(pid, 0)
        status = 0
    except BaseException:  # noqa: BLE001 - the parent draws whatever did not arrive
        pass
    os._exit(status)


def _warm() -> None:
    """Import the figures and the Agg canvas and save one small PNG with a text, so fonts and
    the PNG writer are loaded before the data arrives."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    import mbus_framework.pipeline.figures  # noqa: F401 - what the data's classes and the drawing need
    import mbus_framework.pipeline.html  # noqa: F401

    fig = Figure(figsize=(1, 1))
    FigureCanvasAgg(fig)
    fig.text(0.5, 0.5, "0")
    fig.savefig(io.BytesIO(), format="png", dpi=10)


#: A record on a helper's pipe: its length (8 bytes, little-endian), then the pickled (name, dpi, PNG bytes).
FRAME = struct.Struct("<Q")


def _draw(d: "FitData", dpi: int, names: list[str], out: "io.BufferedWriter") -> None:
    """Draw ``names``, writing a (name, dpi, PNG bytes) record (:data:`FRAME`) to ``out`` as each is done; a figure that fails
    is left for the parent. The cyclic garbage collector waits while a figure is drawn (matplotlib
    makes thousands of linked objects: about a tenth of the drawing time) and runs between figures,
over the figure's objects only (the helper froze what it had loaded before)."""
    from mbus_framework.pipeline.figures import render_all

    for name in names:
        gc.disable()
        try:
            png = render_all(d, dpi, [name])[name]
        except Exception:  # noqa: BLE001 - drawn (and raised) again in the parent
            continue
        finally:
            gc.enable()
            gc.collect()
        record = pickle.dumps((name, dpi, png), protocol=pickle.HIGHEST_PROTOCOL)
        out.write(FRAME.pack(len(record)) + record)
        out.flush()


def _exchange(data_fd: int, pending: bytearray, fds: tuple[int, int],
              arrived: Callable[[str, int, bytes], None]) -> bool:
    """Write ``pending`` to the helper (then close ``data_fd``) while reading both helpers' pipes,
    passing each whole (name, dpi, PNG) record to ``arrived`` as it comes, until both pipes close
    (True) or :data:`SILENCE` passes (False). Both at once: a helper that is still sending an
    early figure reads the rest of the data only after. A record that cannot be read ends the
    reading of that pipe (False: those figures are drawn by the parent)."""
    buffers = {fd: bytearray() for fd in fds}
    readable = True
    try:
        with selectors.DefaultSelector() as sel:
            for fd in fds:
                sel.register(fd, selectors.EVENT_READ)
            if pending:
                sel.register(data_fd, selectors.EVENT_WRITE)
            while any(fd in sel.get_map() for fd in fds):
                ready = sel.select(SILENCE)
                if not ready:
                    return False  # silent helpers: the parent draws the rest
                for key, _ in ready:
                    if key.fd == data_fd:
                        try:
                            del pending[:os.write(data_fd, pending)]
                        except BlockingIOError:
                            continue
                        if not pending:  # all sent: the helper may read to the end of the data
                            sel.unregister(data_fd)
                            os.close(data_fd)
                            data_fd = -1
                        continue
                    chunk = os.read(key.fd, 1 << 20)
                    if not chunk:
                        sel.unregister(key.fd)
                        continue
                    buf = buffers[key.fd]
                    buf += chunk
                    if not _records(buf, arrived):
                        sel.unregister(key.fd)  # unreadable: ignore the rest of this pipe
                        readable = False
            return readable and not sel.get_map()
    finally:
        if data_fd >= 0:
            os.close(data_fd)


def _records(buf: bytearray, arrived: Callable[[str, int, bytes], None]) -> bool:
    """Pass the whole records at the start of ``buf`` to ``arrived`` and remove them; False when
    one is not a (name, dpi, PNG bytes) record."""
    while len(buf) >= FRAME.size:
        (size,) = FRAME.unpack_from(buf)
        if len(buf) < FRAME.size + size:
            return True  # the rest of this record has not come yet
        try:
            name, dpi, png = pickle.loads(bytes(buf[FRAME.size:FRAME.size + size]))
        except Exception:  # noqa: BLE001 - garbage on the pipe
            return False
        if not (isinstance(name, str) and isinstance(dpi, int) and isinstance(png, bytes)):
            return False
        del buf[:FRAME.size + size]
        arrived(name, dpi, png)
    return True
