#!/usr/bin/env python3
"""The python-canopen peer of hal/tests/interop_canopen.rs.

python-canopen (2.4.1) on python-can's `slcan` interface (4.6.1), on a pty whose other end is
our SlcanAdapter bridging to a LoopbackCanBus, so every frame crosses a real serial line and a
third-party CANopen stack:

  client CHANNEL   python is the NMT master and SDO client; our emulated wheel drives
                   (0x11-0x14) and pan-tilt head (0x20) are the devices.
  device CHANNEL   python is wheel drive 0x14 (a canopen.LocalNode with heartbeat, answering
                   SYNC with TPDO1); our CanopenMaster runs the network.

Results go to stdout as `key=value` lines for the Rust test to check; a failure prints
`error=...` and exits with status 1.
"""

import collections
import struct
import sys
import threading
import time

import canopen
from canopen.objectdictionary import UNSIGNED16, ODVariable

DRIVES = (0x11, 0x12, 0x13, 0x14)
HEAD = 0x20
PYTHON_DRIVE = 0x14
SYNC_PERIOD_S = 0.02


def emit(**values):
    for key, value in values.items():
        print(f"{key}={value}", flush=True)


def fail(message):
    print(f"error={message}", flush=True)
    sys.exit(1)


def connect(channel):
    network = canopen.Network()
    # No 2 s pause after opening: that is for real adapters that reset when the port opens.
    network.connect(interface="slcan", channel=channel, bitrate=1_000_000, sleep_after_open=0)
    return network


class Recorder:
    """Raw frames of some ids with their arrival times (python-can stamps them on reception)."""

    def __init__(self, network, ids):
        self.lock = threading.Lock()
        self.frames = collections.defaultdict(list)
        for can_id in ids:
            network.subscribe(can_id, self.on_frame)

    def on_frame(self, can_id, data, timestamp):
        with self.lock:
            self.frames[can_id].append((timestamp, bytes(data)))

    def get(self, can_id, since=0.0):
        with self.lock:
            return [(t, d) for t, d in self.frames[can_id] if t >= since]


def wait_for_state(node, wanted, timeout_s):
    deadline = time.monotonic() + timeout_s
    state = None
    while time.monotonic() < deadline:
        try:
            state = node.nmt.wait_for_heartbeat(timeout=max(0.01, deadline - time.monotonic()))
        except canopen.nmt.NmtError:
            break
        if state == wanted:
            return state
    return state


def client(channel):
    network = connect(channel)
    ids = [0x700 + n for n in DRIVES + (HEAD,)] + [0x180 + n for n in DRIVES + (HEAD,)]
    recorder = Recorder(network, ids)
    drive = network.add_node(canopen.RemoteNode(DRIVES[0], canopen.ObjectDictionary()))
    head = network.add_node(canopen.RemoteNode(HEAD, canopen.ObjectDictionary()))

    # Nobody has started our devices: they sit in pre-operational.
    emit(state_before=drive.nmt.wait_for_heartbeat(timeout=2.0))
    started = time.monotonic()
    network.nmt.state = "OPERATIONAL"  # NMT start to node 0: all nodes
    emit(state_after=wait_for_state(drive, "OPERATIONAL", 2.0))
    emit(head_state_after=wait_for_state(head, "OPERATIONAL", 2.0))
    emit(start_to_operational_s=f"{time.monotonic() - started:.3f}")

    emit(device_type=f"{struct.unpack('<I', drive.sdo.upload(0x1000, 0))[0]:#010x}")
    emit(head_device_type=f"{struct.unpack('<I', head.sdo.upload(0x1000, 0))[0]:#010x}")
    emit(vendor_id=f"{struct.unpack('<I', drive.sdo.upload(0x1018, 1))[0]:#010x}")
    emit(heartbeat_ms_before=struct.unpack("<H", drive.sdo.upload(0x1017, 0))[0])
    drive.sdo.download(0x1017, 0, struct.pack("<H", 50))
    written = time.time()
    emit(heartbeat_ms_after=struct.unpack("<H", drive.sdo.upload(0x1017, 0))[0])
    try:
        drive.sdo.upload(0x6064, 0)
        emit(abort_code="none")
    except canopen.SdoAbortedError as error:
        emit(abort_code=f"{error.code:#010x}")

    # Heartbeats of the drive after the write: every 50 ms.
    time.sleep(0.6)
    beats = [t for t, d in recorder.get(0x700 + DRIVES[0], since=written + 0.06)]
    intervals = [b - a for a, b in zip(beats, beats[1:])]
    emit(heartbeat_interval_ms=f"{1000 * sum(intervals) / max(1, len(intervals)):.1f}")
    emit(heartbeats={f"{n:#x}": len(recorder.get(0x700 + n)) for n in DRIVES + (HEAD,)})

    # SYNC at 50 Hz: every drive and the head answer each with TPDO1.
    syncs = 25
    first_sync = time.time()
    for _ in range(syncs):
        network.sync.transmit()
        time.sleep(SYNC_PERIOD_S)
    time.sleep(0.05)
    emit(syncs=syncs)
    emit(tpdos=",".join(str(len(recorder.get(0x180 + n, since=first_sync))) for n in DRIVES + (HEAD,)))
    fl = recorder.get(0x180 + DRIVES[0], since=first_sync)
    (t0, d0), (t1, d1) = fl[0], fl[-1]
    p0, v0 = struct.unpack("<ii", d0)
    p1, _ = struct.unpack("<ii", d1)
    emit(fl_velocity_counts_per_s=v0)
    emit(fl_position_rate_counts_per_s=f"{(p1 - p0) / (t1 - t0):.0f}")

    # Head: RPDO1 target (micro-radians), then a SYNC to read where it is.
    network.send_message(0x200 + HEAD, struct.pack("<ii", 300_000, -200_000))
    time.sleep(0.5)
    since = time.time()
    network.sync.transmit()
    time.sleep(0.05)
    head_pdos = recorder.get(0x180 + HEAD, since=since)
    if not head_pdos:
        fail("no head TPDO after the RPDO")
    pan, tilt = struct.unpack("<ii", head_pdos[-1][1])
    emit(head_pan_microrad=pan, head_tilt_microrad=tilt)
    network.disconnect()


