//! The radio between the robots of a simulated team, for the process runner: UDP on 127.0.0.1
//! through one [`hal::emulator::DuplexEmulator`] per pair of robots, on the wall clock.
//!
//! Robot `a`'s comms process has one UDP team link; its peers are the relay's sockets
//! `S[a][b]`, one per other robot `b`. A datagram arriving on `S[a][b]` is robot `a` talking to
//! `b`: it enters the `a → b` direction of the pair's emulator, and what the emulator delivers
//! leaves from `S[b][a]` to robot `b`'s link, so `b` sees it come from its configured peer
//! address. Datagrams are the emulator's packets (the link's fragments, each charged by the
//! emulator's framing), so loss hits fragments as a real radio's would.

use std::collections::BTreeMap;
use std::io::ErrorKind;
use std::net::{SocketAddr, UdpSocket};

use hal::emulator::{DuplexEmulator, EmulatorConfig, Side};

/// Larger than any datagram the UDP link sends.
const DATAGRAM_MAX: usize = 2048;
/// Datagrams taken from one socket per pump at most.
const MAX_PER_PUMP: usize = 256;

#[derive(Debug, thiserror::Error)]
pub enum RelayError {
    #[error("relay socket: {0}")]
    Socket(std::io::Error),
}

/// Counters of the relay.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RelayStats {
    pub received: u64,
    pub forwarded: u64,
    pub send_errors: u64,
    /// Datagrams before the destination robot's address was known.
    pub unroutable: u64,
}

/// See the module documentation.
#[derive(Debug)]
pub struct Relay {
    robots: usize,
    /// `sockets[a][b]`: robot `a`'s peer address for robot `b` (`None` for `a == b`).
    sockets: Vec<Vec<Option<UdpSocket>>>,
    /// Each robot's team-link address.
    robot_addrs: Vec<Option<SocketAddr>>,
    /// Pair `(a, b)`, `a < b`; side A is robot `a`.
    radios: BTreeMap<(usize, usize), DuplexEmulator>,
    buf: Box<[u8]>,
    stats: RelayStats,
}

impl Relay {
    /// Binds the sockets for `robots` robots; the pair `(a, b)`'s emulator is `radio` with the
    /// same seed the lockstep runner gives that pair.
    pub fn bind(robots: usize, radio: &EmulatorConfig, seed: u64) -> Result<Relay, RelayError> {
        let mut sockets = Vec::with_capacity(robots);
        for a in 0..robots {
            let mut row = Vec::with_capacity(robots);
            for b in 0..robots {
                row.push(if a == b {
                    None
                } else {
                    let socket = UdpSocket::bind("127.0.0.1:0").map_err(RelayError::Socket)?;
                    socket.set_nonblocking(true).map_err(RelayError::Socket)?;
                    Some(socket)
                });
            }
            sockets.push(row);
        }
        let mut radios = BTreeMap::new();
        for a in 0..robots {
            for b in a + 1..robots {
                let pair_seed = seed.wrapping_mul(1_000_003).wrapping_add((a * 64 + b) as u64);
                radios.insert((a, b), DuplexEmulator::symmetric(radio.clone().with_seed(pair_seed)));
            }
        }
        Ok(Relay {
            robots,
            sockets,
            robot_addrs: vec![None; robots],
            radios,
            buf: vec![0; DATAGRAM_MAX].into_boxed_slice(),
            stats: RelayStats::default(),
        })
    }

    /// The address robot `robot` sends to for `peer`.
    pub fn peer_addr(&self, robot: usize, peer: usize) -> Option<SocketAddr> {
        self.sockets.get(robot)?.get(peer)?.as_ref()?.local_addr().ok()
    }

    /// Where robot `robot`'s team link receives.
    pub fn set_robot_addr(&mut self, robot: usize, addr: SocketAddr) {
        if let Some(slot) = self.robot_addrs.get_mut(robot) {
            *slot = Some(addr);
        }
    }

    pub fn stats(&self) -> RelayStats {
        self.stats
    }

    /// Moves what arrived into the emulators and what they deliver by `now_ms` to the robots.
    pub fn pump(&mut self, now_ms: u64) {
        for a in 0..self.robots {
            for b in 0..self.robots {
                let Some(Some(socket)) = self.sockets.get(a).and_then(|row| row.get(b)) else { continue };
                for _ in 0..MAX_PER_PUMP {
                    match socket.recv_from(&mut self.buf) {
                        Ok((len, _)) => {
                            self.stats.received += 1;
                            let (pair, side) = if a < b { ((a, b), Side::A) } else { ((b, a), Side::B) };
                            if let (Some(radio), Some(bytes)) = (self.radios.get_mut(&pair), self.buf.get(..len)) {
                                radio.send(side, now_ms, bytes);
                            }
                        }
                        Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                        // ICMP port-unreachable from a robot that is restarting, and the like.
                        Err(_) => {}
                    }
                }
            }
        }
        for (&(a, b), radio) in &mut self.radios {
            for (to, from, side) in [(b, a, Side::B), (a, b, Side::A)] {
                while let Some(packet) = radio.poll(side, now_ms) {
                    let socket = self.sockets.get(to).and_then(|row| row.get(from)).and_then(Option::as_ref);
                    match (socket, self.robot_addrs.get(to).copied().flatten()) {
                        (Some(socket), Some(addr)) => match socket.send_to(&packet, addr) {
                            Ok(_) => self.stats.forwarded += 1,
                            Err(_) => self.stats.send_errors += 1,
                        },
                        _ => self.stats.unroutable += 1,
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use protocol::frame::Framing;
    use std::time::Duration;

    #[test]
    fn datagrams_cross_the_emulated_radio_to_the_peer() {
        let radio = EmulatorConfig::ideal(1_000_000, Framing::Datagram { mtu: 1200 });
        let mut relay = Relay::bind(3, &radio, 1).unwrap();
        let robot: Vec<UdpSocket> = (0..3).map(|_| UdpSocket::bind("127.0.0.1:0").unwrap()).collect();
        for (i, s) in robot.iter().enumerate() {
            relay.set_robot_addr(i, s.local_addr().unwrap());
            s.set_read_timeout(Some(Duration::from_millis(500))).unwrap();
        }
        robot[0].send_to(b"hello two", relay.peer_addr(0, 2).unwrap()).unwrap();
        robot[2].send_to(b"hello one", relay.peer_addr(2, 1).unwrap()).unwrap();
        std::thread::sleep(Duration::from_millis(20));
        relay.pump(0);
        relay.pump(10);
        let mut buf = [0u8; 64];
        let (len, from) = robot[2].recv_from(&mut buf).unwrap();
        assert_eq!(&buf[..len], b"hello two");
        assert_eq!(from, relay.peer_addr(2, 0).unwrap(), "arrives from robot 2's address for robot 0");
        let (len, from) = robot[1].recv_from(&mut buf).unwrap();
        assert_eq!(&buf[..len], b"hello one");
        assert_eq!(from, relay.peer_addr(1, 2).unwrap());
        assert_eq!(relay.stats().forwarded, 2);
        assert!(relay.peer_addr(1, 1).is_none());
    }
}
