//! CanLink over the in-memory LoopbackCanBus, and over SocketCAN on a vcan interface. The SocketCAN
//! tests are `#[ignore = "needs vcan"]`: run them with `--ignored` where the kernel offers vcan
//! (scripts/test does), and they fail, not skip, when no interface can be had.

// Helpers outside #[test] functions are test code too; clippy.toml only exempts the latter.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::process::Command;
use std::sync::Mutex;
use std::thread;
use std::time::{Duration, Instant};

use hal::can::{CanBus, CanFrame, CanLink, LoopbackCanBus};
use hal::link::{Link, LinkError, MAX_LINK_PACKET_BYTES};
use protocol::frame::Framing;
use protocol::frame::can::{CanKind, can_id_destination, can_id_priority, can_id_source};
use protocol::message::{Heartbeat, Mode};
use protocol::{AnyMessage, NodeId, Priority};

const PACKETS_PER_NODE: u16 = 60;
/// Sizes at every segmentation boundary (classic single frame holds 7, FD 62; first frames 6
/// and 62 bytes of payload) and the largest packet.
const SIZES: [usize; 14] = [3, 6, 7, 8, 13, 14, 61, 62, 63, 64, 125, 126, 500, MAX_LINK_PACKET_BYTES];

/// Packet `seq` of node `sender`: its first bytes name both, the rest is derived from them, so
/// any receiver can check a packet without being told what was sent.
fn packet(sender: u8, seq: u16) -> Vec<u8> {
    let len = match seq as usize % (SIZES.len() + 3) {
        i if i < SIZES.len() => SIZES[i],
        _ => 3 + (usize::from(seq) * 7919 + usize::from(sender) * 31) % (MAX_LINK_PACKET_BYTES - 3),
    };
    let [s0, s1] = seq.to_le_bytes();
    let mut state = u64::from(seq) << 8 | u64::from(sender) | 1 << 40;
    let mut p = vec![sender, s0, s1];
    p.extend((3..len).map(|_| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state as u8
    }));
    p
}

/// Every node sends its packets, interleaved with the others', and receives everyone else's:
/// checks each arrives whole, once, in its sender's order, and that no node hears itself.
fn exchange<B: CanBus + 'static>(buses: Vec<B>) {
    let nodes = buses.len();
    let handles: Vec<_> = buses
        .into_iter()
        .enumerate()
        .map(|(index, bus)| {
            thread::spawn(move || {
                let me = index as u8 + 1;
                let mut link = CanLink::new(bus, NodeId(me));
                let mut next_seq = [0u16; 256];
                let expected_total = usize::from(PACKETS_PER_NODE) * (nodes - 1);
                let mut received = 0;
                let mut sent = 0u16;
                let mut buf = vec![0u8; MAX_LINK_PACKET_BYTES];
                let deadline = Instant::now() + Duration::from_secs(20);
                while sent < PACKETS_PER_NODE || received < expected_total {
                    assert!(Instant::now() < deadline, "node {me}: {received}/{expected_total} received");
                    if sent < PACKETS_PER_NODE {
                        link.send(&packet(me, sent)).unwrap();
                        sent += 1;
                    }
                    let wait = if sent < PACKETS_PER_NODE { Duration::ZERO } else { Duration::from_millis(100) };
                    while let Some(len) = link.recv(&mut buf, wait).unwrap() {
                        let got = &buf[..len];
                        let sender = got[0];
                        assert_ne!(sender, me, "node {me} received its own packet");
                        let seq = u16::from_le_bytes([got[1], got[2]]);
                        assert_eq!(seq, next_seq[usize::from(sender)], "node {me}: packet from {sender} out of order");
                        assert_eq!(
                            got,
                            packet(sender, seq).as_slice(),
                            "node {me}: packet {seq} from {sender} corrupted"
                        );
                        next_seq[usize::from(sender)] += 1;
                        received += 1;
                    }
                }
                link.counters()
            })
        })
        .collect();
    for handle in handles {
        let counters = handle.join().unwrap();
        assert_eq!(counters.packets_sent, u64::from(PACKETS_PER_NODE));
        assert_eq!(counters.packets_received, u64::from(PACKETS_PER_NODE) * (nodes as u64 - 1));
        assert_eq!(counters.rejected.total(), 0, "{counters:?}");
        assert_eq!(counters.dropped_frames, 0, "{counters:?}");
    }
}

