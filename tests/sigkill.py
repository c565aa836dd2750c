"""Test helper: run a ``tvcid`` command in a subprocess and interrupt it (SIGKILL, SIGTERM or
SIGINT, i.e. Ctrl-C) once its chain holds steps."""
import os
import signal
import subprocess
import sys
import time

import emcee

CLI = [sys.executable, "-c", "import sys; from tvcid.cli import main; sys.exit(main(sys.argv[1:]))"]


def kill_once_checkpointed(args, chain_glob, directory, min_steps, max_steps, stderr_path, timeout,
                           sig=signal.SIGKILL):
    """Start ``tvcid ARGS``; send ``sig`` as soon as ``directory/chain_glob`` holds ``min_steps``.

    Fails the test when the run ends (or saves ``max_steps``) before it could be interrupted, and,
    for SIGTERM and SIGINT, unless tvcid exits with status 130 and one line on stderr saying so
    (no traceback). Returns the steps the checkpoint held at the signal.
    """
    with open(stderr_path, "w") as err_file:
        proc = subprocess.Popen([*CLI, *args], stdout=subprocess.DEVNULL, stderr=err_file)
    saved, deadline = 0, time.time() + timeout
    while time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
        chains = sorted(directory.glob(chain_glob))
        if not chains:
            continue
        try:
            saved = emcee.backends.HDFBackend(str(chains[0]), read_only=True).iteration
        except Exception:  # not created yet, or being written
            continue
        if saved >= min_steps:
            break
    # a reader holding the chain must not kill the run (CheckpointBackend waits for it)
    assert proc.poll() is None and saved < max_steps, (
        f"the run ended before it could be killed ({saved} steps seen): "
        f"{open(stderr_path).read()[-500:]}")
    os.kill(proc.pid, sig)
    status = proc.wait(timeout=60)
    if sig != signal.SIGKILL:
        err = open(stderr_path).read()
        last = err.strip().splitlines()[-1] if err.strip() else ""
        assert status == 130 and "interrupted" in last and "Traceback" not in err, (
            f"after {sig.name}: status {status}, stderr {err[-800:]!r}")
    return saved
