"""TLS between a host and its readers, with a CA and certificates made here by openssl:
a reader with the CA (and, with mTLS, its own certificate) gets the forces; a reader
without gets nothing. Also the [zenoh] table's TLS keys, through load_host_config."""

from __future__ import annotations

import contextlib
import shutil
from pathlib import Path

import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh (the zenoh extra) is not installed")

from canbus.master.hostconfig import load_host_config
from canbus.master.zenoh_settings import ZenohSettings
from canbus.zenoh.reader import subscribe
from tests.support.rigs.children import run
from tests.support.rigs.ports import tcp_port
from tests.support.rigs.waiting import wait_until
from tests.support.rigs.zenoh_host import publishing_host

OPENSSL = shutil.which("openssl")
pytestmark = pytest.mark.skipif(OPENSSL is None, reason="no openssl to make certificates")


def _openssl(*args: str, cwd: Path) -> None:
    assert OPENSSL is not None
    made = run([OPENSSL, *args], cwd=cwd, timeout=60)
    assert made.returncode == 0, made.stderr


def _certificate(name: str, cwd: Path, *, ca: bool = False, signer: str = "ca") -> None:
    """``name.key`` and ``name.pem``: a self-signed CA, or a leaf for localhost signed by
    ``signer``."""
    _openssl("ecparam", "-name", "prime256v1", "-genkey", "-noout", "-out", f"{name}.ec",
             cwd=cwd)
    _openssl("pkcs8", "-topk8", "-nocrypt", "-in", f"{name}.ec", "-out", f"{name}.key", cwd=cwd)
    if ca:
        _openssl("req", "-x509", "-new", "-key", f"{name}.key", "-days", "2", "-subj",
                 f"/CN={name}", "-addext", "basicConstraints=critical,CA:TRUE",
                 "-addext", "keyUsage=critical,keyCertSign,cRLSign", "-out", f"{name}.pem",
                 cwd=cwd)
        return
    _openssl("req", "-new", "-key", f"{name}.key", "-subj", f"/CN={name}", "-out",
             f"{name}.csr", cwd=cwd)
    (cwd / f"{name}.ext").write_text(
        "basicConstraints=CA:FALSE\nsubjectAltName=DNS:localhost,IP:127.0.0.1\n"
        "extendedKeyUsage=serverAuth,clientAuth\n")
    _openssl("x509", "-req", "-in", f"{name}.csr", "-CA", f"{signer}.pem", "-CAkey",
             f"{signer}.key", "-CAcreateserial", "-days", "2", "-extfile", f"{name}.ext",
             "-out", f"{name}.pem", cwd=cwd)


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    where = tmp_path_factory.mktemp("certs")
    _certificate("ca", where, ca=True)
    _certificate("host", where)
    _certificate("reader", where)
    _certificate("other-ca", where, ca=True)
    _certificate("stranger", where, signer="other-ca")
    return where


def _received(trusted: ZenohSettings, *others: ZenohSettings) -> list[int]:
    """Samples each of ``others`` received while a reader with ``trusted`` settings, at the
    same time, received 5 (so a reader that got none had every chance)."""
    with contextlib.ExitStack() as stack:
        subs = [stack.enter_context(subscribe(settings=s, ring=1)) for s in others]
        with subscribe(settings=trusted, ring=1) as sure:
            wait_until(lambda: sure.received >= 5, what="5 samples for the trusted reader")
        return [sub.received for sub in subs]


def _host_toml(certs: Path, port: int, mtls: bool, where: Path) -> Path:
    config = where / "host.toml"
    config.write_text(f"""
[[patches]]
node_id = 1
[zenoh]
host = "tls-host"
listen = ["tls/localhost:{port}"]
[zenoh.tls]
root_ca_certificate = "{certs / 'ca.pem'}"
listen_certificate = "{certs / 'host.pem'}"
listen_private_key = "{certs / 'host.key'}"
enable_mtls = {'true' if mtls else 'false'}
""")
    return config


def test_a_reader_with_the_ca_gets_forces_one_without_gets_nothing(certs: Path,
                                                                   tmp_path: Path) -> None:
    port = tcp_port()
    settings = load_host_config(_host_toml(certs, port, False, tmp_path)).zenoh
    assert settings is not None
    endpoint = f"tls/localhost:{port}"
    with publishing_host((1,), settings=settings):
        trusted = ZenohSettings(connect=(endpoint,),
                                tls={"root_ca_certificate": str(certs / "ca.pem")})
        wrong_ca = ZenohSettings(connect=(endpoint,),
                                 tls={"root_ca_certificate": str(certs / "other-ca.pem")})
        # no CA: no link; another CA; plain TCP
        assert _received(trusted, ZenohSettings(connect=(endpoint,)), wrong_ca,
                         ZenohSettings(connect=(f"tcp/127.0.0.1:{port}",))) == [0, 0, 0]


def test_with_mtls_a_reader_needs_a_certificate_of_the_ca(certs: Path, tmp_path: Path) -> None:
    port = tcp_port()
    settings = load_host_config(_host_toml(certs, port, True, tmp_path)).zenoh
    assert settings is not None
    endpoint = f"tls/localhost:{port}"
    ca = str(certs / "ca.pem")

    def reader(name: str | None, root: str = ca) -> ZenohSettings:
        tls = {"root_ca_certificate": root, "enable_mtls": True}
        if name is not None:
            tls |= {"connect_certificate": str(certs / f"{name}.pem"),
                    "connect_private_key": str(certs / f"{name}.key")}
        return ZenohSettings(connect=(endpoint,), tls=tls)

    with publishing_host((1,), settings=settings):
        # no certificate; one signed by another CA
        assert _received(reader("reader"), reader(None), reader("stranger")) == [0, 0]


def test_access_control_lets_only_the_named_reader_have_the_forces(certs: Path,
                                                                   tmp_path: Path) -> None:
    """docs/zenoh.md's access-control example: mTLS names the readers by their
    certificate's common name; the rules let only `reader` receive the forces."""
    _certificate("other-reader", certs)  # the same CA, another name
    port = tcp_port()
    config = _host_toml(certs, port, True, tmp_path)
    config.write_text(config.read_text() + """
[zenoh.options.access_control]
enabled = true
default_permission = "deny"
[[zenoh.options.access_control.rules]]
id = "forces out"
permission = "allow"
flows = ["egress", "ingress"]
messages = ["put", "declare_subscriber", "liveliness_token"]
key_exprs = ["canskin/**"]
[[zenoh.options.access_control.subjects]]
id = "controller"
cert_common_names = ["reader"]
[[zenoh.options.access_control.policies]]
rules = ["forces out"]
subjects = ["controller"]
""")
    settings = load_host_config(config).zenoh
    assert settings is not None
    endpoint = f"tls/localhost:{port}"

    def reader(name: str) -> ZenohSettings:
        return ZenohSettings(connect=(endpoint,), tls={
            "root_ca_certificate": str(certs / "ca.pem"), "enable_mtls": True,
            "connect_certificate": str(certs / f"{name}.pem"),
            "connect_private_key": str(certs / f"{name}.key")})

    with publishing_host((1,), settings=settings):
        assert _received(reader("reader"), reader("other-reader")) == [0]