/// Queues large enough that no thread falls behind by a whole queue, whatever the scheduler
/// does: this test is about interleaving, overflow has its own.
fn roomy_network(kind: CanKind) -> Vec<LoopbackCanBus> {
    LoopbackCanBus::network_with_queue(kind, 3, 1 << 17)
}

#[test]
fn loopback_classic_three_nodes_interleaved() {
    exchange(roomy_network(CanKind::Classic));
}

#[test]
fn loopback_fd_three_nodes_interleaved() {
    exchange(roomy_network(CanKind::Fd));
}

fn frame(id: u32, byte: u8) -> CanFrame {
    CanFrame::new(id, &[byte; 8]).unwrap()
}

#[test]
fn loopback_delivers_to_every_other_node_in_send_order_but_not_to_the_sender() {
    let mut nodes = LoopbackCanBus::network(CanKind::Classic, 3);
    nodes[0].send(&frame(0x100, 1)).unwrap();
    nodes[1].send(&frame(0x200, 2)).unwrap();
    nodes[0].send(&frame(0x100, 3)).unwrap();
    let ids = |bus: &mut LoopbackCanBus| {
        let mut seen = Vec::new();
        while let Some(f) = bus.recv(Duration::ZERO).unwrap() {
            seen.push((f.id, f.data[0]));
        }
        seen
    };
    assert_eq!(ids(&mut nodes[2]), [(0x100, 1), (0x200, 2), (0x100, 3)]);
    assert_eq!(ids(&mut nodes[1]), [(0x100, 1), (0x100, 3)]);
    assert_eq!(ids(&mut nodes[0]), [(0x200, 2)]);
}

#[test]
fn loopback_overflow_drops_oldest_and_counts() {
    let mut nodes = LoopbackCanBus::network_with_queue(CanKind::Classic, 2, 4);
    for i in 0..10 {
        nodes[0].send(&frame(0x10, i)).unwrap();
    }
    let mut kept = Vec::new();
    while let Some(f) = nodes[1].recv(Duration::ZERO).unwrap() {
        kept.push(f.data[0]);
    }
    assert_eq!(kept, [6, 7, 8, 9]);
    assert_eq!(nodes[1].dropped_frames(), 6);
    assert_eq!(nodes[0].dropped_frames(), 0);
}

#[test]
fn overflow_shows_as_lost_packet_not_corruption() {
    // A node that does not keep up loses frames; the link drops the damaged packets and still
    // delivers whole later ones.
    let mut nodes = LoopbackCanBus::network_with_queue(CanKind::Classic, 2, 200).into_iter();
    let (tx, rx) = (nodes.next().unwrap(), nodes.next().unwrap());
    let mut tx = CanLink::new(tx, NodeId(1));
    let mut rx = CanLink::new(rx, NodeId(2));
    for seq in 0..3 {
        tx.send(&packet(1, 13 + seq)).unwrap(); // 1070 bytes each: 153 frames
    }
    let mut buf = vec![0u8; MAX_LINK_PACKET_BYTES];
    while rx.recv(&mut buf, Duration::ZERO).unwrap().is_some() {}
    let last = packet(1, 100);
    tx.send(&last).unwrap();
    let len = rx.recv(&mut buf, Duration::from_secs(1)).unwrap().unwrap();
    assert_eq!(&buf[..len], last.as_slice());
    let counters = rx.counters();
    assert!(counters.dropped_frames > 0, "{counters:?}");
    assert!(counters.rejected.total() > 0, "{counters:?}");
}

