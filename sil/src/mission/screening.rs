//! What the robots' graphs made of the truth source's inter-robot closures in the outlier
//! experiment (`--wrong-closure-fraction`): how many were wrong, and per robot how many wrong
//! ones its consistency check let in and how many genuine ones it kept out.

use std::collections::BTreeSet;

use mapper::slam::{ClosureKey, TeamGraph};
use serde_json::{Value, json};

/// One robot's graph at the end of the mission.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RobotScreening {
    pub robot: u16,
    /// Inter-robot closures its check screened (0 without a check: all went in).
    pub screened: usize,
    pub accepted: usize,
    /// Injected wrong closures in its graph: without a check, every one it received.
    pub wrong_accepted: usize,
    /// Genuine closures it kept out (the truth source's own rare gross match errors count as
    /// genuine here).
    pub genuine_rejected: usize,
    /// Accepted closures withdrawn later (optimizer rebuilds).
    pub withdrawn: usize,
}

/// The experiment's outcome over the team.
#[derive(Debug, Clone, PartialEq)]
pub struct ClosureScreening {
    /// `none` or `pcm`.
    pub consistency: String,
    pub wrong_fraction: f64,
    /// Inter-robot closures the truth source handed to the mappers, and how many were wrong.
    pub inter_robot_closures: u64,
    pub injected_wrong: u64,
    pub robots: Vec<RobotScreening>,
}

impl ClosureScreening {
    /// Robot `robot`'s graph against the set of wrong closures.
    pub fn robot(robot: u16, graph: &TeamGraph, wrong: &BTreeSet<ClosureKey>) -> RobotScreening {
        let closures = graph.screened_closures();
        match graph.consistency_stats() {
            Some(stats) => RobotScreening {
                robot,
                screened: stats.closures,
                accepted: stats.accepted,
                wrong_accepted: closures.iter().filter(|c| c.accepted && wrong.contains(&c.key)).count(),
                genuine_rejected: closures.iter().filter(|c| !c.accepted && !wrong.contains(&c.key)).count(),
                withdrawn: stats.withdrawn,
            },
            // Without a check every wrong closure this robot received is in its graph; the ones
            // it received are the ones the team made, up to those still in flight at the end.
            None => RobotScreening {
                robot,
                screened: 0,
                accepted: 0,
                wrong_accepted: wrong.len(),
                genuine_rejected: 0,
                withdrawn: 0,
            },
        }
    }

    pub fn to_json(&self) -> Value {
        let robots: Vec<Value> = self
            .robots
            .iter()
            .map(|r| {
                json!({
                    "robot": r.robot,
                    "screened": r.screened,
                    "accepted": r.accepted,
                    "wrong_accepted": r.wrong_accepted,
                    "genuine_rejected": r.genuine_rejected,
                    "withdrawn": r.withdrawn,
                })
            })
            .collect();
        json!({
            "consistency": self.consistency,
            "wrong_fraction": self.wrong_fraction,
            "inter_robot_closures": self.inter_robot_closures,
            "injected_wrong": self.injected_wrong,
            "robots": robots,
        })
    }

    /// One line for the summary and the markdown report.
    pub fn line(&self) -> String {
        let robots: Vec<String> = self
            .robots
            .iter()
            .map(|r| {
                format!(
                    "robot {}: {} wrong in its graph, {} genuine kept out ({} screened, {} withdrawn)",
                    r.robot, r.wrong_accepted, r.genuine_rejected, r.screened, r.withdrawn
                )
            })
            .collect();
        format!(
            "inter-robot closure screening {}: {} of {} truth inter-robot closures made wrong ({:.0} %); {}",
            self.consistency,
            self.injected_wrong,
            self.inter_robot_closures,
            self.wrong_fraction * 100.0,
            robots.join("; ")
        )
    }
}
