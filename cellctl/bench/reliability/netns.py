"""Hosts in one machine: network namespaces linked by veth pairs, for the cluster tests and bench.

Each "host" is a network namespace with its own loopback; hosts are linked point to point by
veth pairs addressed from the link-local range 169.254.0.0/16 (link ``n`` is
``169.254.(100+n).1/24`` ↔ ``.2/24``, never ``169.254.169.x``), and only on those veths. Nothing
here touches the root namespace's interfaces or routes, and nothing is reachable beyond the
namespaces this harness made. Processes run in a host with ``ip netns exec``.

Bounded and always torn down: at most :data:`MAX_HOSTS` namespaces per plant, names start
with :data:`PREFIX` and a per-process tag, leftovers of that prefix (from a run that was
killed) are removed on start, and :meth:`Plant.close` kills every process it started and
deletes its namespaces (the veths go with them). Needs root (``CAP_NET_ADMIN``);
:func:`netns_unavailable` says why not, for a skip message.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from cellctl.errors import CellError

__all__ = ["MAX_HOSTS", "PREFIX", "Host", "Link", "Plant", "cleanup_leftovers", "netns_unavailable"]

PREFIX = "cellctl-clt-"
"""Every namespace this harness makes starts with this; leftovers are found by it."""

MAX_HOSTS = 8
_VETH_PREFIX = "clv"


def _ip(*args: str, ns: str | None = None, check: bool = True) -> subprocess.CompletedProcess[str]:
    cmd = ["ip", *(["-n", ns] if ns else []), *args]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=10)
    if check and res.returncode != 0:
        raise CellError(f"`{' '.join(cmd)}` failed ({res.returncode}): {res.stderr.strip()}")
    return res


def netns_unavailable() -> str | None:
    """None when this process may create namespaces and veths, else the reason (for a skip)."""
    if os.geteuid() != 0:
        return "network namespaces need root (CAP_NET_ADMIN); running as uid %d" % os.geteuid()
    probe = f"{PREFIX}probe-{os.getpid()}"
    try:
        res = _ip("netns", "add", probe, check=False)
    except (OSError, subprocess.SubprocessError) as err:
        return f"`ip netns` cannot run here: {err}"
    if res.returncode != 0:
        return f"`ip netns add` is not permitted here: {res.stderr.strip()}"
    try:
        res = _ip("link", "add", "clvprobe0", "type", "veth", "peer", "name", "clvprobe1", ns=probe, check=False)
        if res.returncode != 0:
            return f"veth pairs cannot be created here: {res.stderr.strip()}"
    finally:
        _ip("netns", "del", probe, check=False)
    return None


def _pid_alive(pid: int) -> bool:
    return Path(f"/proc/{pid}").exists()  # the harness is Linux-only (ip netns)


def _ns_pids(ns: str) -> list[int]:
    res = _ip("netns", "pids", ns, check=False)
    return [int(x) for x in res.stdout.split() if x.isdigit()]


def cleanup_leftovers(prefix: str = PREFIX) -> list[str]:
    """Kill the processes in, and delete, every namespace named ``prefix*`` (a killed run's rests)."""
    res = _ip("netns", "list", check=False)
    gone = []
    for line in res.stdout.splitlines():
        name = line.split()[0] if line.split() else ""
        if not name.startswith(prefix):
            continue
        owner = name[len(prefix) :].split("-", 1)[0]
        if owner.isdigit() and _pid_alive(int(owner)):
            continue  # a live run's plant (a concurrent test or bench), not a leftover
        for pid in _ns_pids(name):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        _ip("netns", "del", name, check=False)
        gone.append(name)
    return gone


@dataclass
class Host:
    """One namespace: a host with its own loopback and the veth ends linked to it."""

    name: str
    ns: str
    plant: Plant
    addresses: dict[str, str] = field(default_factory=dict)  # peer host name -> this host's address on that link

    def address_to(self, peer: str) -> str:
        """This host's address on its link to ``peer`` (what ``peer`` connects to)."""
        try:
            return self.addresses[peer]
        except KeyError:
            raise CellError(f"host {self.name!r} has no link to {peer!r}; links: {sorted(self.addresses)}") from None

    def spawn(self, argv: list[str], name: str, env: dict[str, str] | None = None) -> subprocess.Popen[bytes]:
        """Start ``argv`` in this host; stdout+stderr go to ``<tmp>/<host>-<name>.log``."""
        return self.plant.spawn(self, argv, name, env)

    def run(self, argv: list[str], timeout: float = 30.0) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            ["ip", "netns", "exec", self.ns, *argv], capture_output=True, text=True, timeout=timeout, check=False
        )