#[test]
fn recv_times_out_with_none() {
    let mut nodes = LoopbackCanBus::network(CanKind::Fd, 2).into_iter();
    let mut link = CanLink::new(nodes.next().unwrap(), NodeId(1));
    assert_eq!(link.framing(), Framing::Can(CanKind::Fd));
    let mut buf = vec![0u8; MAX_LINK_PACKET_BYTES];
    let start = Instant::now();
    assert_eq!(link.recv(&mut buf, Duration::from_millis(100)).unwrap(), None);
    let waited = start.elapsed();
    assert!(waited >= Duration::from_millis(100) && waited < Duration::from_secs(1), "{waited:?}");
}

#[test]
fn can_id_carries_message_priority_destination_and_link_node() {
    let heartbeat =
        AnyMessage::Heartbeat(Heartbeat { node: NodeId(3), stamp_ns: 1, uptime_ms: 2, boot_id: 3, mode: Mode::Idle });
    let mut encoded = [0u8; MAX_LINK_PACKET_BYTES];
    let len = protocol::encode(&heartbeat, NodeId(3), NodeId::GROUND, 9, &mut encoded).unwrap();
    let encoded = &encoded[..len];

    let mut nodes = LoopbackCanBus::network(CanKind::Classic, 2).into_iter();
    let mut link = CanLink::new(nodes.next().unwrap(), NodeId(3));
    let mut raw = nodes.next().unwrap();
    link.send(encoded).unwrap();
    let first = raw.recv(Duration::from_secs(1)).unwrap().unwrap();
    assert_eq!(first.id, link.can_id_for(encoded));
    assert_eq!(can_id_priority(first.id), Some(Priority::Control));
    assert_eq!(can_id_source(first.id), NodeId(3));
    assert_eq!(can_id_destination(first.id), NodeId::GROUND);

    // Not a packet: lowest priority, to everyone.
    let opaque = link.can_id_for(&[0xFF; 20]);
    assert_eq!(can_id_priority(opaque), Some(Priority::Bulk));
    assert_eq!(can_id_destination(opaque), NodeId::BROADCAST);
    assert_eq!(can_id_source(opaque), NodeId(3));
}

#[test]
fn bus_refuses_frames_it_cannot_carry() {
    let mut nodes = LoopbackCanBus::network(CanKind::Classic, 2);
    let fd_frame = CanFrame::new(0x1, &[0; 12]).unwrap();
    assert!(matches!(nodes[0].send(&fd_frame), Err(LinkError::CanFrameTooLong { len: 12, max: 8 })));
    let wide = CanFrame { id: 0x2000_0000, len: 1, data: [0; 64], extended: true };
    assert!(nodes[0].send(&wide).is_err());
    let mut link = CanLink::new(nodes.pop().unwrap(), NodeId(1));
    assert!(matches!(link.send(&vec![0; MAX_LINK_PACKET_BYTES + 1]), Err(LinkError::PacketTooLarge { .. })));
}

/// A vcan interface for one test. `HAL_VCAN` names an existing one (scripts/test creates `vcan0`
/// as root with FD's mtu, so the test binary itself needs no privileges); without it the test
/// creates its own, which needs root or CAP_NET_ADMIN, and removes it on drop.
struct Vcan {
    name: String,
    owned: bool,
}

/// The interface named by `HAL_VCAN` is shared by both SocketCAN tests, which run in parallel
/// threads: their nodes use the same ids, so they would receive each other's packets.
static SHARED_VCAN: Mutex<()> = Mutex::new(());

/// CAN_MTU and CANFD_MTU: an interface carries FD frames only with the larger mtu.
const CAN_MTU: u32 = 16;
const CANFD_MTU: u32 = 72;
/// ARPHRD_CAN, the link type of every SocketCAN interface.
const ARPHRD_CAN: u32 = 280;

