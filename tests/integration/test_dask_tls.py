"""``phrt sweep --scheduler tls://...`` on a Dask cluster that speaks only TLS (docs/cluster.md):
certificates made with ``openssl`` (a self-signed certificate that is its own CA), a ``dask
scheduler`` and one ``dask worker --resources phrt=1`` started with them, and the sweep given
the same files through ``--tls-ca-file/--tls-cert/--tls-key``.  Without them the sweep is
refused in one line; with them it runs the plan on the worker."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-user-"))

import bpy  # noqa: E402
import pytest  # noqa: E402

import phrt  # noqa: E402
from phrt_render import save_moving_showcase  # noqa: E402

BIN = Path(sys.executable).parent
PHRT = BIN / "phrt"
pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command")


def run_phrt(args, cwd):
    process = subprocess.run([str(PHRT), *args], cwd=cwd, capture_output=True, text=True, timeout=900)
    errors = [line for line in process.stderr.splitlines() if line.strip() and "EGL" not in line]
    return process.returncode, process.stdout, errors


@pytest.fixture(scope="module")
def tls_cluster(tmp_path_factory):
    """(scheduler address, TLS options, folder) of a running TLS-only scheduler with one worker."""
    if not hasattr(bpy.types.Scene, "phrt"):
        phrt.register()
    folder = tmp_path_factory.mktemp("tls")
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "key.pem", "-out",
                    "cert.pem", "-days", "2", "-subj", "/CN=localhost",
                    "-addext", "subjectAltName=IP:127.0.0.1,DNS:localhost"],
                   cwd=folder, check=True, capture_output=True)
    tls = ["--tls-ca-file", str(folder / "cert.pem"), "--tls-cert", str(folder / "cert.pem"),
           "--tls-key", str(folder / "key.pem")]
    scheduler_file = folder / "scheduler.json"
    processes = [subprocess.Popen([str(BIN / "dask"), "scheduler", "--protocol", "tls", "--host", "127.0.0.1",
                                   "--port", "0", "--no-dashboard", "--scheduler-file", str(scheduler_file), *tls],
                                  cwd=folder, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        deadline = time.monotonic() + 60
        while not scheduler_file.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = json.loads(scheduler_file.read_text())["address"]
        assert address.startswith("tls://127.0.0.1:")
        processes.append(subprocess.Popen(
            [str(BIN / "dask"), "worker", address, "--nworkers", "1", "--nthreads", "1", "--resources", "phrt=1",
             "--host", "127.0.0.1", "--no-dashboard", "--memory-limit", "0", *tls],
            cwd=folder, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        yield address, tls, folder
    finally:
        for process in reversed(processes):
            process.terminate()
        for process in processes:
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()


def test_a_tls_scheduler_without_certificates_is_refused_in_one_line(tls_cluster):
    address, _, folder = tls_cluster
    blend = save_moving_showcase(folder / "refused.blend", 32, 24)
    status, _, errors = run_phrt(["sweep", str(blend), "--frames", "1-2", "--out", "never", "--scheduler", address],
                                 folder)
    assert status == 2 and len(errors) == 1, errors
    assert errors[0].startswith("phrt: error: ") and "--tls-ca-file" in errors[0]
    assert not (folder / "never").exists()


def test_sweep_runs_on_a_tls_cluster_given_its_certificates(tls_cluster):
    address, tls, folder = tls_cluster
    blend = save_moving_showcase(folder / "showcase.blend", 32, 24)
    status, stdout, errors = run_phrt(["sweep", str(blend), "--frames", "1-2", "--budgets", "1", "--variants",
                                       "measured", "--resolution", "32x24", "--oracle-every", "2", "--out", "sw",
                                       "--scheduler", address, *tls], folder)
    assert status == 0, "\n".join(errors[-6:])
    assert f"the Dask cluster at {address}" in stdout
    done = [line for line in stdout.splitlines() if line.startswith("phrt: [") and ": done in " in line]
    assert len(done) == 4 and all(" on " in line for line in done), stdout
    assert (folder / "sw" / "report" / "report.md").is_file()
