//! The decoder is total: a million random and mutated byte strings give a packet or a typed
//! error, never a panic; mutated authenticated packets never pass the MAC check.

mod common;

use std::collections::BTreeMap;

use common::{any_message, encode_any, test_key};
use proptest::strategy::{Strategy, ValueTree};
use proptest::test_runner::TestRunner;
use protocol::{MAX_PACKET_BYTES, decode};

/// SplitMix64: a tiny deterministic generator, so the million cases are the same on every run.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

fn corpus(count: usize) -> Vec<Vec<u8>> {
    let mut runner = TestRunner::deterministic();
    let strategy = any_message();
    (0..count)
        .map(|i| {
            let Ok(tree) = strategy.new_tree(&mut runner) else { panic!("strategy failed to generate") };
            let message = tree.current();
            let mut buf = [0u8; MAX_PACKET_BYTES];
            let len = encode_any(&message, i as u32, &mut buf);
            buf[..len].to_vec()
        })
        .collect()
}

/// One of several mutations a corrupting link or an attacker could apply.
fn mutate(rng: &mut SplitMix64, original: &[u8], other: &[u8], out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(original);
    let rounds = 1 + rng.below(4);
    for _ in 0..rounds {
        match rng.below(8) {
            0 if !out.is_empty() => {
                let i = rng.below(out.len());
                out[i] ^= 1 << rng.below(8);
            }
            1 if !out.is_empty() => {
                let i = rng.below(out.len());
                out[i] = rng.next() as u8;
            }
            2 if !out.is_empty() => {
                let keep = rng.below(out.len());
                out.truncate(keep);
            }
            3 => {
                let n = 1 + rng.below(16);
                out.extend((0..n).map(|_| rng.next() as u8));
            }
            4 if !out.is_empty() => {
                let i = rng.below(out.len());
                out.remove(i);
            }
            5 => {
                let i = rng.below(out.len() + 1);
                out.insert(i, rng.next() as u8);
            }
            6 if !other.is_empty() => {
                // Splice: head of this packet, tail of another.
                let i = rng.below(out.len() + 1);
                let j = rng.below(other.len());
                out.truncate(i);
                out.extend_from_slice(&other[j..]);
            }
            7 if out.len() > 6 => {
                // Header fields are where a decoder is most tempted to trust the input.
                let i = rng.below(7);
                out[i] = [0u8, 1, 2, 0x7F, 0x80, 0xFF][rng.below(6)];
            }
            _ => {}
        }
    }
}

#[test]
fn a_million_random_and_mutated_inputs_never_panic() {
    const CASES: usize = 1_000_000;
    let corpus = corpus(2_000);
    let key = test_key();
    let mut rng = SplitMix64(0x5EED_2026);
    let mut input = Vec::with_capacity(2 * MAX_PACKET_BYTES);
    let mut outcomes: BTreeMap<String, usize> = BTreeMap::new();
    let mut forged_accepted = 0usize;

    for case in 0..CASES {
        let original_index = rng.below(corpus.len());
        let original = &corpus[original_index];
        if case % 4 == 0 {
            // Pure noise of any length a link could deliver.
            let len = rng.below(2 * MAX_PACKET_BYTES);
            input.clear();
            input.extend((0..len).map(|_| rng.next() as u8));
        } else {
            let other = &corpus[rng.below(corpus.len())];
            mutate(&mut rng, original, other, &mut input);
        }

        let outcome = match decode(&input) {
            Ok(packet) => {
                // Whatever decodes must re-encode to a fixed point: encode(decode(encode(m)))
                // gives the same bytes (compared as bytes, since a mutated float may be NaN).
                let mut first = [0u8; MAX_PACKET_BYTES];
                let first_len = encode_any(&packet.message, packet.header.seq, &mut first);
                let again = decode(&first[..first_len]).unwrap();
                let mut second = [0u8; MAX_PACKET_BYTES];
                let second_len = encode_any(&again.message, again.header.seq, &mut second);
                assert_eq!(first[..first_len], second[..second_len]);
                "ok".to_string()
            }
            Err(error) => format!("{error:?}").split([' ', '(', '{']).next().unwrap_or("").to_string(),
        };
        *outcomes.entry(outcome).or_default() += 1;

        if key.verify(&input).is_ok() && input != *original {
            // Only an unmodified authenticated packet may verify; anything else is a forgery
            // that got through (the chance of a random 128-bit tag match is nil).
            let genuine = corpus.contains(&input);
            if !genuine {
                forged_accepted += 1;
            }
        }
    }
    println!("{CASES} cases: {outcomes:?}");
    assert_eq!(forged_accepted, 0);
    assert_eq!(outcomes.values().sum::<usize>(), CASES);
    // The mutations must exercise both paths, or the test proves little.
    assert!(outcomes.get("ok").copied().unwrap_or(0) > 10_000, "{outcomes:?}");
    assert!(outcomes.len() >= 8, "too few distinct outcomes: {outcomes:?}");
}