impl Vcan {
    /// Panics with the reason when no usable interface exists: these tests are ignored unless
    /// asked for, and when asked for, a missing vcan is a failure, not a pass.
    fn get(kind: CanKind) -> Vcan {
        if let Ok(name) = std::env::var("HAL_VCAN") {
            if let Err(reason) = check_existing(&name, kind) {
                panic!("needs vcan: HAL_VCAN={name} is not usable: {reason}");
            }
            return Vcan { name, owned: false };
        }
        Vcan::create(kind).unwrap_or_else(|reason| {
            panic!(
                "needs vcan and none could be created ({reason}); creating one takes a kernel with vcan \
                 and root or CAP_NET_ADMIN. Or create one as root (`modprobe vcan && ip link add dev vcan0 \
                 type vcan && ip link set vcan0 mtu {CANFD_MTU} up`) and set HAL_VCAN=vcan0, as scripts/test \
                 does where it can"
            )
        })
    }

    fn create(kind: CanKind) -> Result<Vcan, String> {
        let suffix = if kind == CanKind::Fd { 'f' } else { 'c' };
        let name = format!("vhal{}{suffix}", std::process::id() % 100_000);
        run(&["link", "add", "dev", &name, "type", "vcan"])?;
        let vcan = Vcan { name, owned: true };
        if kind == CanKind::Fd {
            run(&["link", "set", "dev", &vcan.name, "mtu", &CANFD_MTU.to_string()])?;
        }
        run(&["link", "set", "dev", &vcan.name, "up"])?;
        Ok(vcan)
    }
}

impl Drop for Vcan {
    fn drop(&mut self) {
        if self.owned {
            let _ = run(&["link", "del", "dev", &self.name]);
        }
    }
}

/// Whether `name` is an up CAN interface that carries frames of `kind`.
fn check_existing(name: &str, kind: CanKind) -> Result<(), String> {
    let read = |attribute: &str| -> Result<u32, String> {
        let path = format!("/sys/class/net/{name}/{attribute}");
        let text = std::fs::read_to_string(&path).map_err(|e| format!("cannot read {path}: {e}"))?;
        let text = text.trim();
        let parsed = match text.strip_prefix("0x") {
            Some(hex) => u32::from_str_radix(hex, 16),
            None => text.parse(),
        };
        parsed.map_err(|e| format!("{path}: {text:?}: {e}"))
    };
    if read("type")? != ARPHRD_CAN {
        return Err("not a CAN interface".into());
    }
    if read("flags")? & 1 == 0 {
        return Err(format!("interface is down (`ip link set {name} up`)"));
    }
    let mtu = read("mtu")?;
    let needed = if kind == CanKind::Fd { CANFD_MTU } else { CAN_MTU };
    if mtu < needed {
        return Err(format!(
            "mtu {mtu}, {kind:?} frames need {needed} (`ip link set {name} mtu {needed}`, while down)"
        ));
    }
    Ok(())
}

fn run(args: &[&str]) -> Result<(), String> {
    let output = Command::new("ip").args(args).output().map_err(|e| format!("cannot run `ip`: {e}"))?;
    if output.status.success() {
        Ok(())
    } else {
        Err(format!("`ip {}` failed: {}", args.join(" "), String::from_utf8_lossy(&output.stderr).trim()))
    }
}

fn socketcan_exchange(kind: CanKind) {
    let vcan = Vcan::get(kind);
    let _exclusive = (!vcan.owned).then(|| SHARED_VCAN.lock().unwrap_or_else(|poisoned| poisoned.into_inner()));
    let buses: Vec<hal::can::SocketCanBus> =
        (0..3).map(|_| hal::can::SocketCanBus::open(&vcan.name, kind).unwrap()).collect();
    assert_eq!(buses[0].kind(), kind);
    exchange(buses);
}

// Ignored by default because vcan needs kernel support and root, which a plain `cargo test` cannot
// assume; scripts/test runs them wherever it can create vcan and reports them as not run elsewhere.
#[test]
#[ignore = "needs vcan"]
fn socketcan_classic_three_nodes_on_vcan() {
    socketcan_exchange(CanKind::Classic);
}

#[test]
#[ignore = "needs vcan"]
fn socketcan_fd_three_nodes_on_vcan() {
    socketcan_exchange(CanKind::Fd);
}
