"""``cellctl gateway opcua``: an asyncua server speaking PackML (OPC 30050 + PackTags) to PLCs, Zenoh to the cell.

One asyncio loop serves OPC UA; Zenoh samples reach it through ``call_soon_threadsafe`` (Zenoh
callbacks never block), commands leave it through a small thread pool (a query blocks for the
Ack). Requests of one cell are serialised, so each accepted request is exactly one Command on
the bus and the handshake tags always describe the request that was just handled.

Who may do what: anonymous sessions (and bus principals without the command grant) may browse,
read and subscribe; writes and method calls need a user that may command. asyncua decides by
role per service (:class:`_Permissions`); the gateway checks every written value itself
(:class:`_GatewayAttributes`) because asyncua checks only the variant type.
"""

from __future__ import annotations

import asyncio
import contextvars
import datetime as _dt
import logging
import secrets
import threading
import time
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from asyncua import Server, ua
from asyncua.crypto.permission_rules import USER_TYPES, PermissionRuleset, User, UserRole
from asyncua.server.address_space import AttributeService
from asyncua.server.user_managers import UserManager
from pydantic import ValidationError

from cellctl.bus import keys
from cellctl.bus.codec import decode_as
from cellctl.bus.opcua_cert import APPLICATION_URI
from cellctl.bus.plc_client import CellLink, RequestIds
from cellctl.bus.security import PASSWORDS_FILE, PRINCIPALS
from cellctl.config import CellConfig
from cellctl.errors import CellError, ConfigError, ProtocolError, WorkerTimeout, WorkerUnavailable
from cellctl.gateway.opcua.config import OpcuaConfig
from cellctl.gateway.opcua.space import (
    BASE_PARKED_METHOD,
    CELLCTL_NS,
    METHODS,
    PACKML_NS,
    VARIABLES,
    CellSpace,
    build_cell_space,
    last_cycle_values,
)
from cellctl.login_throttle import LoginThrottle
from cellctl.messages import (
    Ack,
    Command,
    CycleResult,
    Event,
    LastCycle,
    PackMLCommand,
    Status,
    UnitMode,
    now_iso,
)
from cellctl.supervisor.definition import PackMLState
from cellctl.surface import SURFACES

