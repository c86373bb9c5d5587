"""SIGTERM, Ctrl-C (SIGINT) and a closed terminal (SIGHUP) for the ``nrtraffic`` command, from its
first instruction to its last. SIGHUP is handled as SIGTERM is.

A signal must never end the process without a run directory that says what happened. Until a run
has written its first ``summary.json`` (``"status": "running"``) nothing can be kept, so a signal
is *deferred*: it is noted, the pre-run checks and the set-up go on, and it is raised as soon as the
run is *armed* (:func:`arm`), which then stops like any interrupt of a running simulation: what was
finished is written and ``summary.json`` says ``"status": "failed"`` and why; further signals are
ignored while that is written. A second signal while one is deferred stops at once (a way out of a
slow check). A signal is never raised while numba compiles a kernel or loads it from its cache
(an exception there can crash the process, :func:`_in_compiler`): it is sent again every
:data:`AGAIN_S` until it lands outside, and acts then. Once the run's results are written the
command defers again (:func:`defer`), so that its figures and report are finished; :func:`pending`
then tells the command that it was asked to stop. Once the command has its exit status
(:func:`finish`) a signal is only noted, whichever came before, and once the command returns it
is ignored (:func:`settle`), so that a signal while the interpreter shuts down is neither a
traceback nor a kill.

Only the command installs these handlers (:func:`install`, in the main thread); in a library call,
a test or a sweep's worker :func:`arm` and :func:`defer` do nothing.
"""

from __future__ import annotations

import os
import signal
import sys
import threading


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C: the run stops, and what it finished is written."""


_installed: dict[int, object] = {}  # signal -> the handler before install()
_armed = False
_pending: int | None = None
_received: int | None = None  # the signal that interrupted the run (armed), for its summary
_finished = False  # the command has its exit status: a signal is noted, never raised


AGAIN_S = 0.01  # a signal that came while numba compiled is sent again after this [s]

# the signals handled: termination, Ctrl-C, and the terminal closing (SIGHUP, where there is one)
SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGINT", "SIGHUP") if hasattr(signal, name))


def _interrupt(signum: int) -> KeyboardInterrupt:
    if signum == signal.SIGINT:
        return KeyboardInterrupt("interrupted (SIGINT)")
    return Terminated(f"terminated by {signal.Signals(signum).name}")


def _handler(signum, frame) -> None:
    global _pending, _received
    if _finished:
        _pending = _pending or signum
        return
    if _armed and _received is not None:
        return  # one is enough: the run is stopping, let its clean-up finish
    if _armed or _pending is not None:
        if _in_compiler(frame):  # never raised inside numba or LLVM: sent again until it lands outside
            _send_again(signum)
            return
        _received = signum
        raise _interrupt(signum)
    _pending = signum


def _in_compiler(frame) -> bool:
    """Whether ``frame`` or a frame that called it is numba's or llvmlite's code (compiling a
    kernel, or loading it from numba's cache). An exception raised there can land in one of
    llvmlite's ctypes callbacks, which ignores it and hands LLVM an unfinished answer: the process
    then dies of a segmentation fault, its summary still saying "running"."""
    dirs = tuple(os.path.dirname(m.__file__) + os.sep for m in map(sys.modules.get, ("numba", "llvmlite"))
                 if getattr(m, "__file__", None))
    while dirs and frame is not None:
        if frame.f_code.co_filename.startswith(dirs):
            return True
        frame = frame.f_back
    return False


_again: threading.Timer | None = None  # the signal, to be sent again (one at a time)


def _send_again(signum: int) -> None:
    """Send ``signum`` to this process again in :data:`AGAIN_S`, so that it interrupts once the
    compiler has returned."""
    global _again
    if _again is not None and _again.is_alive():
        return
    _again = threading.Timer(AGAIN_S, os.kill, (os.getpid(), signum))
    _again.daemon = True
    _again.start()


def install() -> None:
    """Handle SIGTERM and SIGINT, deferred until :func:`arm` (main thread only; elsewhere nothing)."""
    global _armed, _pending, _received, _finished
    if threading.current_thread() is not threading.main_thread():
        return
    _armed, _pending, _received, _finished = False, None, None, False
    for sig in SIGNALS:
        _installed[sig] = signal.signal(sig, _handler)


def uninstall() -> None:
    """The handlers from before :func:`install` back (the command returns to a caller)."""
    global _armed, _pending, _received, _finished
    if _again is not None:
        _again.cancel()
    for sig, old in _installed.items():
        signal.signal(sig, old)
    _installed.clear()
    _armed, _pending, _received, _finished = False, None, None, False


def arm() -> None:
    """From now on a signal interrupts at once; one that came before is raised here."""
    global _armed, _pending, _received
    if not _installed:
        return
    _armed = True
    if _pending is not None:
        signum, _pending, _received = _pending, None, _pending
        raise _interrupt(signum)


def defer() -> None:
    """From now on a signal is only noted (:func:`pending`): what the run finished is being written."""
    global _armed
    if _installed:
        _armed = False


def finish() -> None:
    """The command has its exit status: from now on a signal is only noted (:func:`pending`), also
    a second one while one is deferred, which would otherwise stop at once."""
    global _armed, _finished
    if _installed:
        _armed, _finished = False, True


def settle() -> None:
    """The process is about to exit with the command's status: the signals it handles are ignored
    from now on. (The interpreter, shutting down, puts back the default action of a signal whose handler
    is Python's, which would end the process with 143 or 130 after its outputs were complete and
    its status printed; an ignored signal it leaves ignored.)"""
    if _installed:
        for sig in _installed:
            signal.signal(sig, signal.SIG_IGN)


def pending() -> str | None:
    """The name of a signal noted while deferred (``"SIGTERM"``), or None."""
    return None if _pending is None else signal.Signals(_pending).name


def received() -> str | None:
    """The name of the signal that interrupted the run, or None. A library the run was in may have
    turned the interrupt into an error of its own (numba, stopped while it compiled), so that the
    error does not say it; the run's summary then does."""
    return None if _received is None else signal.Signals(_received).name
