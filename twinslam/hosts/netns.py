"""Three hosts on one machine: network namespaces ``device``, ``edge`` and ``twin``.

Each host is a network namespace with one interface, ``eth0``, holding an address on a private
/24 that exists only inside these namespaces; the three ``eth0`` are veth pairs whose other
ends hang on a bridge in a fourth namespace, the "switch". Nothing is routed anywhere else: the
namespaces have no default route and no link to the machine's own network, so no packet of a
run can leave them.

Fast DDS is configured per host for UDPv4 only, with the three host addresses as static
discovery peers (``ROS_STATIC_PEERS``), as on a LAN whose switch drops multicast. Its messages
stay below the link MTU, so a lost packet costs one RTPS fragment, not an IP-fragmented
datagram of 45.

The device's uplink is its veth: ``tc`` on the device's ``eth0`` shapes what the device sends
(:mod:`twinslam.uplink.tc_shaper`), and :meth:`NetnsHosts.set_link` pulls the switch-side
end of a host's cable. :class:`NetnsHosts` is a context manager with the process handling of
:class:`~twinslam.hosts.loopback.LoopbackDomain`: ``spawn(args, host=...)`` runs ``python
args``
inside a host, ``close()`` stops them and deletes every namespace, even after a failure.
Creating namespaces needs root (CAP_SYS_ADMIN and CAP_NET_ADMIN) and ``iproute2``;
:func:`unavailable_reason` says why they cannot be made here.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

from twinslam.hosts.fastdds import ENV_KEYS, ros_env
from twinslam.hosts.forked import enter_network_namespace
from twinslam.hosts.loopback import ProcessDomain

HOSTS = ("device", "edge", "twin")
SUBNET = "10.210.0"                      #: the hosts' /24; addresses exist only in the namespaces
HOST_NUMBER = {"device": 2, "edge": 3, "twin": 4}
INTERFACE = "eth0"
MTU = 1500

#: Fast DDS profile of a host: UDPv4 only (shared memory would carry a device's samples to the
#: edge past the shaped cable, the namespaces sharing /dev/shm) with datagrams below the link MTU
#: (a lost packet costs one RTPS fragment, not an IP-fragmented 64 KB datagram of 45), and
#: the timings of config/fastdds.xml: participants announced every second, reliable writers
#: heartbeating every 0.5 s (after a pulled cable is plugged back, what was lost is resent within
#: half a second instead of up to Fast DDS's 3 s)
HOST_PROFILE = """<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <profiles>
    <transport_descriptors>
      <transport_descriptor>
        <transport_id>host_udp</transport_id>
        <type>UDPv4</type>
        <maxMessageSize>1472</maxMessageSize>
        <sendBufferSize>1048576</sendBufferSize>
        <receiveBufferSize>4194304</receiveBufferSize>
      </transport_descriptor>
    </transport_descriptors>
    <participant profile_name="twinslam_host" is_default_profile="true">
      <rtps>
        <builtin>
          <discovery_config>
            <leaseAnnouncement><sec>1</sec></leaseAnnouncement>
          </discovery_config>
        </builtin>
        <useBuiltinTransports>false</useBuiltinTransports>
        <userTransports><transport_id>host_udp</transport_id></userTransports>
      </rtps>
    </participant>
    <data_writer profile_name="twinslam_host_writer" is_default_profile="true">
      <times>
        <heartbeatPeriod><sec>0</sec><nanosec>500000000</nanosec></heartbeatPeriod>
      </times>
    </data_writer>
  </profiles>
