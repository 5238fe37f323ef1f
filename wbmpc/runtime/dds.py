"""A small DDS transport over Eclipse Cyclone DDS: one participant bound to one network interface.

The participant's configuration is a Cyclone DDS XML string built here, never the environment: a
``cyclonedds.domain.Domain(domain_id, config)`` is created first (the Python API's ``dds_create_domain``;
``DomainParticipant`` itself takes no configuration), and the ``DomainParticipant`` then joins it.
``CYCLONEDDS_URI`` is neither read for the domains made here nor set, so nothing leaks into other code of
the process. Cyclone allows one configuration per domain id per process, so endpoints of one process on
the same domain share the ``Domain`` (reference counted); asking for the same domain on another interface
is a ``ValueError``.

The configuration binds the participant ONLY to the named interface (``<Interfaces><NetworkInterface
name=.../>``). On a loopback interface (``lo``, ``lo0``) multicast may be unavailable (Linux's ``lo`` has
no MULTICAST flag), so discovery is made unicast: ``<AllowMulticast>false</AllowMulticast>``, the peer
127.0.0.1, and ``<ParticipantIndex>auto</ParticipantIndex>`` with ``<MaxAutoParticipantIndex>`` =
:data:`MAX_PARTICIPANTS_PER_HOST` - 1 (each participant takes the unicast ports of the lowest free index,
and discovery probes the ports of every index up to that maximum). On any other interface (the robot's
Ethernet) Cyclone's default multicast discovery is kept, as Unitree's SDK does.

Domain ids. DDS maps a domain id d to UDP ports 7400 + 250 d + ..., which must stay below 65536: d in
0..232. Unitree's robots speak on domain 0, and their simulator bridge convention is domain 1 on ``lo``.
wbmpc's default is :data:`DEFAULT_DOMAIN` = 42 so that nothing else on the network (a robot's own
controller, a Unitree tool, a colleague's simulator) can receive our commands or feed us state by
accident: talking to a real robot is an explicit ``domain=0``.

QoS, chosen to match whatever Unitree's SDK offers or asks for: readers are best effort, keep last
``depth`` (a best-effort reader matches both reliable and best-effort writers); writers are reliable, keep
last 1 (the Python SDK's writers use the DDS default, reliable, and a reliable writer matches both kinds of
readers; with keep-last-1 history a write does not wait for a slow reader: the new sample replaces the
unacknowledged one).

Serialized samples. :func:`write_serialized` and :meth:`DdsEndpoint.take_serialized` hand cyclonedds the
bytes of a sample (encapsulation header included) and take them back with their ``SampleInfo``: what
``DataWriter.write`` does after ``sample.serialize()`` and ``DataReader.take`` before ``deserialize``
(cyclonedds 11's ``ddspy_write`` / ``ddspy_take``), without a Python object in between, for the
fixed-layout codecs of :mod:`wbmpc.runtime.cdr`.
"""

import random
import socket
import threading
import time

from cyclonedds._clayer import ddspy_take, ddspy_write
from cyclonedds.core import (
    DDSException,
    InstanceState,
    Policy,
    Qos,
    ReadCondition,
    SampleState,
    ViewState,
    WaitSet,
)
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

DEFAULT_DOMAIN = 42
MAX_DOMAIN = 232
MAX_PARTICIPANTS_PER_HOST = 20
LOOPBACK_INTERFACES = ("lo", "lo0")

_ANY_SAMPLE = SampleState.Any | ViewState.Any | InstanceState.Any

_domains_lock = threading.Lock()
_domains: dict[int, list] = {}  # domain id -> [Domain, interface, number of endpoints using it]


def check_domain(domain: int) -> int:
    """The domain id, or ValueError unless it is an int in 0..232."""
    if isinstance(domain, bool) or not isinstance(domain, int) or not 0 <= domain <= MAX_DOMAIN:
        raise ValueError(f"DDS domain id must be an integer in 0..{MAX_DOMAIN}, got {domain!r}")
    return domain


def check_interface(interface: str) -> str:
    """The interface name, or ValueError unless this machine has a network interface of that name."""
    names = [name for _, name in socket.if_nameindex()]
    if interface not in names:
        raise ValueError(f"no network interface {interface!r} on this machine (it has: {', '.join(names)})")
    return interface