@dataclass
class Link:
    """A veth pair between two hosts; ``down()`` cuts it the way a pulled cable does."""

    a: Host
    b: Host
    a_dev: str
    b_dev: str
    a_ip: str
    b_ip: str

    def down(self) -> None:
        _ip("link", "set", self.a_dev, "down", ns=self.a.ns)
        _ip("link", "set", self.b_dev, "down", ns=self.b.ns)

    def up(self) -> None:
        _ip("link", "set", self.a_dev, "up", ns=self.a.ns)
        _ip("link", "set", self.b_dev, "up", ns=self.b.ns)


class Plant:
    """Namespaces, links and the processes started in them; a context manager that tears all down.

    Args:
        tmp: folder for the processes' logs.
        tag: distinguishes this plant's namespaces (default: pid + random).
    """

    def __init__(self, tmp: Path, tag: str | None = None) -> None:
        self.tmp = Path(tmp)
        self.tag = tag or f"{os.getpid()}-{uuid.uuid4().hex[:4]}"
        self._short = self.tag.rsplit("-", 1)[-1][:4]
        self.hosts: dict[str, Host] = {}
        self.links: dict[tuple[str, str], Link] = {}
        self.procs: list[tuple[str, subprocess.Popen[bytes]]] = []
        self._n_links = 0

    def __enter__(self) -> Plant:
        cleanup_leftovers()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def add_host(self, name: str) -> Host:
        if len(self.hosts) >= MAX_HOSTS:
            raise CellError(f"a plant holds at most {MAX_HOSTS} hosts; {name!r} would be one more")
        ns = f"{PREFIX}{self.tag}-{name}"
        _ip("netns", "add", ns)
        host = Host(name, ns, self)
        self.hosts[name] = host
        _ip("link", "set", "lo", "up", ns=ns)
        return host

    def link(self, a: str, b: str) -> Link:
        """Link hosts ``a`` and ``b`` with a veth pair on 169.254.(100+n).0/24."""
        ha, hb = self.hosts[a], self.hosts[b]
        n = self._n_links
        if n >= 60:
            raise CellError("at most 60 links per plant")
        self._n_links += 1
        # veth names are at most 15 characters and live in one name space until moved
        a_dev, b_dev = f"{_VETH_PREFIX}{self._short}{n}a", f"{_VETH_PREFIX}{self._short}{n}b"
        _ip("link", "add", a_dev, "netns", ha.ns, "type", "veth", "peer", "name", b_dev, "netns", hb.ns)
        a_ip, b_ip = f"169.254.{100 + n}.1", f"169.254.{100 + n}.2"
        _ip("addr", "add", f"{a_ip}/24", "dev", a_dev, ns=ha.ns)
        _ip("addr", "add", f"{b_ip}/24", "dev", b_dev, ns=hb.ns)
        link = Link(ha, hb, a_dev, b_dev, a_ip, b_ip)
        link.up()
        ha.addresses[b], hb.addresses[a] = a_ip, b_ip
        self.links[(a, b)] = link
        return link

    def link_between(self, a: str, b: str) -> Link:
        link = self.links.get((a, b)) or self.links.get((b, a))
        if link is None:
            raise CellError(f"no link between {a!r} and {b!r}; links: {sorted(self.links)}")
        return link

    def spawn(
        self, host: Host, argv: list[str], name: str, env: dict[str, str] | None = None
    ) -> subprocess.Popen[bytes]:
        log = (self.tmp / f"{host.name}-{name}.log").open("ab")
        proc = subprocess.Popen(
            ["ip", "netns", "exec", host.ns, *argv],
            stdout=log,
            stderr=subprocess.STDOUT,
            env={**os.environ, **(env or {})},
            start_new_session=True,  # its own process group: stopped as a whole, never by name
        )
        log.close()
        self.procs.append((f"{host.name}/{name}", proc))
        return proc

    def log_of(self, host: str, name: str) -> str:
        p = self.tmp / f"{host}-{name}.log"
        return p.read_text(errors="replace") if p.exists() else ""

    def wait_log(self, host: str, name: str, needle: str, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if needle in self.log_of(host, name):
                return True
            time.sleep(0.2)
        return False

    @staticmethod
    def stop(proc: subprocess.Popen[bytes], sig: int = signal.SIGTERM, timeout: float = 10.0) -> None:
        """Stop one process group this plant started (SIGTERM, then SIGKILL after ``timeout``)."""
        if proc.poll() is not None:
            return
        try:
            os.killpg(proc.pid, sig)
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=5)
        except ProcessLookupError:
            pass

    def close(self) -> None:
        for _, proc in reversed(self.procs):
            self.stop(proc, timeout=8.0)
        self.procs.clear()
        for host in self.hosts.values():
            for pid in _ns_pids(host.ns):  # anything a process left behind in its host
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            _ip("netns", "del", host.ns, check=False)
        self.hosts.clear()
        self.links.clear()
