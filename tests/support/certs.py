"""Throwaway TLS certificates made with the openssl binary: a CA, a server cert for localhost.

The folder is world-readable (mosquitto started as root reads its files as the
user "mosquitto"); the keys are test keys, made fresh for each test session.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Certs:
    folder: Path
    ca: Path  # the CA that signed the server certificate
    other_ca: Path  # a CA that signed nothing the broker has
    server_cert: Path
    server_key: Path


def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True)


def _ca(name: str, cwd: Path) -> None:
    _openssl(
        "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
        "-keyout", f"{name}.key", "-out", f"{name}.crt", "-days", "2", "-subj", f"/CN={name}",
        cwd=cwd,
    )  # fmt: skip


def make_certs() -> Certs:
    if shutil.which("openssl") is None:
        msg = "openssl not found"
        raise FileNotFoundError(msg)
    folder = Path(tempfile.mkdtemp(prefix="scotti-certs-"))
    folder.chmod(0o755)
    _ca("ca", folder)
    _ca("other-ca", folder)
    _openssl(
        "req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
        "-keyout", "server.key", "-out", "server.csr", "-subj", "/CN=localhost", cwd=folder,
    )  # fmt: skip
    (folder / "san.ext").write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\n")
    _openssl(
        "x509", "-req", "-in", "server.csr", "-CA", "ca.crt", "-CAkey", "ca.key",
        "-CAcreateserial", "-out", "server.crt", "-days", "2", "-extfile", "san.ext", cwd=folder,
    )  # fmt: skip
    for path in folder.iterdir():
        path.chmod(0o644)
    return Certs(
        folder, folder / "ca.crt", folder / "other-ca.crt", folder / "server.crt",
        folder / "server.key",
    )  # fmt: skip
