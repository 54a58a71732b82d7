"""Production security: Basic256Sha256 Sign&Encrypt with the certificate from `cellctl secure init`, users from
the secured bus' principals, and the gateway on the bus as the plc principal."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
from asyncua import Client, ua
from asyncua.crypto import cert_gen
from cryptography import x509
from cryptography.hazmat.primitives import serialization
from cryptography.x509.oid import ExtendedKeyUsageOID

from cellctl.bus.security import init_deployment
from cellctl.config import load_config
from cellctl.gateway.opcua import CELLCTL_NS, OpcuaGateway, load_gateway_config
from cellctl.gateway.opcua.server import read_users
from tests.conftest import cfg_overrides, free_port
from tests.gateway.conftest import make_daemon, wait_until

CLIENT_URI = "urn:cellctl:test:plc"


def client_certificate(folder: Path) -> tuple[Path, Path]:
    key = cert_gen.generate_private_key()
    cert = cert_gen.generate_self_signed_app_certificate(
        key, "test plc", {}, [x509.UniformResourceIdentifier(CLIENT_URI)], [ExtendedKeyUsageOID.CLIENT_AUTH], 30
    )
    (folder / "plc-key.pem").write_bytes(cert_gen.dump_private_key_as_pem(key))
    (folder / "plc.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return folder / "plc.pem", folder / "plc-key.pem"


async def secure_client(url: str, cert: Path, key: Path, user: str, password: str) -> Client:
    c = Client(url, timeout=10)
    c.application_uri = CLIENT_URI
    await c.set_security_string(f"Basic256Sha256,SignAndEncrypt,{cert},{key}")
    c.set_user(user)
    c.set_password(password)
    await c.connect()
    return c


def test_sign_and_encrypt_with_bus_principals(tmp_path: Path) -> None:
    sec = tmp_path / "secure"
    init_deployment(sec, "cell1")
    assert (sec / "opcua" / "server.pem").is_file() and (sec / "opcua" / "server.key").stat().st_mode & 0o077 == 0
    passwords = read_users(sec / "passwords")
    cfg = load_config(None, [*cfg_overrides(tmp_path, free_port()), f"bus.security_dir={sec}"])
    gw_cfg = load_gateway_config(None, [f"endpoint=opc.tcp://127.0.0.1:{free_port()}", "security=[sign_encrypt]"])
    cert, key = client_certificate(tmp_path)
    cell = make_daemon(cfg)
    gw = OpcuaGateway(cfg, gw_cfg).start_thread()
    try:
        assert gw.cell_cfg.bus.principal == "plc"
        wait_until(lambda: gw._down.get("cell1") is None, 15, "the gateway on the secured bus")

        async def body() -> None:
            url = gw_cfg.endpoint
            with pytest.raises(Exception):  # noqa: B017 - no unsecured endpoint to talk to
                async with Client(url, timeout=5) as plain:
                    await plain.nodes.objects.read_browse_name()
            c = await secure_client(url, cert, key, "plc", passwords["plc"])
            try:
                ns = await c.get_namespace_index(CELLCTL_NS)
                sm = ua.NodeId("cell1/BaseStateMachine", ns)
                res = await c.uaclient.call(
                    [ua.CallMethodRequest(ObjectId=sm, MethodId=ua.NodeId("cell1/BaseStateMachine/Reset", ns))]
                )
                assert res[0].StatusCode.is_good(), res[0].OutputArguments
                state = c.get_node(ua.NodeId("cell1/Status/StateCurrent", ns))
                for _ in range(200):
                    if await state.read_value() == 4:
                        break
                    await asyncio.sleep(0.05)
                assert await state.read_value() == 4
            finally:
                await c.disconnect()
            # a principal without the command grant may log in and read, not command
            op = await secure_client(url, cert, key, "operator", passwords["operator"])
            try:
                node = op.get_node(ua.NodeId("cell1/Command/CntrlCmd", ns))
                with pytest.raises(ua.UaStatusCodeError) as err:
                    await node.write_value(ua.Variant(3, ua.VariantType.Int32))
                assert err.value.code == ua.StatusCodes.BadUserAccessDenied
            finally:
                await op.disconnect()
            with pytest.raises(ua.UaStatusCodeError):
                await secure_client(url, cert, key, "plc", "not-the-password")

        asyncio.run(body())
    finally:
        gw.close()
        cell.close()


def test_config_rejects_unknown_keys_and_bad_values(tmp_path: Path) -> None:
    from cellctl.errors import ConfigError

    with pytest.raises(ConfigError, match="unknown key 'endpiont'"):
        load_gateway_config(None, ["endpiont=opc.tcp://127.0.0.1:4840"])
    with pytest.raises(ConfigError, match="expected opc.tcp://HOST:PORT"):
        load_gateway_config(None, ["endpoint=http://127.0.0.1:4840"])
    with pytest.raises(ConfigError, match="security"):
        load_gateway_config(None, ["security=[encrypt_only]"])
    f = tmp_path / "gw.yaml"
    f.write_text("endpoint: opc.tcp://127.0.0.1:4999\nallow_anonymous: no\n")
    with pytest.raises(ConfigError, match="allow_anonymous"):
        load_gateway_config(f)
    f.write_text("endpoint: opc.tcp://127.0.0.1:4999\ncells: [cell1, cell2]\n")
    g = load_gateway_config(f)
    assert g.port == 4999 and g.cells == ["cell1", "cell2"]
    assert load_gateway_config().endpoint == "opc.tcp://127.0.0.1:4840"


def test_secured_modes_need_the_certificate(tmp_path: Path) -> None:
    cfg = load_config(None, cfg_overrides(tmp_path, free_port()))
    gw_cfg = load_gateway_config(None, [f"endpoint=opc.tcp://127.0.0.1:{free_port()}", "security=[sign_encrypt]"])
    with pytest.raises(Exception, match="needs the server certificate"):
        OpcuaGateway(cfg, gw_cfg).start_thread()
