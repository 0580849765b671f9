"""An interrupted command never hangs: Ctrl-C arms a watchdog that ends a process whose ending hangs."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time

from tests.collect.test_scripted import ctrl_c_reaches

# A command that, after Ctrl-C, runs ENDING: a lock it never gets hangs it, and only the watchdog ends it.
COMMAND = textwrap.dedent("""
    import sys, threading
    from demo import interrupts
    interrupts.GRACE_S = 1.0
    interrupts.install()
    lock = threading.Lock()
    lock.acquire()
    try:
        print("ready", flush=True)  # in the try: Ctrl-C may come as soon as it is printed
        threading.Event().wait(60)
    except KeyboardInterrupt:
        ENDING
""")
HANGS_WHILE_ENDING = COMMAND.replace("ENDING", "lock.acquire()")
ENDS_ON_CTRL_C = COMMAND.replace("ENDING", "sys.exit(130)")


def _interrupt(code: str) -> tuple[subprocess.CompletedProcess, float]:
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             start_new_session=True, preexec_fn=ctrl_c_reaches)
    try:
        assert child.stdout.readline().strip() == "ready"
        t0 = time.monotonic()
        child.send_signal(signal.SIGINT)
        out, err = child.communicate(timeout=30)
        return subprocess.CompletedProcess(child.args, child.returncode, out, err), time.monotonic() - t0
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()


def test_a_hang_after_ctrl_c_ends_with_every_thread_s_stack() -> None:
    done, seconds = _interrupt(HANGS_WHILE_ENDING)
    assert done.returncode == 1 and seconds < 20
    assert "Thread" in done.stderr and "Timeout" in done.stderr  # faulthandler's dump of the stacks
    hung_at = [n for n, line in enumerate(HANGS_WHILE_ENDING.splitlines(), 1) if "lock.acquire()" in line][-1]
    assert f"line {hung_at} in <module>" in done.stderr  # where it hung: the second lock.acquire()


def test_a_clean_ending_is_left_alone() -> None:
    done, seconds = _interrupt(ENDS_ON_CTRL_C)
    assert done.returncode == 130 and done.stderr == ""
    time.sleep(1.5)  # past the grace period: the watchdog died with the process, nothing printed later
