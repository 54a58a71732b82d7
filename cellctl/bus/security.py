"""Who may do what on the cell's bus: principals, the router's access-control list, secured deployments.

The daemon's router authenticates every link by user/password (``transport/auth/usrpwd``) and
filters every message of a remote face against an ACL with default deny. The supervisor lives
in the router's own session, which Zenoh never filters; everyone else is a client with its own
principal. The ACL is derived here from :mod:`cellctl.bus.keys`, so it cannot drift from the
wire contract. ``cellctl secure init`` writes a deployment folder::

    DIR/router.json5            usrpwd dictionary + access_control (+ TLS listen)
    DIR/passwords               user:password per line, mode 0600, router host only
    DIR/clients/<principal>.json5   one per principal: user/password (+ TLS connect), 0600
    DIR/tls/                    CA, router and per-principal certificates (--tls)
    DIR/bus.yaml                the ``bus:`` section that points a cell config at DIR
    DIR/opcua/server.pem|.key   the OPC UA gateway's application certificate (RSA, Basic256Sha256)

Paths inside the json5 files are relative to DIR and resolved when a session opens, so the
folder can be moved as a whole.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from cellctl.bus import keys
from cellctl.errors import ConfigError

__all__ = [
    "PRINCIPALS",
    "Principal",
    "access_control",
    "acl_hint",
    "apply_security",
    "init_deployment",
    "principal_table",
    "rotate_password",
]

ROUTER_FILE = "router.json5"
PASSWORDS_FILE = "passwords"
CLIENTS_DIR = "clients"
TLS_DIR = "tls"
BUS_YAML = "bus.yaml"

# Message kinds as the Zenoh ACL names them. Each must be allowed on both faces it crosses:
# a put is ingress on the publisher's face and egress on each subscriber's face, a query is
# ingress on the querier's and egress on the queryable's face, a reply the other way round.
# A publisher also needs subscriber declarations egress: a client drops puts nobody it knows
# of subscribes to (measured, docs/security.md "Findings").
_SUBSCRIBE_IN = ["declare_subscriber", "query"]
_SUBSCRIBE_OUT = ["put", "reply"]


@dataclass(frozen=True)
class Principal:
    """One identity on the bus and the grants (sets of ACL rules) it holds."""

    name: str
    grants: tuple[str, ...]
    description: str


PRINCIPALS: dict[str, Principal] = {
    p.name: p
    for p in (
        Principal("plc", ("observe", "command"), "the line PLC: sends PackML commands, reads everything"),
        Principal(
            "hmi",
            ("observe", "command", "robot-maintenance"),
            "the web HMI (cellctl hmi): commands and the robot's maintenance op for its logged-in users, reads "
            "everything; serves no worker key",
        ),
        Principal(
            "operator",
            ("observe", "robot-maintenance"),
            "people and the cellctl CLI: status, acks, results, events, liveliness; the robot's maintenance op",
        ),
        Principal("viewer", ("status",), "dashboards: the status key only"),
        Principal(
            "replay",
            ("replay", "watch-supervisor"),
            "cellctl replay: publishes only under replay/** (never a cell's keys, no command grant); may ask"
            " whether the cell's supervisor is alive",
        ),
        Principal(
            "engineer",
            ("observe", "maintain"),
            "commissioning tools (vision collect, sim scenarios): query worker ops directly, bypassing PackML",
        ),
        Principal("robot", ("status", "watch-supervisor", "serve:robot"), "the robot worker"),
        Principal(
            "camera",
            ("status", "watch-supervisor", "serve:camera", "sim-view"),
            "the camera worker (sim camera reads sim state)",
        ),
        Principal("classifier", ("status", "watch-supervisor", "serve:classifier"), "the classifier worker"),
        Principal("planner", ("status", "watch-supervisor", "serve:planner"), "the planner worker(s)"),
    )
}
"""Every principal ``cellctl secure init`` creates. Workers run as the principal named after their role."""


def _grant_rules(cell_id: str) -> dict[str, list[tuple[str, list[str], list[str]]]]:
    """Grant name → ``(flow, messages, key_exprs)`` triples for one cell."""
    c = cell_id
    observed = [
        keys.status(c),
        keys.cmd_ack(c),
        keys.result(c),
        keys.events(c),
        keys.robot_joints(c),
        keys.sim_state(c),
        keys.planner_job_progress(c),
        *(keys.worker_fault(c, role) for role in keys.ROLES),
    ]
    grants: dict[str, list[tuple[str, list[str], list[str]]]] = {
        "status": [("ingress", _SUBSCRIBE_IN, [keys.status(c)]), ("egress", _SUBSCRIBE_OUT, [keys.status(c)])],
        "observe": [
            ("ingress", _SUBSCRIBE_IN, observed),
            ("egress", _SUBSCRIBE_OUT, observed),
            ("ingress", ["declare_liveliness_subscriber", "liveliness_query"], [keys.alive_all(c)]),
            ("egress", ["liveliness_token", "reply"], [keys.alive_all(c)]),
        ],
        # Exactly the cmd key: cmd/** would let the PLC forge the supervisor's acks.
        "command": [
            ("ingress", ["put", "query"], [keys.cmd(c)]),
            ("egress", ["reply", "declare_subscriber"], [keys.cmd(c)]),
        ],
        # The robot stops its motion when the supervisor's token goes (workers/robot): a refused
        # liveliness subscriber would never see the token, nor its DELETE.
        "watch-supervisor": [
            ("ingress", ["declare_liveliness_subscriber", "liveliness_query"], [keys.alive(c, "supervisor")]),
            ("egress", ["liveliness_token", "reply"], [keys.alive(c, "supervisor")]),
        ],
        # Unlocking a protective stop, powering on, releasing brakes, clearing the latched fault: a
        # person who looked at the cause (UR: "inspect the cause before unlocking"), never the PLC's
        # program nor the supervisor, which could loop on it. Exactly this op, not robot/**.
        "robot-maintenance": [
            ("ingress", ["query"], [keys.robot_op(c, "maintenance")]),
            ("egress", ["reply"], [keys.robot_op(c, "maintenance")]),
        ],
        # A recorded log republished: under its own prefix only, so a replay can never drive a cell
        # (issue 32). Subscriber declarations egress: a client drops puts nobody it knows of subscribes to.
        "replay": [
            ("ingress", ["put"], [keys.replay_all()]),
            ("egress", ["declare_subscriber"], [keys.replay_all()]),
        ],
        "sim-view": [("ingress", ["query"], [keys.sim_state(c)]), ("egress", ["reply"], [keys.sim_state(c)])],
        "maintain": [
            ("ingress", ["query"], [*(keys.worker_all(c, r) for r in keys.ROLES), keys.sim_state(c)]),
            ("egress", ["reply"], [*(keys.worker_all(c, r) for r in keys.ROLES), keys.sim_state(c)]),
        ],
    }
    for role in keys.ROLES:
        own = [keys.worker_all(c, role)] + ([keys.sim_state(c)] if role == "robot" else [])
        grants[f"serve:{role}"] = [
            ("ingress", ["declare_queryable", "reply", "put"], own),
            ("egress", ["query", "declare_subscriber"], own),
            ("ingress", ["liveliness_token"], [keys.alive(c, role), keys.alive_instances(c, role)]),
        ]
    return grants


def access_control(cell_id: str, *, mtls: bool = False) -> dict[str, Any]:
    """The router's ``access_control`` section for ``cell_id``: default deny, one policy per principal.

    With ``mtls`` a subject must match both the username and the certificate's common name
    (Zenoh ANDs the properties of one subject), so a stolen password alone is not enough.
    """
    grants = _grant_rules(cell_id)
    rules = []
    for grant, triples in grants.items():
        for i, (flow, messages, key_exprs) in enumerate(triples):
            rules.append(
                {
                    "id": f"{grant}-{i}",
                    "permission": "allow",
                    "flows": [flow],
                    "messages": messages,
                    "key_exprs": key_exprs,
                }
            )
    subjects = []
    policies = []
    for p in PRINCIPALS.values():
        subject: dict[str, Any] = {"id": p.name, "usernames": [p.name]}
        if mtls:
            subject["cert_common_names"] = [p.name]
        subjects.append(subject)
        ids = [f"{g}-{i}" for g in p.grants for i in range(len(grants[g]))]
        policies.append({"id": p.name, "rules": ids, "subjects": [p.name]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def principal_table(acl: dict[str, Any]) -> str:
    """A markdown table of what each principal may do, read back from an ``access_control`` section."""
    rules = {r["id"]: r for r in acl["rules"]}
    lines = ["| principal | ingress (it may send/declare) | egress (it may receive) |", "|---|---|---|"]
    for pol in acl["policies"]:
        cells: dict[str, list[str]] = {"ingress": [], "egress": []}
        for rid in pol["rules"]:
            r = rules[rid]
            for flow in r["flows"]:
                cells[flow].append(f"{', '.join(r['messages'])} on `{'`, `'.join(r['key_exprs'])}`")
        lines.append(f"| `{pol['id']}` | {'<br>'.join(cells['ingress'])} | {'<br>'.join(cells['egress'])} |")
    return "\n".join(lines)


# --- loading a deployment into a session's config -------------------------------------------------

_PATH_KEYS = {
    "transport/auth/usrpwd": ("dictionary_file",),
    "transport/link/tls": (
        "root_ca_certificate",
        "listen_private_key",
        "listen_certificate",
        "connect_private_key",
        "connect_certificate",
    ),
}


def apply_security(conf: zenoh.Config, security_dir: Path, mode: str, principal: str | None) -> None:
    """Insert the auth, ACL and TLS sections of a deployment folder into ``conf``.

    The router (``mode == "router"``) loads ``router.json5``; a client loads its principal's
    ``clients/<principal>.json5``. Relative paths in those files are resolved against the folder.

    Raises:
        ConfigError: the folder or the principal's file is missing, the principal is unset, or
            the file does not parse.
    """
    if not security_dir.is_dir():
        raise ConfigError(
            f"bus.security_dir {str(security_dir)!r} is not a folder; create it with `cellctl secure init`"
        )
    if mode == "router":
        path = security_dir / ROUTER_FILE
    else:
        available = sorted(p.stem for p in (security_dir / CLIENTS_DIR).glob("*.json5"))
        if not principal:
            raise ConfigError(
                f"bus.principal is not set: the secured bus in {str(security_dir)!r} needs to know who this "
                f"process is (e.g. --set bus.principal=operator); expected one of {available}"
            )
        path = security_dir / CLIENTS_DIR / f"{principal}.json5"
        if not path.is_file():
            raise ConfigError(
                f"bus.principal {principal!r} has no credentials: {str(path)!r} does not exist; "
                f"expected one of {available}"
            )
    if not path.is_file():
        raise ConfigError(f"{str(path)!r} does not exist; create the folder with `cellctl secure init`")
    try:
        sec = zenoh.Config.from_file(str(path))
    except Exception as err:  # zenoh raises its own ZError for any parse problem
        raise ConfigError(f"{str(path)!r} cannot be loaded: {err}") from err
    for section in ("transport/auth/usrpwd", "transport/link/tls", "access_control"):
        value = json.loads(sec.get_json(section))
        for k in _PATH_KEYS.get(section, ()):
            if value.get(k) is not None and not Path(value[k]).is_absolute():
                value[k] = str(security_dir / value[k])
        conf.insert_json5(section, json.dumps(value))


def acl_hint(bus: object, key: str) -> str:
    """Why a secured bus may have answered nothing on ``key``: the ACL drops refused messages silently."""
    if getattr(bus, "security_dir", None) is None:
        return ""
    return f"; or the access-control list refuses {key!r} to principal {getattr(bus, 'principal', None)!r}"


# --- writing a deployment -------------------------------------------------------------------------


def _write(path: Path, text: str, mode: int) -> Path:
    """Write ``text`` with ``mode`` from the first byte (no window where a secret is world-readable)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.exists():
        path.unlink()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.chmod(path, mode)  # umask may have narrowed it
    return path


