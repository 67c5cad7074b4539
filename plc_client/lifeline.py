"""Die with the parent process: the demo's processes end when their launcher ends (Linux).

Run as a script in front of a program::

    python -I -S plc_client/lifeline.py PARENT_PID -- PROGRAM [ARG...]

it asks the kernel to send SIGTERM to this process when its parent ends (``prctl
PR_SET_PDEATHSIG``; the setting survives the ``execvp`` of PROGRAM), then checks that its parent
is still PARENT_PID: if the parent ended before the ``prctl`` (between its fork and here), this
process has been re-parented and nobody would ever signal it, so it ends at once instead. Then
it becomes PROGRAM (``execvp``: same pid, same environment).

``zenoh-nc-demo`` starts ``nc-server`` and ``plc-run`` through it (:func:`wrap`), and ``make demo``
starts the launcher itself through it with make's pid, so a SIGKILL of make ends the launcher,
and a SIGKILL of the launcher ends its children. SIGTERM and not SIGKILL: nc-server then stops
moving axes with their stop ramp and plc-run switches its enables off and releases its claims,
as after Ctrl-C; both end within a few seconds.

Notes: the signal is sent when the parent *thread* that forked ends (the demo forks from its
main thread); it is not kept for set-user-ID programs; elsewhere than on Linux the program is
simply started. Standard library only, no import of the package (``-S``: no site-packages
either), so the program starts without delay.
"""
from __future__ import annotations

import ctypes
import os
import signal
import sys
from typing import Sequence

#: linux/prctl.h
PR_SET_PDEATHSIG = 1


def die_with_parent(parent: int, sig: int = signal.SIGTERM) -> bool:
    """Have ``sig`` sent to this process when its parent ends; end at once (with ``sig``) if
    the parent is no longer ``parent``.

    Returns:
        True if the kernel took the setting, False where ``prctl`` is missing (not Linux).

    Raises:
        OSError: prctl refused (errno).
    """
    if not sys.platform.startswith("linux"):
        return False
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"prctl(PR_SET_PDEATHSIG): {os.strerror(err)}")
    if os.getppid() != parent:  # the parent ended before the prctl: nobody will signal us
        signal.signal(sig, signal.SIG_DFL)
        os.kill(os.getpid(), sig)
        os._exit(128 + int(sig))  # if sig was blocked
    return True


def wrap(argv: Sequence[str], parent: int | None = None) -> list[str]:
    """The command line that runs ``argv`` through this file, bound to ``parent`` (default: the
    calling process, which must start it from the thread that stays alive as long as it)."""
    return [sys.executable, "-I", "-S", os.path.abspath(__file__), str(os.getpid() if parent is None else parent),
            "--", *argv]


def main(argv: Sequence[str]) -> int:
    """``lifeline.py PARENT_PID -- PROGRAM [ARG...]``; returns only on a usage error (2)."""
    args = list(argv)
    if len(args) < 3 or args[1] != "--" or not args[0].isdigit():
        print("usage: lifeline.py PARENT_PID -- PROGRAM [ARG...]", file=sys.stderr)
        return 2
    die_with_parent(int(args[0]))
    program = args[2:]
    try:
        os.execvp(program[0], program)
    except OSError as exc:
        print(f"lifeline: cannot run {program[0]}: {exc}", file=sys.stderr)
        return 127
    return 0  # not reached


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
