"""The ns-3 network model (extra ``uav-harness[ns3]``, PyPI ``ns3``): Wi-Fi ad hoc nodes that follow the vehicles.

Vehicle ``v`` is ns-3 node ``v`` with address ``10.42.0.(v+1)``, a UDP socket on port 9 and a constant-
position mobility model moved to the vehicle's position at every step. ns-3's clock follows sim time: a
step runs the simulator to the end of the interval with ``Simulator.Stop``/``Run``.

Known traps, handled here:
- sends issued all at the tick boundary collide (every node transmits at once): they are spread within
  the interval, one every ``period / (n + 1)``;
- a broadcast before the first ``Run()`` crashes ns-3: one empty millisecond runs right after building;
- ``Ipv4AddressGenerator`` keeps its state across builds: it is reset before building;
- importing ns-3 takes ~10 s and ~650 MB: it happens once, when the model is made;
- an ARP entry that failed while a vehicle was out of range stays "dead" for 100 s: neighbour caches are
  populated statically, so delivery resumes from the tick a vehicle is back in range.

The payload travels by identity: ns-3 carries a packet of the right size and keeps its UID on every copy, so
the receiver looks the original up by UID. ns-3 reports no drop causes without tracing: a packet that does
not arrive is simply not delivered (drops are not listed).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from harness.core.errors import ScenarioError
from harness.core.geo import Vec3
from harness.net.model import Delivery, StepResult
from harness.wire.protocol import BROADCAST, Packet

_STANDARDS = {"80211a": "WIFI_STANDARD_80211a", "80211g": "WIFI_STANDARD_80211g", "80211n": "WIFI_STANDARD_80211n"}
_RATES = {"80211a": "OfdmRate6Mbps", "80211g": "ErpOfdmRate6Mbps", "80211n": "HtMcs0"}
PORT = 9


@dataclass(frozen=True)
class Ns3Config:
    standard: str = "80211a"
    """80211a, 80211g or 80211n."""
    max_vehicles: int = 64
    """Nodes built at start (vehicle indices above have no radio)."""
    tx_power_dbm: float = 20.0
    path_loss_exponent: float = 3.0
    """Log-distance loss from the free-space loss at 1 m for the band (2.4 GHz for g/n, 5.2 GHz for a)."""

    @classmethod
    def from_params(cls, params: Mapping[str, object]) -> Ns3Config:
        known = {"standard", "max_vehicles", "tx_power_dbm", "path_loss_exponent"}
        for key in params:
            if key not in known:
                raise ScenarioError(f"network.params.{key}: unknown ns-3 parameter (valid: {', '.join(sorted(known))})")
        standard = str(params.get("standard", "80211a"))
        if standard not in _STANDARDS:
            raise ScenarioError(f"network.params.standard: {standard!r} is not one of {sorted(_STANDARDS)}")
        max_vehicles = params.get("max_vehicles", 64)
        if not isinstance(max_vehicles, int) or not 1 <= max_vehicles <= 250:
            raise ScenarioError(f"network.params.max_vehicles: expected an integer 1-250, got {max_vehicles!r}")
        numbers = {}
        for key in ("tx_power_dbm", "path_loss_exponent"):
            value = params.get(key, getattr(cls, key))
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ScenarioError(f"network.params.{key}: expected a finite number, got {value!r}")
            numbers[key] = float(value)
        return cls(standard, max_vehicles, **numbers)


def _import_ns() -> Any:
    try:
        from ns import ns
    except ImportError:
        raise ScenarioError(
            "network model 'ns3' needs the ns-3 Python package: pip install 'uav-harness[ns3]'"
        ) from None
    return ns


class Ns3Radio:
    def __init__(self, cfg: Ns3Config | None = None, seed: int = 0) -> None:
        self.cfg = cfg or Ns3Config()
        self.ns = ns = _import_ns()
        ns.RngSeedManager.SetSeed(max(1, seed + 1))
        ns.RngSeedManager.SetRun(1)
        ns.Ipv4AddressGenerator.Reset()
        n = self.cfg.max_vehicles
        self.nodes = ns.NodeContainer()
        self.nodes.Create(n)
        wifi = ns.WifiHelper()
        wifi.SetStandard(getattr(ns, _STANDARDS[self.cfg.standard]))
        rate = ns.StringValue(_RATES[self.cfg.standard])
        wifi.SetRemoteStationManager("ns3::ConstantRateWifiManager", "DataMode", rate, "ControlMode", rate)
        phy = ns.YansWifiPhyHelper()
        phy.Set("TxPowerStart", ns.DoubleValue(self.cfg.tx_power_dbm))
        phy.Set("TxPowerEnd", ns.DoubleValue(self.cfg.tx_power_dbm))
        channel = ns.YansWifiChannelHelper()
        channel.SetPropagationDelay("ns3::ConstantSpeedPropagationDelayModel")
        frequency_hz = 5.2e9 if self.cfg.standard == "80211a" else 2.4e9
        reference_loss_db = 20.0 * math.log10(4.0 * math.pi * frequency_hz / 299_792_458.0)
        channel.AddPropagationLoss(
            "ns3::LogDistancePropagationLossModel",
            "Exponent",
            ns.DoubleValue(self.cfg.path_loss_exponent),
            "ReferenceLoss",
            ns.DoubleValue(reference_loss_db),
        )
        phy.SetChannel(channel.Create())
        mac = ns.WifiMacHelper()
        mac.SetType("ns3::AdhocWifiMac")
        devices = wifi.Install(phy, mac, self.nodes)
        mobility = ns.MobilityHelper()
        mobility.SetMobilityModel("ns3::ConstantPositionMobilityModel")
        mobility.Install(self.nodes)
        ns.InternetStackHelper().Install(self.nodes)
        addresses = ns.Ipv4AddressHelper()
        addresses.SetBase(ns.Ipv4Address("10.42.0.0"), ns.Ipv4Mask("255.255.255.0"))
        addresses.Assign(devices)
        # static ARP: a vehicle coming back into range is reachable at once (no 100 s "dead" ARP entry)
        ns.NeighborCacheHelper().PopulateNeighborCache()
        factory = ns.TypeId.LookupByName("ns3::UdpSocketFactory")
        self.sockets = []
        self.mobility = []
        for v in range(n):
            sock = ns.Socket.CreateSocket(self.nodes.Get(v), factory)
            sock.Bind(ns.InetSocketAddress(ns.Ipv4Address.GetAny(), PORT).ConvertTo())
            sock.SetAllowBroadcast(True)
            self.sockets.append(sock)
            self.mobility.append(self.nodes.Get(v).GetObject[ns.MobilityModel]())
            self.mobility[-1].SetPosition(ns.Vector(0.0, 0.0, -1000.0 * (v + 1)))  # far apart until placed
        self._sent: dict[int, Packet] = {}
        self._run_to(1_000_000)  # one empty millisecond: a broadcast before the first Run() crashes ns-3

    def _run_to(self, t_ns: int) -> None:
        ns = self.ns
        now = int(ns.Simulator.Now().GetNanoSeconds())
        if t_ns > now:
            ns.Simulator.Stop(ns.NanoSeconds(t_ns - now))
            ns.Simulator.Run()

    def _address(self, v: int) -> Any:
        ip = "10.42.0.255" if v == BROADCAST else f"10.42.0.{v + 1}"
        return self.ns.InetSocketAddress(self.ns.Ipv4Address(ip), PORT).ConvertTo()

    def step(self, t_ns: int, period_ns: int, positions: Mapping[int, Vec3], packets: Sequence[Packet]) -> StepResult:
        ns = self.ns
        for v, (n_m, e_m, d_m) in positions.items():
            if 0 <= v < len(self.mobility):
                self.mobility[v].SetPosition(ns.Vector(n_m, e_m, -d_m))
        start = max(t_ns, int(ns.Simulator.Now().GetNanoSeconds()))
        sendable = [pk for pk in packets if 0 <= pk.src < len(self.sockets)]
        gap = period_ns // (len(sendable) + 1)
        deliveries: list[Delivery] = []
        for i, pk in enumerate(sendable):
            self._run_to(start + (i + 1) * gap)
            self._collect(deliveries)
            p = ns.Packet(max(1, len(pk.payload)))
            self._sent[int(p.GetUid())] = pk
            self.sockets[pk.src].SendTo(p, 0, self._address(pk.dst))
        self._run_to(t_ns + period_ns)
        self._collect(deliveries)
        if len(self._sent) > 100_000:  # forget packets long gone
            for uid in sorted(self._sent)[:50_000]:
                del self._sent[uid]
        return StepResult(deliveries, [])

    def _collect(self, out: list[Delivery]) -> None:
        ns = self.ns
        now = int(ns.Simulator.Now().GetNanoSeconds())
        for v, sock in enumerate(self.sockets):
            while sock.GetRxAvailable() > 0:
                frm = ns.Address()
                p = sock.RecvFrom(frm)
                original = self._sent.get(int(p.GetUid()))
                if original is None or original.src == v:
                    continue
                pk = Packet(original.t_ns, original.src, v, original.port, original.seq, original.payload)
                out.append(Delivery(now, pk, math.nan))