def domain_ports_free(domain: int) -> bool:
    """Whether the UDP ports of ``domain`` on 127.0.0.1 are unused (discovery 7400 + 250 d + 0/1, and the
    unicast ports + 10 + 2 i / + 11 + 2 i of every participant index i): no other run shares the domain."""
    base = 7400 + 250 * check_domain(domain)
    ports = [base, base + 1] + [base + 10 + k for k in range(2 * MAX_PARTICIPANTS_PER_HOST)]
    for port in ports:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                return False
    return True


def free_domain(low: int = 100, high: int = MAX_DOMAIN, tries: int = 100, rng=None) -> int | None:
    """A random domain in ``[low, high]`` other than :data:`DEFAULT_DOMAIN`, not used by this process and
    with its ports free (:func:`domain_ports_free`), e.g. for a test run beside others; ``None`` if none of
    ``tries`` candidates is."""
    rng = rng or random.Random()
    for _ in range(tries):
        domain = rng.randint(low, high)
        if domain != DEFAULT_DOMAIN and domain not in _domains and domain_ports_free(domain):
            return domain
    return None


def cyclonedds_config(domain: int, interface: str) -> str:
    """The Cyclone DDS XML configuration of a participant on ``domain`` bound to ``interface`` only."""
    general = f'<Interfaces><NetworkInterface name="{interface}"/></Interfaces>'
    discovery = ""
    if interface in LOOPBACK_INTERFACES:
        general += "<AllowMulticast>false</AllowMulticast>"
        discovery = (
            '<Discovery><Peers><Peer address="127.0.0.1"/></Peers>'
            "<ParticipantIndex>auto</ParticipantIndex>"
            f"<MaxAutoParticipantIndex>{MAX_PARTICIPANTS_PER_HOST - 1}</MaxAutoParticipantIndex></Discovery>"
        )
    return f'<CycloneDDS><Domain id="{domain}"><General>{general}</General>{discovery}</Domain></CycloneDDS>'


def write_serialized(writer: DataWriter, data: bytes) -> None:
    """Write one serialized sample (its 4-byte encapsulation header first, e.g. from
    :meth:`wbmpc.runtime.cdr.FixedCdr.encode`) as ``writer.write`` would write the sample.

    Raises:
        DDSException: cyclonedds refused the write.
    """
    if len(data) % 4:
        data = data.ljust((len(data) + 3) & ~3, b"\0")  # as DataWriter.write pads it
    ret = ddspy_write(writer._ref, data)
    if ret < 0:
        raise DDSException(ret, f"Occurred while writing a serialized sample in {writer!r}")


def _acquire_domain(domain: int, interface: str) -> None:
    with _domains_lock:
        entry = _domains.get(domain)
        if entry is None:
            _domains[domain] = [Domain(domain, cyclonedds_config(domain, interface)), interface, 1]
        elif entry[1] != interface:
            raise ValueError(
                f"DDS domain {domain} is already configured on interface {entry[1]!r} in this process; "
                f"cannot also bind it to {interface!r}"
            )
        else:
            entry[2] += 1


def _release_domain(domain: int) -> None:
    with _domains_lock:
        entry = _domains[domain]
        entry[2] -= 1
        if entry[2] == 0:
            del _domains[domain]
            entry[0].__del__()  # dds_delete now, not whenever the garbage collector gets to it