</dds>
"""


class NetnsError(RuntimeError):
    """A namespace, link or address that could not be made (the message holds ip's words)."""


def unavailable_reason() -> str | None:
    """Why namespaces cannot be made on this machine, or None when they can."""
    if sys.platform != "linux":
        return f"network namespaces need Linux, this is {sys.platform}"
    if shutil.which("ip") is None:
        return "iproute2's `ip` is not installed"
    if shutil.which("tc") is None:
        return "iproute2's `tc` is not installed"
    if os.geteuid() != 0:
        return "creating network namespaces needs root (CAP_SYS_ADMIN, CAP_NET_ADMIN)"
    probe = f"twinslam-probe-{os.getpid()}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f"`ip netns add` failed: {made.stderr.strip()}"
    subprocess.run(["ip", "netns", "delete", probe], capture_output=True)
    return None


def host_env(domain_id: int, profile: Path, hosts: tuple[str, ...] = HOSTS,
             addresses: tuple[str, ...] | None = None) -> dict[str, str]:
    """The DDS environment of a node on a host: the hosts' addresses as static peers (the
    namespaces have no route for multicast, as a LAN whose switch drops it) and the host
    profile."""
    peers = addresses if addresses is not None else tuple(address_of(h) for h in hosts)
    return ros_env(domain_id, "SUBNET", profile, peers)


def address_of(host: str) -> str:
    if host not in HOST_NUMBER:
        raise ValueError(f"unknown host {host!r}; hosts are {', '.join(HOSTS)}")
    return f"{SUBNET}.{HOST_NUMBER[host]}"


def _ip(*args: str, netns: str | None = None) -> str:
    cmd = ["ip", *(["-n", netns] if netns else []), *args]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise NetnsError(f"`{' '.join(cmd)}` failed: {done.stderr.strip()}")
    return done.stdout


def _setns(path: str) -> None:
    try:
        enter_network_namespace(path)
    except OSError as exc:
        raise NetnsError(str(exc.strerror)) from None


class NetnsHosts(ProcessDomain):
    """The hosts (device, edge and twin unless ``hosts`` names others, e.g. one per device of
    a fleet: ``("ar1", "ar2", "edge")``) and their switch; ``up()`` builds, ``close()``
    removes. Addresses: :meth:`address`."""

    def __init__(self, prefix: str = "twinslam-", domain_id: int = 0,
                 hosts: tuple[str, ...] = HOSTS) -> None:
        super().__init__(domain_id)
        if len(set(hosts)) != len(hosts) or not 0 < len(hosts) <= 200:
            raise ValueError(f"hosts must be 1 to 200 distinct names, got {hosts}")
        self.prefix, self.hosts = prefix, tuple(hosts)
        self.namespaces = {h: f"{prefix}{h}" for h in self.hosts}
        self.switch = f"{prefix}switch"
        self._bpffs: Path | None = None         # where loss programs are pinned
        self._profile_dir = Path(tempfile.mkdtemp(prefix=f"{prefix}dds-"))
        self.profile = self._profile_dir / "fastdds_host.xml"
        self.profile.write_text(HOST_PROFILE, encoding="utf-8")

    def port(self, host: str) -> str:
        """The switch-side end of ``host``'s cable."""
        return f"p-{host}"

    # -- building and removing ------------------------------------------------------------------

    def up(self) -> NetnsHosts:
        """Create the namespaces, the bridge and one cable per host; on failure remove what
        was made and raise :class:`NetnsError`. Namespaces of these names that exist already
        are refused, never reused or removed."""
        taken = self.exists()
        if taken:
            raise NetnsError(f"network namespaces {', '.join(taken)} exist already; "
                             f"`twinslam hosts down --prefix '{self.prefix}'` first")
        try:
            for ns in (self.switch, *self.namespaces.values()):
                _ip("netns", "add", ns)
                _ip("link", "set", "lo", "up", netns=ns)
            _ip("link", "add", "br0", "type", "bridge", netns=self.switch)
            _ip("link", "set", "br0", "up", netns=self.switch)
            for host, ns in self.namespaces.items():
                _ip("link", "add", self.port(host), "mtu", str(MTU), "type", "veth", "peer",
                    "name", INTERFACE, "mtu", str(MTU), "netns", ns, netns=self.switch)
                _ip("link", "set", self.port(host), "master", "br0", "up", netns=self.switch)
                _ip("addr", "add", f"{self.address(host)}/24", "dev", INTERFACE, netns=ns)
                _ip("link", "set", INTERFACE, "up", netns=ns)
        except NetnsError:
            self.down()
            raise
        return self

    def down(self) -> None:
        """Delete every namespace of this set (their veths go with them); idempotent."""
        for ns in (*self.namespaces.values(), self.switch):
            subprocess.run(["ip", "netns", "delete", ns], capture_output=True)

    def exists(self) -> list[str]:
        """The namespaces of this set that exist now."""
        listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
        names = {line.split()[0] for line in listed.splitlines() if line.strip()}
        return [ns for ns in (*self.namespaces.values(), self.switch) if ns in names]

    # -- running inside a host --------------------------------------------------------------------

    def address(self, host: str) -> str:
        """``host``'s address on the switch: device, edge and twin always have theirs
        (:func:`address_of`), other hosts SUBNET.10, .11, … in the order given. The edge keeps
        its address whatever the set: Fast DDS takes a process's network interfaces from its
        first participant, so a monitor of a later set in the same process announces the
        edge host's address of the first (measured: a fleet whose edge was .4 after a run
        whose edge was .3 was never discovered)."""
        if host not in self.namespaces:
            raise ValueError(f"unknown host {host!r}; hosts are {', '.join(self.hosts)}")
        if host in HOST_NUMBER:
            return address_of(host)
        others = [h for h in self.hosts if h not in HOST_NUMBER]
        return f"{SUBNET}.{10 + others.index(host)}"

    def _host_env(self) -> dict[str, str]:
        return host_env(self.domain_id, self.profile,
                        addresses=tuple(self.address(h) for h in self.hosts))

    def env_for(self, host: str | None) -> dict[str, str]:
        env = self.base_env()
        env.update(self._host_env())
        return env

    def network_namespace(self, host: str | None) -> str | None:
        return f"/run/netns/{self.namespaces[host]}" if host in self.namespaces else None

    def command(self, host: str | None, argv: list[str]) -> list[str]:
        if host is None or host not in self.namespaces:
            raise ValueError(f"unknown host {host!r}; hosts are {', '.join(self.hosts)}")
        return ["ip", "netns", "exec", self.namespaces[host], *argv]

    def run_in(self, host: str, *argv: str, check: bool = True) -> str:
        """Run a command in ``host`` (e.g. ``tc``) and return its output."""
        done = subprocess.run(self.command(host, list(argv)), capture_output=True, text=True)
        if check and done.returncode != 0:
            raise NetnsError(f"`{' '.join(argv)}` in {host} failed: {done.stderr.strip()}")
        return done.stdout

    @contextlib.contextmanager
    def inside(self, host: str) -> Iterator[None]:
        """Run this thread in ``host``'s namespace for the block: DDS participants made here
        (and the threads the middleware starts for them) live in that host."""
        home = os.open("/proc/thread-self/ns/net", os.O_RDONLY)
        saved = {k: os.environ.get(k) for k in ENV_KEYS}
        try:
            _setns(f"/run/netns/{self.namespaces[host]}")
            os.environ.update(self._host_env())
            yield
        finally:
            _setns(f"/proc/self/fd/{home}")
            os.close(home)
            for key, value in saved.items():
                if value is None:
                    os.environ.pop(key, None)
                else:
                    os.environ[key] = value

    def monitor_scope(self) -> contextlib.AbstractContextManager[None]:
        """A monitor watches from the edge host, as an operator's console beside the server."""
        return self.inside("edge")

    # -- the cables -------------------------------------------------------------------------------

    def set_link(self, host: str, up: bool) -> None:
        """Plug (``up``) or pull ``host``'s cable at the switch: its ``eth0`` loses carrier."""
        _ip("link", "set", self.port(host), "up" if up else "down", netns=self.switch)

    def lose_packets(self, host: str, percent: float) -> str:
        """Drop ``percent`` % of what ``host`` sends, at random, on its ``eth0``: ``tc netem``
        where the kernel has it, else an eBPF classifier (:mod:`twinslam.hosts.ebpf_loss`).
        Returns which; raises :class:`NetnsError` when neither can be installed."""
        ns = self.namespaces[host]
        netem = subprocess.run(["tc", "-n", ns, "qdisc", "replace", "dev", INTERFACE, "root",
                                "netem", "loss", f"{percent:g}%"], capture_output=True, text=True)
        if netem.returncode == 0:
            return "netem"
        from twinslam.hosts.ebpf_loss import EbpfError, pin_random_drop

        if self._bpffs is None:
            self._bpffs = Path(tempfile.mkdtemp(prefix=f"{self.prefix}bpffs-"))
            done = subprocess.run(["mount", "-t", "bpf", "bpf", str(self._bpffs)],
                                  capture_output=True, text=True)
            if done.returncode != 0:
                raise NetnsError(f"no netem ({netem.stderr.strip()}) and cannot mount a bpffs "
                                 f"for the eBPF loss program: {done.stderr.strip()}")
        pin = self._bpffs / f"loss-{host}-{percent:g}"
        try:
            pin_random_drop(percent, pin)
        except EbpfError as exc:
            raise NetnsError(f"no netem ({netem.stderr.strip()}) and no eBPF: {exc}") from None
        for args in (["qdisc", "replace", "dev", INTERFACE, "clsact"],
                     ["filter", "replace", "dev", INTERFACE, "egress", "pref", "1", "bpf", "da",
                      "object-pinned", str(pin)]):
            done = subprocess.run(["tc", "-n", ns, *args], capture_output=True, text=True)
            if done.returncode != 0:
                raise NetnsError(f"`tc {' '.join(args)}` in {host} failed: "
                                 f"{done.stderr.strip()}")
        return "ebpf"

    def port_bytes(self, host: str) -> int:
        """Bytes the switch has received from ``host`` (what crossed its cable, uplink)."""
        ns_path = Path("/run/netns") / self.switch
        if not ns_path.exists():
            raise NetnsError(f"{self.switch} does not exist")
        out = _ip("-s", "-j", "link", "show", self.port(host), netns=self.switch)
        return int(json.loads(out)[0]["stats64"]["rx"]["bytes"])

    def close(self) -> None:
        super().close()
        self.down()
        shutil.rmtree(self._profile_dir, ignore_errors=True)
        if self._bpffs is not None:           # the pinned programs go with the mount
            subprocess.run(["umount", str(self._bpffs)], capture_output=True)
            shutil.rmtree(self._bpffs, ignore_errors=True)
            self._bpffs = None

    def __enter__(self) -> NetnsHosts:
        return self.up()
