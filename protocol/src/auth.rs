//! Authentication of uplink commands: HMAC-SHA256 truncated to 16 bytes over header, body and a
//! monotonic counter, and a replay guard that accepts each sender's counters only increasing.
//!
//! The counter is the sender's, persisted across its restarts; the receiver persists the last
//! accepted counter per sender, so a packet recorded before a restart cannot be replayed after.

use hmac::{Hmac, KeyInit, Mac};
use sha2::Sha256;

use crate::codec::{DecodeError, decode_header};
use crate::ids::NodeId;

/// Bytes of the truncated MAC (RFC 2104 allows truncation to half the hash; 128 bits here).
pub const TAG_BYTES: usize = 16;
pub const COUNTER_BYTES: usize = 8;
pub const AUTH_TRAILER_BYTES: usize = COUNTER_BYTES + TAG_BYTES;
/// Shortest accepted key: the full 256 bits of SHA-256's block security are not needed, but a
/// key shorter than the tag would be the weakest link.
pub const MIN_KEY_BYTES: usize = 16;
pub const MAX_KEY_BYTES: usize = 64;

type HmacSha256 = Hmac<Sha256>;

/// A shared secret for command authentication. Never logged: `Debug` prints only its length.
#[derive(Clone)]
pub struct AuthKey {
    bytes: [u8; MAX_KEY_BYTES],
    len: usize,
}

impl core::fmt::Debug for AuthKey {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "AuthKey({} bytes, redacted)", self.len)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum AuthError {
    #[error("key must be {MIN_KEY_BYTES}..={MAX_KEY_BYTES} bytes, got {0}")]
    KeyLength(usize),
    #[error("packet is not authenticated")]
    NotAuthenticated,
    #[error("packet malformed: {0}")]
    Malformed(DecodeError),
    #[error("MAC does not match (forged or corrupted)")]
    BadTag,
    #[error("replayed: counter {counter} from node {} is not above {last}", sender.0)]
    Replayed { sender: NodeId, counter: u64, last: u64 },
    #[error("replay guard full: no room for another sender")]
    TooManySenders,
}

impl AuthKey {
    pub fn from_bytes(key: &[u8]) -> Result<Self, AuthError> {
        if !(MIN_KEY_BYTES..=MAX_KEY_BYTES).contains(&key.len()) {
            return Err(AuthError::KeyLength(key.len()));
        }
        let mut bytes = [0u8; MAX_KEY_BYTES];
        bytes[..key.len()].copy_from_slice(key);
        Ok(AuthKey { bytes, len: key.len() })
    }

    fn mac(&self) -> HmacSha256 {
        // HMAC accepts keys of any length, and ours is already bounded: this cannot fail.
        match HmacSha256::new_from_slice(&self.bytes[..self.len]) {
            Ok(mac) => mac,
            Err(_) => unreachable!("HMAC-SHA256 accepts keys of every length"),
        }
    }

    /// The truncated tag of `signed` (header, body and counter).
    pub fn tag(&self, signed: &[u8]) -> [u8; TAG_BYTES] {
        let mut mac = self.mac();
        mac.update(signed);
        let full = mac.finalize().into_bytes();
        let mut tag = [0u8; TAG_BYTES];
        tag.copy_from_slice(&full[..TAG_BYTES]);
        tag
    }

    /// Checks the MAC of a whole authenticated packet in constant time and returns the sender
    /// and its counter. Does not check for replay: see [`ReplayGuard`].
    pub fn verify(&self, packet: &[u8]) -> Result<(NodeId, u64), AuthError> {
        let (header, _) = decode_header(packet).map_err(AuthError::Malformed)?;
        if !header.flags.authenticated() {
            return Err(AuthError::NotAuthenticated);
        }
        if packet.len() < AUTH_TRAILER_BYTES {
            return Err(AuthError::Malformed(DecodeError::TruncatedTrailer));
        }
        let (signed, tag) = packet.split_at(packet.len() - TAG_BYTES);
        let mut mac = self.mac();
        mac.update(signed);
        mac.verify_truncated_left(tag).map_err(|_| AuthError::BadTag)?;
        let mut counter = [0u8; COUNTER_BYTES];
        counter.copy_from_slice(&signed[signed.len() - COUNTER_BYTES..]);
        Ok((header.source, u64::from_le_bytes(counter)))
    }
}

/// Last accepted counter per sender, for up to `N` senders.
#[derive(Debug, Clone, Default)]
pub struct ReplayGuard<const N: usize> {
    last: heapless::Vec<(NodeId, u64), N>,
}

impl<const N: usize> ReplayGuard<N> {
    pub fn new() -> Self {
        ReplayGuard { last: heapless::Vec::new() }
    }

    /// Restores persisted state (e.g. after a restart).
    pub fn restore(entries: &[(NodeId, u64)]) -> Result<Self, AuthError> {
        let mut guard = Self::new();
        for &(source, counter) in entries {
            guard.last.push((source, counter)).map_err(|_| AuthError::TooManySenders)?;
        }
        Ok(guard)
    }

    /// The state to persist.
    pub fn entries(&self) -> &[(NodeId, u64)] {
        &self.last
    }

    /// Accepts `counter` from `source` if it is above every counter accepted from it before.
    pub fn accept(&mut self, source: NodeId, counter: u64) -> Result<(), AuthError> {
        match self.last.iter_mut().find(|(node, _)| *node == source) {
            Some((_, last)) if counter <= *last => Err(AuthError::Replayed { sender: source, counter, last: *last }),
            Some((_, last)) => {
                *last = counter;
                Ok(())
            }
            None => self.last.push((source, counter)).map_err(|_| AuthError::TooManySenders),
        }
    }
}