def _json5(header: str, body: dict[str, Any]) -> str:
    return f"// {header}\n// generated by `cellctl secure init`; re-run it rather than editing by hand.\n" + (
        json.dumps(body, indent=2) + "\n"
    )


def _client_body(principal: str, password: str, tls: bool, mtls: bool) -> dict[str, Any]:
    body: dict[str, Any] = {"transport": {"auth": {"usrpwd": {"user": principal, "password": password}}}}
    if tls:
        link: dict[str, Any] = {"root_ca_certificate": f"{TLS_DIR}/ca.pem"}
        if mtls:
            link |= {
                "enable_mtls": True,
                "connect_private_key": f"{TLS_DIR}/{principal}.key",
                "connect_certificate": f"{TLS_DIR}/{principal}.pem",
            }
        body["transport"]["link"] = {"tls": link}
    return body


def _openssl(*args: str, cwd: Path) -> None:
    exe = shutil.which("openssl")
    if exe is None:
        raise ConfigError("--tls needs the `openssl` command line tool, which is not on PATH")
    proc = subprocess.run([exe, *args], cwd=cwd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise ConfigError(f"openssl {args[0]} failed ({proc.returncode}): {proc.stderr.strip()[-400:]}")


def _make_pki(tls_dir: Path, host: str, principals: list[str], days: int) -> list[Path]:
    """A private CA, a router certificate for ``host`` and one client certificate per principal."""
    tls_dir.mkdir(parents=True, exist_ok=True)
    ec = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes")
    _openssl("req", "-x509", *ec, "-keyout", "ca.key", "-out", "ca.pem", "-days", str(days),
             "-subj", "/CN=cellctl cell CA", "-addext", "basicConstraints=critical,CA:TRUE",
             "-addext", "keyUsage=critical,keyCertSign,cRLSign", cwd=tls_dir)  # fmt: skip
    san = f"IP:{host}" if host.replace(".", "").isdigit() or ":" in host else f"DNS:{host}"
    written = [tls_dir / "ca.pem", tls_dir / "ca.key"]
    for name, usage in [("router", "serverAuth"), *((p, "clientAuth") for p in principals)]:
        ext = tls_dir / f"{name}.ext"
        alt = f"subjectAltName={san}\n" if name == "router" else ""
        ext.write_text(f"{alt}basicConstraints=CA:FALSE\nkeyUsage=digitalSignature\nextendedKeyUsage={usage}\n")
        _openssl("req", *ec, "-keyout", f"{name}.key", "-out", f"{name}.csr", "-subj", f"/CN={name}", cwd=tls_dir)
        _openssl("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
                 "-out", f"{name}.pem", "-days", str(days), "-extfile", ext.name, cwd=tls_dir)  # fmt: skip
        (tls_dir / f"{name}.csr").unlink()
        ext.unlink()
        written += [tls_dir / f"{name}.pem", tls_dir / f"{name}.key"]
    (tls_dir / "ca.srl").unlink(missing_ok=True)
    for p in written:
        os.chmod(p, 0o600 if p.suffix == ".key" else 0o644)
    return written


def init_deployment(
    out: Path,
    cell_id: str = "cell1",
    *,
    endpoint: str = "127.0.0.1:7447",
    tls: bool = False,
    mtls: bool = False,
    days: int = 825,
    force: bool = False,
) -> list[Path]:
    """Write a secured deployment folder (see the module docstring) and return the files written.

    Passwords come from :mod:`secrets` and are deliberately not seeded: a reproducible password
    is a published one.

    Raises:
        ConfigError: ``out`` already holds a deployment and ``force`` is false, the cell id or
            endpoint is invalid, or openssl fails.
    """
    keys.check_cell_id(cell_id)
    host, sep, port = endpoint.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ConfigError(f"endpoint {endpoint!r} is invalid: expected HOST:PORT, e.g. 127.0.0.1:7447")
    tls = tls or mtls
    if (out / ROUTER_FILE).exists() and not force:
        raise ConfigError(f"{str(out)!r} already holds a deployment; pass --force to replace every secret in it")
    out.mkdir(parents=True, exist_ok=True)
    os.chmod(out, 0o700)
    names = list(PRINCIPALS)
    passwords = {p: secrets.token_urlsafe(24) for p in names}
    written: list[Path] = []
    if tls:
        written += _make_pki(out / TLS_DIR, host, names, days)
    written.append(_write(out / PASSWORDS_FILE, "".join(f"{p}:{pw}\n" for p, pw in passwords.items()), 0o600))
    router: dict[str, Any] = {
        "transport": {"auth": {"usrpwd": {"dictionary_file": PASSWORDS_FILE}}},
        "access_control": access_control(cell_id, mtls=mtls),
    }
    if tls:
        router["transport"]["link"] = {
            "tls": {
                "root_ca_certificate": f"{TLS_DIR}/ca.pem",
                "listen_private_key": f"{TLS_DIR}/router.key",
                "listen_certificate": f"{TLS_DIR}/router.pem",
                "enable_mtls": mtls,
            }
        }
    written.append(_write(out / ROUTER_FILE, _json5(f"router of cell {cell_id}", router), 0o644))
    for p in names:
        body = _client_body(p, passwords[p], tls, mtls)
        written.append(
            _write(out / CLIENTS_DIR / f"{p}.json5", _json5(f"principal {p} of cell {cell_id}", body), 0o600)
        )
    os.chmod(out / CLIENTS_DIR, 0o700)
    written.append(_write(out / BUS_YAML, bus_yaml(out, cell_id, endpoint, tls), 0o644))
    # The OPC UA gateway's server certificate, for Basic256Sha256 Sign&Encrypt (docs/opcua.md).
    from cellctl.bus.opcua_cert import OPCUA_DIR, write_server_certificate

    written += write_server_certificate(out / OPCUA_DIR, host, days)
    return written


def bus_yaml(out: Path, cell_id: str, endpoint: str, tls: bool) -> str:
    """The cell-config lines that select a deployment folder (``cell:`` and ``bus:`` sections)."""
    ep = json.dumps([f"{'tls' if tls else 'tcp'}/{endpoint}"])
    return (
        "# Merge into the cell config (or pass each as --set KEY=VALUE). Workers always run as the\n"
        "# principal named after their role; CLI tools use bus.principal (`--set bus.principal=plc` to command).\n"
        f"cell:\n  id: {cell_id}\n"
        f"bus:\n  security_dir: {out.resolve()}\n  principal: operator\n  listen: {ep}\n  connect: {ep}\n"
    )


def bus_overrides(out: Path, endpoint: str, tls: bool) -> list[str]:
    """The same selection as ``--set`` strings (what tests and scripts pass to ``load_config``)."""
    ep = json.dumps([f"{'tls' if tls else 'tcp'}/{endpoint}"])
    return [f"bus.security_dir={out.resolve()}", f"bus.listen={ep}", f"bus.connect={ep}"]


def rotate_password(out: Path, principal: str) -> list[Path]:
    """Give ``principal`` a fresh random password in the dictionary and its client file.

    The router reads the dictionary only at start, so the daemon must be restarted; until
    then the old password stays valid.

    Raises:
        ConfigError: ``out`` is not a deployment or the principal is not in it.
    """
    dictionary = out / PASSWORDS_FILE
    client = out / CLIENTS_DIR / f"{principal}.json5"
    if not dictionary.is_file():
        raise ConfigError(f"{str(dictionary)!r} does not exist; is {str(out)!r} a `cellctl secure init` folder?")
    entries = dict(line.split(":", 1) for line in dictionary.read_text().splitlines() if ":" in line)
    if principal not in entries or not client.is_file():
        raise ConfigError(f"principal {principal!r} is not in {str(out)!r}; expected one of {sorted(entries)}")
    entries[principal] = secrets.token_urlsafe(24)
    sec = zenoh.Config.from_file(str(client))
    tls = json.loads(sec.get_json("transport/link/tls"))
    body: dict[str, Any] = {"transport": {"auth": {"usrpwd": {"user": principal, "password": entries[principal]}}}}
    tls = {k: v for k, v in tls.items() if v is not None}
    if tls:
        body["transport"]["link"] = {"tls": tls}
    header = client.read_text().splitlines()[0].removeprefix("// ")
    return [
        _write(dictionary, "".join(f"{p}:{pw}\n" for p, pw in entries.items()), 0o600),
        _write(client, _json5(header, body), 0o600),
    ]
