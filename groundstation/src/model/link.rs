//! Ground-link statistics: per-second bins of what arrived (by message class, by receive time) and
//! of what the robots say they sent (telemetry deltas), closed into [`LinkSample`]s by `tick`.
//!
//! Binning by the packets' receive time, not by when `tick` runs, makes the samples the same
//! whether packets are ingested live or replayed in one go.

use std::collections::{BTreeMap, VecDeque};

use crate::view::{LinkSample, LinkView};

/// Samples kept: 10 minutes at one per second.
pub const MAX_SAMPLES: usize = 600;
const NS_PER_S: u64 = 1_000_000_000;

#[derive(Debug, Clone, Default)]
struct Bin {
    rx: BTreeMap<String, f64>,
    tx: BTreeMap<String, f64>,
    packets: u64,
}

/// What the rest of the model knows at the moment a second is closed.
#[derive(Debug, Clone, Copy, Default)]
pub struct LinkState {
    pub rtt_ms: Option<f64>,
    pub loss_permille: Option<f64>,
    pub robot_queue_depth: u32,
    pub ground_queue_depth: u32,
}

#[derive(Debug, Clone, Default)]
pub struct LinkAccumulator {
    bins: BTreeMap<u64, Bin>,
    /// The next second to close; `None` before the first packet.
    next_s: Option<u64>,
    in_outage: bool,
    pub view: LinkView,
}

impl LinkAccumulator {
    pub fn on_packet(&mut self, recv_ns: u64, class: &str, bytes: usize) {
        let s = recv_ns / NS_PER_S;
        if self.next_s.is_none() {
            self.next_s = Some(s);
        }
        let bin = self.bins.entry(s).or_default();
        *bin.rx.entry(class.to_string()).or_default() += bytes as f64;
        bin.packets += 1;
        self.view.packets_received += 1;
    }

    pub fn on_rejected(&mut self) {
        self.view.packets_rejected += 1;
    }

    /// Bytes a robot reported sending in `class` since its previous report.
    pub fn on_robot_sent(&mut self, recv_ns: u64, class: &str, bytes: u64) {
        let bin = self.bins.entry(recv_ns / NS_PER_S).or_default();
        *bin.tx.entry(class.to_string()).or_default() += bytes as f64;
    }

    /// Closes every whole second before `now_ns`.
    pub fn tick(&mut self, now_ns: u64, state: LinkState) {
        let Some(mut next) = self.next_s else { return };
        let now_s = now_ns / NS_PER_S;
        if now_s > next + MAX_SAMPLES as u64 {
            next = now_s - MAX_SAMPLES as u64;
            self.bins.retain(|s, _| *s >= next);
        }
        while next < now_s {
            let bin = self.bins.remove(&next).unwrap_or_default();
            let outage = bin.packets == 0;
            if outage && !self.in_outage {
                self.view.outages += 1;
            }
            self.in_outage = outage;
            self.view.samples.push_back(LinkSample {
                t_s: (next + 1) as f64,
                rx_bytes_per_s_by_class: bin.rx,
                tx_bytes_per_s_by_class: bin.tx,
                rtt_ms: state.rtt_ms,
                loss_permille: state.loss_permille,
                robot_queue_depth: state.robot_queue_depth,
                ground_queue_depth: state.ground_queue_depth,
                outage,
            });
            while self.view.samples.len() > MAX_SAMPLES {
                self.view.samples.pop_front();
            }
            next += 1;
        }
        self.next_s = Some(next);
    }

    pub fn samples(&self) -> &VecDeque<LinkSample> {
        &self.view.samples
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seconds_close_into_samples_and_silence_is_one_outage() {
        let mut link = LinkAccumulator::default();
        link.on_packet(500_000_000, "Telemetry", 100);
        link.on_packet(700_000_000, "Telemetry", 50);
        link.on_robot_sent(800_000_000, "PoseEstimate", 70);
        link.on_packet(4_200_000_000, "PoseEstimate", 80);
        link.tick(5_000_000_000, LinkState::default());
        let s = link.samples();
        assert_eq!(s.len(), 5);
        assert_eq!(s[0].rx_bytes_per_s_by_class["Telemetry"], 150.0);
        assert_eq!(s[0].tx_bytes_per_s_by_class["PoseEstimate"], 70.0);
        assert_eq!(s.iter().map(|x| x.outage).collect::<Vec<_>>(), [false, true, true, true, false]);
        assert_eq!(link.view.outages, 1);
        assert_eq!(link.view.packets_received, 3);
    }
}