def device(channel):
    network = connect(channel)
    od = canopen.ObjectDictionary()
    heartbeat = ODVariable("Producer heartbeat time", 0x1017, 0)
    heartbeat.data_type = UNSIGNED16
    heartbeat.access_type = "rw"
    heartbeat.default = 100
    od.add_object(heartbeat)
    node = canopen.LocalNode(PYTHON_DRIVE, od)
    network.add_node(node)

    nmt = []
    network.subscribe(0x000, lambda can_id, data, t: nmt.append(bytes(data)))
    counters = {"syncs": 0, "tpdos": 0}

    def on_sync(can_id, data, timestamp):
        counters["syncs"] += 1
        if node.nmt.state == "OPERATIONAL":
            # Position 1000 counts per SYNC received: the master can check it saw every one.
            position = 1000 * counters["syncs"]
            network.send_message(0x180 + PYTHON_DRIVE, struct.pack("<ii", position, 50_000))
            counters["tpdos"] += 1

    network.subscribe(0x080, on_sync)
    booted = time.monotonic()
    node.nmt.send_command(0x81)  # reset node: state initialising, boot-up message sent
    node.nmt.send_command(0x80)  # pre-operational: heartbeat starts with 0x1017
    while node.nmt.state != "OPERATIONAL" and time.monotonic() - booted < 2.0:
        time.sleep(0.001)
    if node.nmt.state != "OPERATIONAL":
        fail(f"no NMT start after boot-up (state {node.nmt.state}, NMT frames {nmt})")
    emit(boot_to_operational_ms=f"{1000 * (time.monotonic() - booted):.1f}")
    time.sleep(1.0)
    node.emcy.send(0x2310, 0x03)
    time.sleep(0.3)
    node.emcy.reset()
    time.sleep(0.3)
    emit(nmt_frames=" ".join(f.hex() for f in nmt))
    emit(syncs=counters["syncs"], tpdos=counters["tpdos"])
    node.nmt.stop_heartbeat()
    network.disconnect()


def main():
    if len(sys.argv) != 3 or sys.argv[1] not in ("client", "device"):
        fail(f"usage: {sys.argv[0]} client|device CHANNEL")
    try:
        {"client": client, "device": device}[sys.argv[1]](sys.argv[2])
    except Exception as error:  # noqa: BLE001 - the Rust test needs the reason on stdout
        fail(f"{type(error).__name__}: {error}")


if __name__ == "__main__":
    main()