__all__ = ["APPLICATION_URI", "OpcuaGateway", "read_users"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

S = ua.StatusCodes
_WRITE = ua.NodeId(ua.ObjectIds.WriteRequest_Encoding_DefaultBinary)
_CALL = ua.NodeId(ua.ObjectIds.CallRequest_Encoding_DefaultBinary)
_READ_ONLY = frozenset(ua.NodeId(t) for t in USER_TYPES) - {_WRITE, _CALL}

_CALLER: contextvars.ContextVar[User | None] = contextvars.ContextVar("opcua_caller", default=None)
"""The user of the request being served: asyncua hands method callbacks no session, but it runs
the permission check and the call in the same task, so the check leaves the user here."""

_PARAM_VALUES = {
    "Command/Parameter/Mode": ("", "evaluate", "collect"),
    "Command/Parameter/Surface": ("", *SURFACES),
    "Command/Parameter/Label": ("", "clean", "dirty"),
}
_SPEC = {v.path: v for v in VARIABLES}
_POLICIES = {
    "none": ua.SecurityPolicyType.NoSecurity,
    "sign": ua.SecurityPolicyType.Basic256Sha256_Sign,
    "sign_encrypt": ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
}


def _cmd_list() -> str:
    return ", ".join(f"{c.value} {c.name.capitalize()}" for c in PackMLCommand)


def _mode_list() -> str:
    return ", ".join(f"{m.value} {m.name.capitalize()}" for m in UnitMode)


class _Permissions(PermissionRuleset):
    """Write and Call for users that may command (role User); the read-only services for everyone else."""

    def check_validity(self, user: User, action_type_id: ua.NodeId, body: Any) -> bool:
        _CALLER.set(user)
        if action_type_id in (_WRITE, _CALL):
            return user is not None and user.role == UserRole.User
        return action_type_id in _READ_ONLY


def read_users(path: Path) -> dict[str, str]:
    """``user:password`` lines (the Zenoh dictionary format) → {user: password}.

    Raises:
        ConfigError: the file is missing or a line is not ``user:password``.
    """
    if not path.is_file():
        raise ConfigError(f"users file {str(path)!r} does not exist; expected lines of user:password")
    users: dict[str, str] = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        name, sep, pw = line.partition(":")
        if not sep or not name or not pw:
            raise ConfigError(f"{path}:{n}: expected user:password, got a line of {len(line)} characters")
        users[name] = pw
    return users


_PEER: contextvars.ContextVar[str] = contextvars.ContextVar("opcua_peer", default="?")
"""The client address of the session being activated: asyncua hands ``get_user`` no session, but
calls it synchronously inside ``activate_session``, which :func:`_tag_peer` wraps to set this."""


def _tag_peer(iserver: Any) -> None:
    """Make each new session's ``activate_session`` publish its client address in :data:`_PEER`."""
    create = iserver.create_session

    def create_session(name: Any, *args: Any, **kwargs: Any) -> Any:
        session = create(name, *args, **kwargs)
        activate = session.activate_session
        host = str(name[0]) if isinstance(name, tuple) and name else str(name)

        def activate_session(*a: Any, **kw: Any) -> Any:
            token = _PEER.set(host)
            try:
                return activate(*a, **kw)
            finally:
                _PEER.reset(token)

        session.activate_session = activate_session
        return session

    iserver.create_session = create_session


class _QuietRefusals(logging.Filter):
    """Drops asyncua's per-try ERROR line for a refused login (the throttle logs those, bounded)."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not (str(record.msg).startswith("sending service fault") and "BadUserAccessDenied" in str(record.args))


class _Users(UserManager):
    """Username/password sessions: commanders get role User, readers and anonymous role Anonymous.

    Wrong passwords are throttled per (user, client address) and per address (:mod:`cellctl.login_throttle`);
    a try during a back-off is refused without checking the password.
    """

    def __init__(
        self, commanders: dict[str, str], readers: dict[str, str], allow_anonymous: bool, throttle: LoginThrottle
    ) -> None:
        self.commanders = commanders
        self.readers = readers
        self.allow_anonymous = allow_anonymous
        self.throttle = throttle

    def get_user(self, iserver: Any, username: str | None = None, password: Any = None, certificate: Any = None):
        if username is None:
            # ``certificate`` is the secure channel's client certificate, not an identity: ignored
            return User(role=UserRole.Anonymous) if self.allow_anonymous else None
        address = _PEER.get()
        if self.throttle.retry_after(username, address) > 0:
            return None  # backing off: refused unchecked, not logged (the throttle's lines summarise)
        pw = password.decode("utf-8", "replace") if isinstance(password, bytes) else str(password or "")
        for table, role in ((self.commanders, UserRole.User), (self.readers, UserRole.Anonymous)):
            known = table.get(username)
            if known is not None and secrets.compare_digest(known.encode(), pw.encode()):
                self.throttle.succeeded(username, address)
                return User(role=role, name=username)
        log.debug("OPC UA session refused: unknown user or wrong password for %r from %s", username[:64], address)
        self.throttle.failed(username, address)
        return None  # asyncua answers BadUserAccessDenied


_QUIET_REFUSALS = _QuietRefusals()
"""One instance, so that starting several gateways in a process adds the filter once."""

_INTERNAL = User(role=UserRole.Admin)
"""The server's own session (asyncua's default user of an internal write)."""

WriteHook = Callable[[ua.WriteValue, User, Callable[[], Awaitable[ua.StatusCode]]], Awaitable[ua.StatusCode]]


class _GatewayAttributes(AttributeService):
    """asyncua's attribute service with a check of its own for the writable nodes.

    A hook sees the written value and the user and decides; ``store()`` performs the ordinary
    write (access level and variant type checks included).
    """

    def __init__(self, aspace: Any, hooks: dict[ua.NodeId, WriteHook]) -> None:
        super().__init__(aspace)
        self._hooks = hooks

    async def write(self, params: ua.WriteParameters, user: User = _INTERNAL) -> list[ua.StatusCode]:
        results: list[ua.StatusCode] = []
        for wv in params.NodesToWrite:
            hook = self._hooks.get(wv.NodeId)
            if hook is None or wv.AttributeId != ua.AttributeIds.Value or user.role == UserRole.Admin:
                results.extend(await super().write(ua.WriteParameters(NodesToWrite=[wv]), user))
                continue

            async def store(wv: ua.WriteValue = wv) -> ua.StatusCode:
                return (await super(_GatewayAttributes, self).write(ua.WriteParameters(NodesToWrite=[wv]), user))[0]

            try:
                results.append(await hook(wv, user, store))
            except Exception:  # a bug in one hook must answer Bad, not kill the client's session
                log.exception("write hook failed on %s", wv.NodeId)
                results.append(ua.StatusCode(S.BadInternalError))
        return results


def _scalar(wv: ua.WriteValue, vtype: ua.VariantType) -> tuple[Any, ua.StatusCode | None]:
    """The written scalar of ``vtype``, or the Bad status that refuses it."""
    if wv.IndexRange:
        return None, ua.StatusCode(S.BadIndexRangeInvalid)
    dv = wv.Value
    if dv is None or dv.Value is None or (dv.StatusCode is not None and not dv.StatusCode.is_good()):
        return None, ua.StatusCode(S.BadTypeMismatch)
    var = dv.Value
    if var.VariantType != vtype or var.is_array or isinstance(var.Value, list):
        return None, ua.StatusCode(S.BadTypeMismatch)
    return var.Value, None


def _file_format(path: Path) -> str:
    with open(path, "rb") as f:
        return "pem" if f.read(11) == b"-----BEGIN " else "der"


def _stamp(iso: str | None) -> _dt.datetime:
    if iso:
        try:
            t = _dt.datetime.fromisoformat(iso)
            return t if t.tzinfo is not None else t.replace(tzinfo=_dt.UTC)
        except ValueError:
            pass
    return _dt.datetime.now(_dt.UTC)


class OpcuaGateway:
    """The OPC UA server and its Zenoh link.

    Args:
        cell_cfg: the cell config (bus endpoints and security, the default cell id).
        cfg: the gateway config.

    ``await serve(stop)`` runs until ``stop`` is set; :meth:`start_thread` runs it in a thread
    (tests and benches). :attr:`commands_sent` counts the Commands put on the bus.
    """

    def __init__(self, cell_cfg: CellConfig, cfg: OpcuaConfig, clock: Callable[[], float] = time.monotonic) -> None:
        self.cfg = cfg
        self.throttle = LoginThrottle(cfg.login, "OPC UA", clock)
        self.cells = list(cfg.cells) or [cell_cfg.cell_id]
        bus = cell_cfg.bus
        if bus.security_dir is not None and bus.principal != cfg.principal:
            cell_cfg = cell_cfg.model_copy(update={"bus": bus.model_copy(update={"principal": cfg.principal})})
        self.cell_cfg = cell_cfg
        self.commands_sent = 0
        self.ready = threading.Event()
        self.error: BaseException | None = None
        self._spaces: dict[str, CellSpace] = {}
        self._values: dict[ua.NodeId, Any] = {}
        self._last_status: dict[str, float] = {}
        self._down: dict[str, str | None] = {}
        self._link_reason: str | None = "connecting to the cell bus"
        self._locks: dict[str, asyncio.Lock] = {}
        # request ids unique across this gateway's restarts: the daemon refuses an id it acted on (600 s window)
        self._ids = RequestIds("opcua")
        self._pool = ThreadPoolExecutor(max_workers=4, thread_name_prefix="opcua-cmd")
        self._loop: asyncio.AbstractEventLoop | None = None
        self._inbox: asyncio.Queue[tuple[str, str, Any]] | None = None
        self._thread: threading.Thread | None = None
        self._stop_async: asyncio.Event | None = None
        self.server: Server | None = None

    # --- users and security ----------------------------------------------------------------

    def _users(self) -> _Users:
        commanders: dict[str, str] = {}
        readers: dict[str, str] = {}
        sec = self.cell_cfg.bus.security_dir
        if self.cfg.bus_principals and sec is not None:
            path = self.cell_cfg.path(sec) / PASSWORDS_FILE
            if path.is_file():
                for name, pw in read_users(path).items():
                    grants = PRINCIPALS[name].grants if name in PRINCIPALS else ()
                    (commanders if "command" in grants else readers)[name] = pw
        if self.cfg.users_file is not None:
            commanders.update(read_users(self.cell_cfg.path(self.cfg.users_file)))
        return _Users(commanders, readers, self.cfg.allow_anonymous, self.throttle)

    def _cert_paths(self) -> tuple[Path | None, Path | None]:
        sec = self.cell_cfg.bus.security_dir
        base = self.cell_cfg.path(sec) / "opcua" if sec is not None else None
        cert = self.cfg.certificate or (base / "server.pem" if base is not None else None)
        key = self.cfg.private_key or (base / "server.key" if base is not None else None)
        cert = self.cell_cfg.path(cert) if cert is not None else None
        key = self.cell_cfg.path(key) if key is not None else None
        return cert, key

    async def _make_server(self) -> Server:
        server = Server(user_manager=self._users())
        await server.init()
        _tag_peer(server.iserver)
        logging.getLogger("asyncua.server.uaprocessor").addFilter(_QUIET_REFUSALS)
        server.set_endpoint(self.cfg.endpoint)
        server.set_server_name("cellctl OPC UA PackML gateway")
        await server.set_application_uri(APPLICATION_URI)
        server.product_uri = "urn:cellctl"
        secured = [m for m in self.cfg.security if m != "none"]
        cert, key = self._cert_paths()
        if cert is not None and key is not None and cert.is_file() and key.is_file():
            # by content, not by name: a PEM key is often called .key
            await server.load_certificate(str(cert), _file_format(cert))
            await server.load_private_key(str(key), None, _file_format(key))
        elif secured:
            raise ConfigError(
                f"security {secured} needs the server certificate and key; {str(cert)!r}/{str(key)!r} do not exist "
                "(run `cellctl secure init`, or set certificate/private_key in the gateway config)"
            )
        if self.cfg.trusted_clients is not None:
            from asyncua.crypto.truststore import TrustStore
            from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions

            store = TrustStore([self.cell_cfg.path(self.cfg.trusted_clients)], [])
            await store.load()
            opts = CertificateValidatorOptions.TRUSTED_VALIDATION | CertificateValidatorOptions.PEER_CLIENT
            server.set_certificate_validator(CertificateValidator(opts, store).validate)
        server.set_security_policy([_POLICIES[m] for m in self.cfg.security], permission_ruleset=_Permissions())
        tokens: list[type] = [ua.UserNameIdentityToken]
        if self.cfg.allow_anonymous:
            tokens.insert(0, ua.AnonymousIdentityToken)
        server.set_identity_tokens(tokens)
        self._pk = await server.register_namespace(PACKML_NS)
        self._cc = await server.register_namespace(CELLCTL_NS)
        for cell in self.cells:
            self._spaces[cell] = await build_cell_space(
                server, cell, self._pk, self._cc, self._method, self._set_unit_mode_method, self._base_parked_method
            )
            self._locks[cell] = asyncio.Lock()
        hooks: dict[ua.NodeId, WriteHook] = {}
        for cell, space in self._spaces.items():
            for path in ("Command/CntrlCmd", "Command/UnitMode", *_PARAM_VALUES):
                hooks[space.nodeid(path)] = self._value_hook(path)
            hooks[space.nodeid("Command/CmdChangeRequest")] = self._request_hook(cell, "Command/CmdChangeRequest")
            hooks[space.nodeid("Command/UnitModeChangeRequest")] = self._request_hook(
                cell, "Command/UnitModeChangeRequest"
            )
        server.iserver.attribute_service = _GatewayAttributes(server.iserver.aspace, hooks)
        return server

    # --- node values -----------------------------------------------------------------------

    async def _set(self, cell: str, path: str, value: Any, ts: _dt.datetime | None = None) -> None:
        space = self._spaces[cell]
        nodeid = space.nodeid(path)
        if self._values.get(nodeid, ...) == value:
            return
        self._values[nodeid] = value
        if path == "BaseStateMachine/CurrentState":
            variant = ua.Variant(ua.LocalizedText(value), ua.VariantType.LocalizedText)
        else:
            spec = _SPEC[path]
            variant = ua.Variant(value, spec.vtype, is_array=isinstance(spec.initial, list))
        now = _dt.datetime.now(_dt.UTC)
        dv = ua.DataValue(variant, SourceTimestamp=ts or now, ServerTimestamp=now)
        assert self.server is not None
        await self.server.write_attribute_value(nodeid, dv)

    def _get(self, cell: str, path: str) -> Any:
        return self._values.get(self._spaces[cell].nodeid(path), _SPEC[path].initial)

    async def _apply_status(self, cell: str, st: Status) -> None:
        ts = _stamp(st.stamp)
        acting = st.state.endswith("ing") or st.state == "Execute"
        admin = st.admin
        last = admin.last_cycle
        values: list[tuple[str, Any]] = [
            ("Status/StateCurrent", st.state_code),
            ("Status/StateName", st.state),
            ("BaseStateMachine/CurrentState", st.state),
            ("Status/StateChangeInProcess", acting),
            ("Status/UnitModeCurrent", st.unit_mode_code),
            ("Status/Step", st.step or ""),
            ("Status/CycleId", st.cycle_id or ""),
            ("Status/AvailableCommands", list(st.available_commands)),
            ("Status/DaemonConnected", True),
            ("Status/UnavailableReason", ""),
            ("Admin/ProdProcessedCount", min(admin.prod_processed_count, 2**31 - 1)),
            ("Admin/ProdDefectiveCount", min(admin.prod_defective_count, 2**31 - 1)),
            ("Admin/StopReason", admin.stop_reason or ""),
            ("Admin/Warning", list(admin.warnings)),
            ("Admin/LastError", st.last_error or ""),
            *((f"Admin/Workers/{r}", bool(st.workers.get(r, False))) for r in keys.ROLES),
        ]
        if last is not None:
            values += last_cycle_values(last)
        for path, v in values:
            await self._set(cell, path, v, ts)
        if self._down.get(cell):
            log.warning("cell %s: daemon back (state %s)", cell, st.state)
        self._down[cell] = None

    async def _apply_result(self, cell: str, res: CycleResult) -> None:
        ts = _stamp(res.finished)
        for path, v in last_cycle_values(LastCycle.of(res)):
            await self._set(cell, path, v, ts)

    async def _mark_down(self, cell: str, reason: str) -> None:
        if self._down.get(cell) == reason:
            return
        if not self._down.get(cell):
            log.warning("cell %s: StateCurrent 0 (Undefined): %s", cell, reason)
        self._down[cell] = reason
        for path, v in (
            ("Status/StateCurrent", int(PackMLState.Undefined)),
            ("Status/StateName", "Undefined"),
            ("BaseStateMachine/CurrentState", "Undefined"),
            ("Status/StateChangeInProcess", False),
            ("Status/UnitModeCurrent", 0),
            ("Status/AvailableCommands", []),
            ("Status/DaemonConnected", False),
            ("Status/UnavailableReason", reason),
        ):
            await self._set(cell, path, v)

    # --- Zenoh samples -----------------------------------------------------------------------

    def _sink(self, kind: str, cell: str, data: Any) -> None:
        loop, inbox = self._loop, self._inbox
        if loop is None or inbox is None or loop.is_closed():
            return
        try:
            loop.call_soon_threadsafe(inbox.put_nowait, (kind, cell, data))
        except RuntimeError:  # the loop closed between the check and the call
            pass

    async def _handle(self, kind: str, cell: str, data: Any) -> None:
        loop = asyncio.get_running_loop()
        if kind == "link":
            self._link_reason = data
            if data is not None:
                for c in self.cells:
                    await self._mark_down(c, data)
            return
        if cell not in self._spaces:
            return
        try:
            if kind == "status":
                st = decode_as(Status, data)
                if st.cell != cell:
                    return
                self._last_status[cell] = loop.time()
                await self._apply_status(cell, st)
            elif kind == "result":
                await self._apply_result(cell, decode_as(CycleResult, data))
            elif kind == "event":
                decode_as(Event, data)  # checked; Events are the daemon's log, not PackTags
            elif kind == "alive" and data is False:
                self._last_status.pop(cell, None)
                await self._mark_down(
                    cell, f"the daemon's liveliness token {keys.alive(cell, 'supervisor')!r} is gone (daemon down?)"
                )
        except ProtocolError as err:
            log.warning("cell %s: ignoring an undecodable %s: %s", cell, kind, err)

    async def _watchdog(self) -> None:
        loop = asyncio.get_running_loop()
        started = loop.time()
        while True:
            await asyncio.sleep(min(0.5, self.cfg.stale_after_s / 2))
            counters = self.throttle.counters
            for cell in self.cells:  # the gateway's login counters, on every cell's Admin node
                await self._set(cell, "Admin/LoginFailures", min(counters.failures, 2**32 - 1))
                await self._set(cell, "Admin/LoginsThrottled", min(counters.throttled, 2**32 - 1))
            for cell in self.cells:
                if self._link_reason is not None:
                    await self._mark_down(cell, self._link_reason)
                    continue
                seen = self._last_status.get(cell, started)
                if loop.time() - seen > self.cfg.stale_after_s:
                    raw = await loop.run_in_executor(self._pool, self._link_query, cell)
                    if raw is not None:
                        await self._handle("status", cell, raw)
                    else:
                        await self._mark_down(
                            cell,
                            f"no Status from the daemon on {keys.status(cell)!r} for more than "
                            f"{self.cfg.stale_after_s:g} s (daemon down?)",
                        )

    def _link_query(self, cell: str) -> bytes | None:
        return self._link.query_status(cell, timeout=min(1.0, self.cfg.stale_after_s))

    # --- commands ----------------------------------------------------------------------------

    async def _send(self, cell: str, user: User | None, **fields: Any) -> tuple[ua.StatusCode, str]:
        """Build, send and record one Command (the cell's lock is held by the caller)."""
        name = user.name if user is not None and user.name else "anonymous"
        params: dict[str, Any] = {}
        if fields.get("cntrl_cmd") == PackMLCommand.start:
            for path in _PARAM_VALUES:
                value = self._get(cell, path)
                if value:
                    params[path.rsplit("/", 1)[1].lower()] = value
        try:
            rid = self._ids.next()
            # stamped on the gateway's clock: the supervisor refuses a stale or replayed copy (replay_guard)
            cmd = Command(request_id=rid, user=f"opcua:{name}"[:64], params=params, stamp=now_iso(), **fields)
        except ValidationError as err:
            return await self._outcome(cell, None, S.BadInvalidArgument, f"invalid command: {err.errors()[0]['msg']}")
        self.commands_sent += 1
        loop = asyncio.get_running_loop()
        answer: asyncio.Future[Ack | CellError] = loop.create_future()

        def settle(res: Ack | CellError) -> None:
            if not answer.done():
                answer.set_result(res)

        try:
            self._link.send_async(
                cell, cmd, self.cfg.command_timeout_s, lambda res: loop.call_soon_threadsafe(settle, res)
            )
            res = await answer
            if isinstance(res, CellError):
                raise res
            ack = res
        except WorkerUnavailable as err:
            return await self._outcome(cell, None, S.BadCommunicationError, str(err))
        except WorkerTimeout as err:
            return await self._outcome(cell, None, S.BadTimeout, str(err))
        except CellError as err:
            return await self._outcome(cell, None, S.BadUnexpectedError, str(err))
        except Exception as err:  # a session closing under the query: the request failed, the gateway serves on
            log.exception("cell %s: command %s failed on the bus", cell, cmd.request_id)
            return await self._outcome(cell, None, S.BadCommunicationError, f"the bus failed the command: {err}")
        if ack.accepted:
            return await self._outcome(cell, ack.state, S.Good, "")
        reason = ack.reason or "refused by the daemon"
        code = S.BadInvalidState if "not allowed" in reason else S.BadInvalidArgument
        return await self._outcome(cell, None, code, reason)

    async def _outcome(self, cell: str, state: str | None, code: int, reason: str) -> tuple[ua.StatusCode, str]:
        await self._set(cell, "Status/CmdAccepted", code == S.Good)
        await self._set(cell, "Status/CmdRejectReason", reason)
        if state is not None and state in PackMLState.__members__:
            await self._set(cell, "Status/StateRequested", int(PackMLState[state]))
        if code != S.Good:
            log.info("cell %s: command refused (%s): %s", cell, ua.StatusCode(code).name, reason)
        return ua.StatusCode(code), reason

    @staticmethod
    def _result(status: ua.StatusCode, reason: str) -> ua.CallMethodResult:
        return ua.CallMethodResult(StatusCode=status, OutputArguments=[ua.Variant(reason, ua.VariantType.String)])

    def _method(self, cell: str, name: str) -> Callable[..., Awaitable[ua.CallMethodResult]]:
        command = METHODS[name]

        async def call(parent: ua.NodeId, *args: ua.Variant) -> ua.CallMethodResult:
            if parent != self._spaces[cell].state_machine.nodeid:
                return self._result(ua.StatusCode(S.BadMethodInvalid), f"{name} is a method of {cell}/BaseStateMachine")
            if args:
                return self._result(ua.StatusCode(S.BadTooManyArguments), f"{name} takes no arguments, got {len(args)}")
            async with self._locks[cell]:
                return self._result(*await self._send(cell, _CALLER.get(), cntrl_cmd=int(command)))

        return call

    def _one_int32(self, cell: str, name: str, parent: ua.NodeId, args: tuple[Any, ...], what: str) -> Any:
        """The single Int32 argument of method ``name`` on the cell object, or the refusing result."""
        if parent != self._spaces[cell].obj.nodeid:
            return self._result(ua.StatusCode(S.BadMethodInvalid), f"{name} is a method of {cell}")
        if len(args) != 1:
            code = S.BadArgumentsMissing if not args else S.BadTooManyArguments
            return self._result(ua.StatusCode(code), f"{name} takes one Int32 ({what})")
        arg = args[0]
        if not isinstance(arg, ua.Variant) or arg.VariantType != ua.VariantType.Int32 or arg.is_array:
            return self._result(ua.StatusCode(S.BadTypeMismatch), f"{name} takes an Int32 ({what})")
        return int(arg.Value)

    def _set_unit_mode_method(self, cell: str) -> Callable[..., Awaitable[ua.CallMethodResult]]:
        async def call(parent: ua.NodeId, *args: ua.Variant) -> ua.CallMethodResult:
            value = self._one_int32(cell, "SetUnitMode", parent, args, _mode_list())
            if not isinstance(value, int):
                return value
            if value not in {m.value for m in UnitMode}:
                return self._result(
                    ua.StatusCode(S.BadOutOfRange), f"unit mode {value} is unknown; expected one of {_mode_list()}"
                )
            async with self._locks[cell]:
                return self._result(*await self._send(cell, _CALLER.get(), unit_mode_code=value))

        return call

    def _base_parked_method(self, cell: str) -> Callable[..., Awaitable[ua.CallMethodResult]]:
        """``ConfirmBaseParked(Station)``: the ``base_parked`` Command; the daemon refuses it (Reason)
        unless the cycle waits for the base at that station."""

        async def call(parent: ua.NodeId, *args: ua.Variant) -> ua.CallMethodResult:
            value = self._one_int32(cell, BASE_PARKED_METHOD, parent, args, "the station, >= 0")
            if not isinstance(value, int):
                return value
            if value < 0:
                return self._result(ua.StatusCode(S.BadOutOfRange), f"station {value} is negative; expected >= 0")
            async with self._locks[cell]:
                return self._result(*await self._send(cell, _CALLER.get(), base_parked=value))

        return call

    def _value_hook(self, path: str) -> WriteHook:
        """CntrlCmd, UnitMode and the Start params: stored only when of their type and among their values."""
        vtype: ua.VariantType
        if path == "Command/CntrlCmd":
            vtype, allowed, what = ua.VariantType.Int32, {c.value for c in PackMLCommand}, _cmd_list()
        elif path == "Command/UnitMode":
            vtype, allowed, what = ua.VariantType.Int32, {m.value for m in UnitMode}, _mode_list()
        else:
            vtype, allowed = ua.VariantType.String, set(_PARAM_VALUES[path])
            what = ", ".join(repr(v) for v in _PARAM_VALUES[path])

        async def hook(wv: ua.WriteValue, user: User, store: Callable[[], Awaitable[ua.StatusCode]]) -> ua.StatusCode:
            value, bad = _scalar(wv, vtype)
            if bad is not None:
                return bad
            if value not in allowed:
                log.info("refused %s = %.80r: expected one of %s", path, value, what)
                return ua.StatusCode(S.BadOutOfRange)
            status = await store()
            if status.is_good():
                self._values[wv.NodeId] = value
            return status

        return hook

    def _request_hook(self, cell: str, path: str) -> WriteHook:
        code_path = "Command/CntrlCmd" if path == "Command/CmdChangeRequest" else "Command/UnitMode"
        field = "cntrl_cmd" if code_path == "Command/CntrlCmd" else "unit_mode_code"

        async def hook(wv: ua.WriteValue, user: User, store: Callable[[], Awaitable[ua.StatusCode]]) -> ua.StatusCode:
            value, bad = _scalar(wv, ua.VariantType.Boolean)
            if bad is not None:
                return bad
            if not value:
                status = await store()
                if status.is_good():
                    self._values[wv.NodeId] = False
                return status
            async with self._locks[cell]:
                code = self._get(cell, code_path)
                if not code:
                    _, reason = await self._outcome(
                        cell,
                        None,
                        S.BadNothingToDo,
                        f"{path.rsplit('/', 1)[1]} without a command: write {code_path} "
                        f"({_cmd_list() if field == 'cntrl_cmd' else _mode_list()}) first",
                    )
                    return ua.StatusCode(S.BadNothingToDo)
                status = await store()
                if not status.is_good():
                    return status
                self._values[wv.NodeId] = True
                try:
                    result, _ = await self._send(cell, user, **{field: int(code)})
                finally:
                    # handled (accepted or not): the request and its command are consumed
                    await self._set(cell, path, False)
                    await self._set(cell, code_path, 0)
                return result

        return hook

    # --- running -----------------------------------------------------------------------------

    async def serve(self, stop: asyncio.Event) -> None:
        """Serve until ``stop`` is set.

        Raises:
            ConfigError: the endpoint cannot be bound, or the security settings are incomplete.
        """
        self._loop = asyncio.get_running_loop()
        self._inbox = asyncio.Queue()
        self._link = CellLink(
            self.cell_cfg,
            self.cells,
            self._sink,
            reconnect_s=self.cfg.reconnect_s,
            liveliness=True,
            thread_name="opcua-zenoh-link",
        )
        self.server = await self._make_server()
        try:
            await self.server.start()
        except OSError as err:
            raise ConfigError(f"cannot serve OPC UA on {self.cfg.endpoint}: {err} (is another server there?)") from err
        try:
            for cell in self.cells:
                await self._mark_down(cell, "waiting for the daemon's first Status")
            self._link.start()
            watchdog = asyncio.create_task(self._watchdog())
            log.warning(
                "OPC UA PackML gateway on %s for cells %s (security %s), bus %s",
                self.cfg.endpoint,
                self.cells,
                self.cfg.security,
                self.cell_cfg.bus.connect,
            )
            self.ready.set()
            inbox = self._inbox
            stopper = asyncio.create_task(stop.wait())
            stopper.add_done_callback(lambda _: inbox.put_nowait(("stop", "", None)))
            while True:
                item = await inbox.get()  # one await per sample: the StateCurrent latency is made here
                if item[0] == "stop":
                    break
                try:
                    await self._handle(*item)
                except Exception:  # one bad sample must not stop the gateway
                    log.exception("gateway failed on a bus sample")
            watchdog.cancel()
        finally:
            self._link.close()
            await self.server.stop()
            self._pool.shutdown(wait=False, cancel_futures=True)

    def start_thread(self, timeout: float = 30.0) -> OpcuaGateway:
        """Run :meth:`serve` in a thread; return once it serves.

        Raises:
            CellError: it did not come up within ``timeout`` (its error is chained).
        """

        def body() -> None:
            async def main() -> None:
                self._stop_async = asyncio.Event()
                await self.serve(self._stop_async)

            try:
                asyncio.run(main())
            except BaseException as err:  # reported to the starter
                self.error = err
                self.ready.set()

        self._thread = threading.Thread(target=body, name="opcua-gateway", daemon=True)
        self._thread.start()
        if not self.ready.wait(timeout) or self.error is not None:
            raise CellError(f"the OPC UA gateway did not start on {self.cfg.endpoint}: {self.error}") from self.error
        return self

    def close(self) -> None:
        loop, ev = self._loop, self._stop_async
        if loop is not None and ev is not None and not loop.is_closed():
            loop.call_soon_threadsafe(ev.set)
        if self._thread is not None:
            self._thread.join(timeout=15)

    def __enter__(self) -> OpcuaGateway:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