class DdsEndpoint:
    """A DDS participant on one domain and one network interface, with its writers and readers.

    Args:
        domain: DDS domain id in 0..232 (default :data:`DEFAULT_DOMAIN`, 42; a real Unitree robot is 0).
        interface: network interface name, e.g. ``"lo"`` or the robot's Ethernet ``"enp3s0"``.

    Raises:
        ValueError: a domain id outside 0..232, an interface this machine does not have, or a domain this
            process already bound to another interface (all checked before anything is created).
    """

    def __init__(self, domain: int = DEFAULT_DOMAIN, interface: str = "lo"):
        self.domain = check_domain(domain)
        self.interface = check_interface(interface)
        _acquire_domain(self.domain, self.interface)
        try:
            self.participant = DomainParticipant(self.domain)
        except Exception:
            _release_domain(self.domain)
            raise
        self._topics: dict[tuple[str, type], Topic] = {}
        self._waitsets: dict[int, tuple[WaitSet, ReadCondition, int]] = {}  # id(reader) -> its wait
        self._entities: list = []
        self._closed = False

    def _topic(self, topic: str, data_type: type) -> Topic:
        self._check_open()
        key = (topic, data_type)
        if key not in self._topics:
            self._topics[key] = Topic(self.participant, topic, data_type)
        return self._topics[key]

    def writer(self, topic: str, data_type: type) -> DataWriter:
        """A writer of ``data_type`` samples on ``topic`` (reliable, keep last 1)."""
        qos = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.History.KeepLast(1))
        writer = DataWriter(self.participant, self._topic(topic, data_type), qos=qos)
        self._entities.append(writer)
        return writer

    def reader(self, topic: str, data_type: type, depth: int = 1) -> DataReader:
        """A reader of ``data_type`` samples on ``topic`` (best effort, keep the last ``depth``)."""
        if depth < 1:
            raise ValueError(f"reader depth must be >= 1, got {depth}")
        qos = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(depth))
        reader = DataReader(self.participant, self._topic(topic, data_type), qos=qos)
        condition = ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any)
        waitset = WaitSet(self.participant)
        waitset.attach(condition)
        self._waitsets[id(reader)] = (waitset, condition, depth)
        self._entities.append(reader)
        return reader

    def take_latest(self, reader: DataReader, timeout_s: float = 0.0):
        """Take every queued sample of ``reader`` and return the newest, waiting up to ``timeout_s`` [s].

        Returns:
            The newest valid sample, or None if none arrived within the timeout (dispose/unregister
            notifications are not samples and are dropped).
        """
        self._check_open()
        deadline = time.monotonic() + max(timeout_s, 0.0)
        waitset, _, depth = self._waitsets[id(reader)]
        while True:
            samples = [s for s in reader.take(N=depth) if isinstance(s, reader.topic.data_type)]
            if samples:
                return samples[-1]
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                return None
            waitset.wait(duration(seconds=remaining))

    def take_serialized(self, reader: DataReader, timeout_s: float = 0.0) -> list:
        """Take every queued sample of ``reader`` serialized, oldest first, waiting up to ``timeout_s`` [s]
        for the first.

        Returns:
            ``[(data, info), ...]``: each sample's bytes (encapsulation header included) and its
            ``cyclonedds.internal.SampleInfo`` (``publication_handle`` names the writer); dispose and
            unregister notifications are dropped. Empty if nothing arrived within the timeout.
        """
        self._check_open()
        deadline = time.monotonic() + max(timeout_s, 0.0)
        waitset, _, depth = self._waitsets[id(reader)]
        while True:
            ret = ddspy_take(reader._ref, _ANY_SAMPLE, depth)
            if isinstance(ret, int):
                raise DDSException(ret, f"Occurred while taking serialized samples in {reader!r}")
            samples = [(data, info) for data, info in ret if info.valid_data]
            if samples:
                return samples
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                return samples
            waitset.wait(duration(seconds=remaining))

    def wait_for_match(self, entity: DataWriter | DataReader, timeout_s: float, count: int = 1) -> bool:
        """Wait until a writer (reader) matches ``count`` remote readers (writers); False on timeout."""
        if isinstance(entity, DataWriter):
            matched = entity.get_matched_subscriptions
        else:
            matched = entity.get_matched_publications
        deadline = time.monotonic() + timeout_s
        while len(matched()) < count:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.005)
        return True

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"DdsEndpoint(domain={self.domain}, interface={self.interface!r}) is closed")

    def close(self) -> None:
        """Delete the participant (and with it every writer, reader and topic made here). Idempotent."""
        if self._closed:
            return
        self._closed = True
        for waitset, condition, _ in self._waitsets.values():
            waitset.detach(condition)
        self._waitsets.clear()
        self._entities.clear()
        self._topics.clear()
        self.participant.__del__()  # deletes its children in Cyclone too
        _release_domain(self.domain)

    def __enter__(self) -> "DdsEndpoint":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"DdsEndpoint(domain={self.domain}, interface={self.interface!r}, {state})"
