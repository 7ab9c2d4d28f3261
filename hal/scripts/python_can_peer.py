#!/usr/bin/env python3
"""python-can's slcan interface as the host in front of hal's SlcanAdapter (tests/interop_python_can.rs).

Usage: python_can_peer.py CHANNEL BITRATE EXPECT < frames

stdin:  frames to send, one per line: "<extended 0|1> <id hex> <data hex, or - for none>".
stdout: "version <hw> <sw>" and "serial <number>" as python-can's queries read them, then one
        line per frame received, "frame <extended> <id hex> <dlc> <data hex or -> <remote> <fd>",
        then "done". Receives until EXPECT frames came or 3 s passed; the caller compares.
"""

import sys
import time

import can


def parse_frame(line: str) -> can.Message:
    extended, can_id, data = line.split()
    return can.Message(
        arbitration_id=int(can_id, 16),
        is_extended_id=extended == "1",
        data=b"" if data == "-" else bytes.fromhex(data),
    )


def describe(msg: can.Message) -> str:
    data = msg.data.hex() if msg.data else "-"
    return (
        f"frame {int(msg.is_extended_id)} {msg.arbitration_id:x} {msg.dlc} {data} "
        f"{int(msg.is_remote_frame)} {int(msg.is_fd)}"
    )


def main() -> int:
    channel, bitrate, expect = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    to_send = [parse_frame(line) for line in sys.stdin if line.strip()]
    # python-can sleeps 2 s after opening the port by default, for adapters that reset when
    # the port opens (Arduino-based ones); the emulated adapter is ready at once.
    bus = can.Bus(interface="slcan", channel=channel, bitrate=bitrate, sleep_after_open=0)
    try:
        hw, sw = bus.get_version(timeout=1)
        print(f"version {hw} {sw}")
        print(f"serial {bus.get_serial_number(timeout=1)}")
        for msg in to_send:
            bus.send(msg)
        received = []
        deadline = time.monotonic() + 3
        while len(received) < expect and time.monotonic() < deadline:
            msg = bus.recv(timeout=0.1)
            if msg is not None:
                received.append(msg)
        for msg in received:
            print(describe(msg))
        print("done", flush=True)
    finally:
        bus.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
