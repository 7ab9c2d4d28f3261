//! The ground station through the emulated ground link of the process runner
//! (`sil::relay`): a robot's UDP ground link → relay (200 ms one way, a 6 s outage)
//! → the engine's UDP socket. During the outage the robot turns STALE and a command waits in
//! the queue; when the link returns the robot is fresh again and the command goes out, is
//! verified by the robot's endpoint (HMAC) and its acknowledgement reaches the view.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod model_common;

use std::time::{Duration, Instant};

use groundstation::engine::Engine;
use groundstation::model::ModelConfig;
use groundstation::view::{CommandState, Staleness, TeamView, UiAction};
use hal::emulator::EmulatorConfig;
use hal::udp::UdpLink;
use model_common::*;
use protocol::NodeId;
use protocol::message::{CommandOutcome, Mode};
use sil::ground_end::GroundEnd;
use sil::relay::{GroundLinkEmulation, Relay};

const OUTAGE_MS: (u64, u64) = (2_000, 8_000);
const END_MS: u64 = 11_000;

#[test]
fn a_robot_goes_stale_in_an_outage_and_a_queued_command_is_delivered_after_it() {
    let engine = Engine::live(
        "udp://127.0.0.1:0".parse().unwrap(),
        ModelConfig { auth_key: Some(key()), source: "test".into() },
    )
    .unwrap();
    let station = engine.local_addr().unwrap();

    let team_radio = EmulatorConfig::ideal(1_000_000, FRAMING);
    let mut relay = Relay::bind(1, &team_radio, 1).unwrap();
    let nodes = [NodeId(1)];
    let end = GroundEnd::new(Some(station), &nodes, None).unwrap();
    let emulation = GroundLinkEmulation { delay_ms: 200, loss: 0.0, outages_ms: vec![OUTAGE_MS], seed: 5 };
    relay.enable_ground(&nodes, end, &emulation).unwrap();
    let mut link = UdpLink::bind("127.0.0.1:0").unwrap().with_peers([relay.ground_addr(0).unwrap()]);
    let mut robot = SimRobot::new(1, Some(key()));

    let start = Instant::now();
    let (mut next_telemetry_ms, mut sent_command_at_ms) = (0u64, None);
    let mut seen: Vec<(u64, Staleness, Option<CommandState>)> = Vec::new();
    let mut verified_commands = 0;
    loop {
        let now_ms = start.elapsed().as_millis() as u64;
        if now_ms > END_MS {
            break;
        }
        let now_ns = now_ms * 1_000_000;
        if now_ms >= next_telemetry_ms {
            robot.send(now_ns, telemetry(1, now_ns, 0));
            next_telemetry_ms += 250;
        }
        robot.transmit_over(&mut link, now_ms);
        relay.pump(now_ms);
        for command in robot.receive_over(&mut link, now_ms, Duration::ZERO) {
            assert_eq!(command.kind, protocol::message::CommandKind::SetMode(Mode::Safe));
            verified_commands += 1;
        }
        // The operator sends a command once the robot is flagged STALE, inside the outage.
        let view = engine.view();
        if sent_command_at_ms.is_none() && staleness(&view) == Some(Staleness::Stale) {
            engine.act(UiAction::SetMode { robot: 1, mode: Mode::Safe }).unwrap();
            sent_command_at_ms = Some(now_ms);
        }
        seen.push((now_ms, staleness(&view).unwrap_or(Staleness::Lost), view.commands.first().map(|c| c.state)));
        std::thread::sleep(Duration::from_millis(10));
    }

    let at = |ms: u64| seen.iter().rev().find(|(t, ..)| *t <= ms).copied().unwrap();
    assert_eq!(at(1_500).1, Staleness::Fresh, "fresh before the outage");
    let sent = sent_command_at_ms.expect("the robot never turned STALE during the outage");
    // The emulator drops a packet sent or arriving inside the outage, so the last one through is
    // the telemetry of 1.75 s, arriving at 1.95 s; STALE follows 5 s without a message.
    let last_arrival_ms = 1_750 + 200;
    assert!((last_arrival_ms + 5_000..OUTAGE_MS.1).contains(&sent), "STALE at {sent} ms");
    // The engine publishes its view a moment after the action.
    let during: Vec<_> = seen.iter().filter(|(t, _, c)| (sent..OUTAGE_MS.1).contains(t) && c.is_some()).collect();
    assert!(during.first().is_some_and(|(t, ..)| *t < sent + 500), "the command never showed: {:?}", during.first());
    assert!(
        during.iter().all(|(_, _, c)| *c == Some(CommandState::Queued)),
        "the command waits in the queue while the link is down: {during:?}"
    );
    assert_eq!(at(END_MS).1, Staleness::Fresh, "fresh again after the outage");
    assert_eq!(verified_commands, 1, "the robot executes the command exactly once");
    let acked = seen.iter().find(|(_, _, c)| matches!(c, Some(CommandState::Acknowledged { .. })));
    let Some((acked_ms, _, Some(CommandState::Acknowledged { outcome, rtt_ms }))) = acked else {
        panic!("no acknowledgement: {:?}", seen.last())
    };
    assert_eq!(*outcome, CommandOutcome::Executed);
    // Sent when the first packet after the outage arrives, acked one round trip later.
    assert!(*acked_ms >= OUTAGE_MS.1 + 400, "acknowledged at {acked_ms} ms");
    assert!((400..1_500).contains(rtt_ms), "round trip {rtt_ms} ms over a 2 × 200 ms link");
    let stats = relay.ground_stats().unwrap();
    assert!(stats.downlink_packets > 20 && stats.uplink_packets >= 2, "{stats:?}");
}

fn staleness(view: &TeamView) -> Option<Staleness> {
    view.robots.get(&1).map(|r| r.staleness)
}
