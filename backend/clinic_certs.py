"""A clinic's own certificate authority for Zenoh's mutual TLS, made with the ``openssl`` tool.

One CA per clinic; the service gets a server certificate (its host names and addresses in the
subject alternative names, as rustls checks them), each device a client certificate whose
common name is its device name: the Zenoh access-control rules match that name
(``cert_common_names``), so a device can only publish under its own key.
Keys are ECDSA P-256 (PKCS#8 PEM), certificates SHA-256, valid ``days`` days.
"""

from __future__ import annotations

import ipaddress
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

from protocol import keys


@dataclass(frozen=True)
class Pair:
    cert: Path
    key: Path


def _openssl(*args: str) -> None:
    proc = subprocess.run(["openssl", *args], capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"openssl {args[0]} failed: {proc.stderr.strip()[:500]}")


def _key(path: Path) -> None:
    _openssl(
        "genpkey", "-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256", "-out", str(path)
    )
    path.chmod(0o600)


def make_ca(out: Path, name: str = "rehab clinic CA", days: int = 3650) -> Pair:
    out.mkdir(parents=True, exist_ok=True)
    pair = Pair(out / "ca.pem", out / "ca-key.pem")
    _key(pair.key)
    _openssl(
        "req", "-x509", "-new", "-key", str(pair.key), "-out", str(pair.cert), "-days", str(days),
        "-sha256", "-subj", f"/CN={name}",
        "-addext", "basicConstraints=critical,CA:TRUE,pathlen:0",
        "-addext", "keyUsage=critical,keyCertSign,cRLSign",
    )  # fmt: skip
    return pair


def _san(hosts: list[str]) -> str:
    items = []
    for h in hosts:
        try:
            ipaddress.ip_address(h)
        except ValueError:
            items.append(f"DNS:{h}")
        else:
            items.append(f"IP:{h}")
    return ",".join(items)


def issue(
    ca: Pair, out: Path, name: str, *, server_hosts: list[str] | None = None, days: int = 825
) -> Pair:
    """A leaf certificate with common name ``name``: a server's (``server_hosts`` as its
    alternative names; also usable as a client) or a device's (client only)."""
    if server_hosts is None and not keys.DEVICE_RE.fullmatch(name):
        raise ValueError(f"not a device name: {name!r}")
    pair = Pair(out / f"{name}.pem", out / f"{name}-key.pem")
    _key(pair.key)
    if server_hosts:
        ext = f"subjectAltName={_san(server_hosts)}\nextendedKeyUsage=serverAuth,clientAuth\n"
    else:
        ext = "extendedKeyUsage=clientAuth\n"
    ext += "basicConstraints=critical,CA:FALSE\nkeyUsage=critical,digitalSignature\n"
    with tempfile.TemporaryDirectory() as tmp:
        csr, extfile = Path(tmp) / "req.csr", Path(tmp) / "ext.cnf"
        extfile.write_text(ext)
        _openssl("req", "-new", "-key", str(pair.key), "-out", str(csr), "-subj", f"/CN={name}")
        _openssl(
            "x509", "-req", "-in", str(csr), "-CA", str(ca.cert), "-CAkey", str(ca.key),
            "-CAcreateserial", "-out", str(pair.cert), "-days", str(days), "-sha256",
            "-extfile", str(extfile),
        )  # fmt: skip
    return pair
