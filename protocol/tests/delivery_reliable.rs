//! Reliable channels: the receiver hands out every sequence number exactly once and in order,
//! whatever permutation and duplication of a window arrives, both alone and inside an
//! `Endpoint`; a sender and a receiver over a lossy, duplicating, reordering channel deliver a
//! long stream completely.

// Test helpers too may unwrap and panic: a panic is a failed test with a backtrace.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use proptest::prelude::*;
use protocol::delivery::{
    Arrival, Endpoint, EndpointConfig, ReliableReceiver, ReliableSender, RtoConfig, RttEstimator,
};
use protocol::frame::Framing;
use protocol::message::{Constraint, ConstraintId, ConstraintKind};
use protocol::{AnyMessage, Cov6, NodeId, NodeRef, Pose3, RobotId, encode};

const WINDOW: usize = 32;

/// A permutation of `0..n` in which each number appears 1 to 3 times, and after each arrival
/// whether the application takes its deliveries.
fn window_arrivals() -> impl Strategy<Value = (u32, Vec<(u32, bool)>)> {
    (1..=WINDOW as u32)
        .prop_flat_map(|n| (Just(n), proptest::collection::vec(1..=3usize, n as usize)))
        .prop_flat_map(|(n, copies)| {
            let list: Vec<u32> = (0..n).flat_map(|seq| std::iter::repeat_n(seq, copies[seq as usize])).collect();
            let len = list.len();
            (Just(n), Just(list).prop_shuffle(), proptest::collection::vec(any::<bool>(), len))
        })
        .prop_map(|(n, list, polls)| (n, list.into_iter().zip(polls).collect()))
}

