"""A warm test runner for mutation testing (a dev tool; not part of the package, not run in CI).

mutmut runs the test command once per mutant. Started cold, every run spends seconds importing torch, numba's
cached kernels, Stable-Baselines3 and highway-env before the first test. This runner keeps one warm server that
has imported those libraries, and the unmutated layers of seal, and forks a fresh child per test run; the child
imports the mutated modules from disk (byte-code writing is off, so no stale ``.pyc`` of one mutant serves the
next) and runs pytest. Usage, from the repository root (README.md, "Mutation testing")::

    python tools/mutation_runner.py serve &                          # once
    mutmut run --paths-to-mutate FILE --runner "python tools/mutation_runner.py test TESTS..."
    python tools/mutation_runner.py stop

``test`` exits with pytest's exit code (0: the mutant survived). A run is cut after ``--timeout`` seconds.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import socket
import struct
import sys
from pathlib import Path

SOCKET = Path(os.environ.get("SEAL_MUTATION_SOCKET", "/tmp/seal-mutation-runner.sock"))

# Imported once in the server. Only layers that no mutated module sits in or below: a module listed here is
# shared by every child as it was when the server started.
WARM_MODULES = (
    "numpy", "torch", "numba", "gymnasium", "highway_env", "stable_baselines3", "shapely", "yaml", "pytest",
    "seal.core.kernels", "seal.core.scenario", "seal.core.dataset", "seal.envs.scenario_env", "seal.envs.obs_kernels",
    "seal.scoring.kernels", "seal.models.prior.prior", "seal.models.skills.fast",
)

MUTATED_PACKAGES = ("seal.adversaries", "seal.experiments", "seal.core.importers")
"""Where the mutated modules live: never imported by the server."""


def _send_int(conn: socket.socket, value: int) -> None:
    conn.sendall(struct.pack("!i", value))


def _recv_exact(conn: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = conn.recv(n - len(data))
        if not chunk:
            raise ConnectionError("runner connection closed")
        data += chunk
    return data


def _child(args: list[str], timeout_s: int) -> None:
    """In the forked child: a fresh pytest run over ``args``; never returns."""
    signal.alarm(timeout_s)  # a mutant that loops forever ends here (SIGALRM's default action kills the child)
    os.setsid()
    import pytest

    code = pytest.main(["-q", "-x", "-p", "no:cacheprovider", *args])
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(int(code))


def serve(timeout_s: int) -> None:
    """Import `WARM_MODULES`, then fork one child per request on `SOCKET` and answer its exit code."""
    sys.dont_write_bytecode = True
    os.environ["PYTHONDONTWRITEBYTECODE"] = "1"
    sys.path.insert(0, str(Path.cwd() / "tests"))
    for name in WARM_MODULES:
        importlib.import_module(name)
    shared = [m for m in sys.modules if m.startswith(MUTATED_PACKAGES)]
    if shared:  # a child would test the server's copy of these, not the mutant on disk
        raise SystemExit(f"warm imports loaded modules that may be mutated: {sorted(shared)[:5]}")
    with contextlib.suppress(FileNotFoundError):
        SOCKET.unlink()
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(str(SOCKET))
    server.listen(1)
    print(f"mutation runner ready on {SOCKET}", flush=True)
    while True:
        conn, _ = server.accept()
        with conn:
            size = struct.unpack("!i", _recv_exact(conn, 4))[0]
            request = _recv_exact(conn, size).decode().split("\0") if size else []
            if request == ["--stop"]:
                _send_int(conn, 0)
                break
            pid = os.fork()
            if pid == 0:
                server.close()
                _child(request, timeout_s)
            _, status = os.waitpid(pid, 0)
            code = os.waitstatus_to_exitcode(status)
            _send_int(conn, code if code >= 0 else 128 - code)
    server.close()
    SOCKET.unlink(missing_ok=True)


def request(args: list[str]) -> int:
    """Ask the server for one pytest run over ``args``; its exit code."""
    payload = "\0".join(args).encode()
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as conn:
        conn.connect(str(SOCKET))
        conn.sendall(struct.pack("!i", len(payload)) + payload)
        return struct.unpack("!i", _recv_exact(conn, 4))[0]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    serve_p = sub.add_parser("serve", help="start the warm server (foreground)")
    serve_p.add_argument("--timeout", type=int, default=120, help="seconds one test run may take")
    test_p = sub.add_parser("test", help="run pytest over the given arguments in a fresh child of the server")
    test_p.add_argument("pytest_args", nargs=argparse.REMAINDER)
    sub.add_parser("stop", help="stop the server")
    args = parser.parse_args()
    if args.cmd == "serve":
        serve(args.timeout)
        return 0
    if args.cmd == "stop":
        return request(["--stop"])
    return request(args.pytest_args)


if __name__ == "__main__":
    sys.exit(main())