fn constraint(seq: u32) -> AnyMessage {
    AnyMessage::from(Constraint {
        id: ConstraintId { robot: RobotId(7), seq },
        kind: ConstraintKind::SubmapMatch,
        stamp_ns: u64::from(seq) * 1_000,
        from: NodeRef::Landmark { id: seq },
        to: NodeRef::Landmark { id: seq + 1 },
        t_from_to: Pose3::IDENTITY,
        covariance: Cov6::from_std_devs([0.1; 6]),
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn receiver_hands_out_each_window_item_once_in_order((n, arrivals) in window_arrivals()) {
        let mut rx = ReliableReceiver::<u32, WINDOW>::new();
        let mut out = Vec::new();
        let mut duplicates = 0;
        for (seq, poll) in &arrivals {
            match rx.insert(*seq, *seq) {
                Ok(arrival) => prop_assert!(matches!(arrival, Arrival::Next | Arrival::Ahead)),
                Err((Arrival::Duplicate, _)) => duplicates += 1,
                Err((other, _)) => prop_assert!(false, "{:?} for {}", other, seq),
            }
            // The acknowledgement never claims more than what arrived.
            let ack = rx.ack(2);
            prop_assert!(ack.next_expected <= n);
            if *poll {
                while let Some((seq, item)) = rx.pop_ready() {
                    prop_assert_eq!(seq, item);
                    out.push(item);
                }
            }
        }
        while let Some((_, item)) = rx.pop_ready() {
            out.push(item);
        }
        prop_assert_eq!(out, (0..n).collect::<Vec<_>>());
        prop_assert_eq!(duplicates, arrivals.len() - n as usize);
        prop_assert_eq!(rx.ack(2).next_expected, n);
        prop_assert_eq!(rx.ack(2).received_mask, 0);
    }

    #[test]
    fn endpoint_delivers_each_window_packet_once_in_order((n, arrivals) in window_arrivals()) {
        let config = EndpointConfig::new(NodeId(1), Framing::Stream, 100_000, 10_000);
        let mut endpoint: Box<Endpoint> = Box::new(Endpoint::new(config).unwrap());
        let packets: Vec<Vec<u8>> = (0..n)
            .map(|seq| {
                let mut buf = [0u8; protocol::MAX_PACKET_BYTES];
                let len = encode(&constraint(seq), NodeId(2), NodeId(1), seq, &mut buf).unwrap();
                buf[..len].to_vec()
            })
            .collect();
        let mut out = Vec::new();
        for (i, (seq, poll)) in arrivals.iter().enumerate() {
            endpoint.handle_packet(i as u64, &packets[*seq as usize]).unwrap();
            if *poll {
                while let Some(d) = endpoint.poll_deliver() {
                    out.push(d);
                }
            }
        }
        while let Some(d) = endpoint.poll_deliver() {
            out.push(d);
        }
        let seqs: Vec<u32> = out.iter().map(|d| d.header.seq).collect();
        prop_assert_eq!(seqs, (0..n).collect::<Vec<_>>());
        for d in &out {
            prop_assert_eq!(&d.message, &constraint(d.header.seq));
        }
        prop_assert_eq!(endpoint.stats().duplicates, (arrivals.len() - n as usize) as u64);
        prop_assert_eq!(endpoint.stats().reorder_buffered, 0);
        // Out-of-window sequence numbers are refused and counted.
        let mut buf = [0u8; protocol::MAX_PACKET_BYTES];
        let far = n + WINDOW as u32;
        let len = encode(&constraint(far), NodeId(2), NodeId(1), far, &mut buf).unwrap();
        prop_assert!(endpoint.handle_packet(1_000, &buf[..len]).is_err());
        prop_assert_eq!(endpoint.stats().rejected.out_of_window, 1);
        prop_assert!(endpoint.poll_deliver().is_none());
    }

    /// A sender and a receiver, acknowledgements going back, over a channel that loses,
    /// duplicates and delays each packet at random (in both directions): every item arrives,
    /// once, in order, however long the stream.
    #[test]
    fn sender_and_receiver_survive_a_bad_channel(seed in any::<u64>(), items in 1u32..400, loss in 0u32..50) {
        let mut rng = seed | 1;
        let mut random = move |below: u64| {
            // xorshift64*: enough for a test channel.
            rng ^= rng >> 12;
            rng ^= rng << 25;
            rng ^= rng >> 27;
            rng.wrapping_mul(0x2545_F491_4F6C_DD1D) % below
        };
        let mut rtt = RttEstimator::new(RtoConfig { initial_ms: 50, min_ms: 5, max_ms: 2_000 });
        let mut tx = ReliableSender::<WINDOW>::new();
        let mut rx = ReliableReceiver::<u32, WINDOW>::new();
        let mut to_rx: Vec<(u64, u32)> = Vec::new(); // (arrival ms, seq)
        let mut to_tx: Vec<(u64, (u32, u32))> = Vec::new(); // (arrival ms, ack)
        let mut next_item = 0u32;
        let mut out = Vec::new();
        let mut now = 0u64;
        while out.len() < items as usize {
            prop_assert!(now < 10_000_000, "stalled at {} of {}", out.len(), items);
            while next_item < items && !tx.is_full() {
                let item = next_item;
                tx.push_with(|_, buf: &mut [u8]| -> Result<usize, ()> {
                    buf[..4].copy_from_slice(&item.to_le_bytes());
                    Ok(4)
                }).unwrap();
                next_item += 1;
            }
            // One packet per ms at most.
            if let Some(choice) = tx.next_to_send(now, &rtt) {
                if let Some(sent_ms) = tx.mark_sent(now, choice.seq)
                    && !choice.fast
                {
                    rtt.on_timeout(now, sent_ms);
                }
                for _ in 0..(1 + u64::from(random(10) == 0)) {
                    if random(100) >= u64::from(loss) {
                        to_rx.push((now + 5 + random(20), choice.seq));
                    }
                }
            }
            let mut ack_due = false;
            to_rx.retain(|&(at, seq)| {
                if at <= now {
                    let _ = rx.insert(seq, seq);
                    ack_due = true;
                    false
                } else {
                    true
                }
            });
            while let Some((seq, item)) = rx.pop_ready() {
                prop_assert_eq!(seq, item);
                out.push(item);
            }
            if ack_due && random(100) >= u64::from(loss) {
                let ack = rx.ack(2);
                to_tx.push((now + 5 + random(20), (ack.next_expected, ack.received_mask)));
            }
            let mut arrived = Vec::new();
            to_tx.retain(|&(at, ack)| if at <= now { arrived.push(ack); false } else { true });
            for (next_expected, mask) in arrived {
                let outcome = tx.on_ack(now, next_expected, mask).unwrap();
                if let Some(sample) = outcome.rtt_sample_ms {
                    rtt.on_sample(sample);
                }
            }
            now += 1;
        }
        prop_assert_eq!(out, (0..items).collect::<Vec<_>>());
    }
}
