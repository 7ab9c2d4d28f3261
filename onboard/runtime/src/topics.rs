//! The registry of the robot's bus topics (DESIGN §4): for every [`Topic`] its path (the
//! iceoryx2 service is `rover/{robot_id}/{path}`), its stable code in recordings, the process
//! that publishes it and its iceoryx2 settings, in one table ([`TOPICS`]). Everything else asks
//! the table: the bus opens its services from it, each process's publishers come from it, the
//! recorder writes the codes.
//!
//! The reasons for each topic's settings are in the table of [`crate::bus`]'s documentation.

use crate::process::NodeKind;

/// A bus topic of one robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Topic {
    Imu,
    WheelOdom,
    Stereo,
    Disparity,
    VoDelta,
    Marker,
    FilterState,
    FrameSwitchRequest,
    FrameSwitch,
    ToComms,
    ToMapper,
    TaskStats,
    HeadCommand,
    Hazards,
}

/// What a full subscriber buffer does with a new sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Overflow {
    /// Safe overflow: the newest sample replaces the oldest unread one.
    DropOldest,
    /// The new sample is not delivered to that subscriber; the publisher counts it.
    DiscardNewest,
}

/// The iceoryx2 settings of one topic's service.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TopicQos {
    pub subscriber_buffer: usize,
    /// Samples a subscriber may hold at once (one drain round).
    pub subscriber_borrow: usize,
    pub history: usize,
    pub max_publishers: usize,
    pub max_subscribers: usize,
    pub overflow: Overflow,
}

/// Who publishes a topic.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Publisher {
    Process(NodeKind),
    /// Every process (its task telemetry).
    Every,
}

/// One row of the registry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TopicSpec {
    pub topic: Topic,
    /// Path below `rover/{id}/`.
    pub path: &'static str,
    /// Stable number of the topic in recordings (never reused).
    pub code: u8,
    pub publisher: Publisher,
    pub qos: TopicQos,
}

/// A topic whose full buffer discards the new sample (counted by the publisher), no history.
const fn discard(buffer: usize) -> TopicQos {
    TopicQos {
        subscriber_buffer: buffer,
        subscriber_borrow: buffer,
        history: 0,
        max_publishers: 2,
        max_subscribers: 4,
        overflow: Overflow::DiscardNewest,
    }
}

const fn spec(topic: Topic, path: &'static str, code: u8, publisher: Publisher, qos: TopicQos) -> TopicSpec {
    TopicSpec { topic, path, code, publisher, qos }
}

use NodeKind::{Comms, Driver, Filter, Mapper, Vision};
use Publisher::{Every, Process};

/// The registry, in [`Topic`] order.
pub const TOPICS: [TopicSpec; 14] = [
    spec(Topic::Imu, "sensors/imu", 1, Process(Driver), TopicQos { history: 256, ..discard(512) }),
    spec(Topic::WheelOdom, "sensors/wheel_odom", 2, Process(Driver), discard(64)),
    spec(
        Topic::Stereo,
        "sensors/stereo",
        3,
        Process(Driver),
        TopicQos {
            subscriber_buffer: 2,
            subscriber_borrow: 2,
            history: 0,
            max_publishers: 2,
            max_subscribers: 3,
            overflow: Overflow::DropOldest,
        },
    ),
    spec(
        Topic::Disparity,
        "vision/disparity",
        4,
        Process(Vision),
        TopicQos {
            subscriber_buffer: 4,
            subscriber_borrow: 2,
            history: 0,
            max_publishers: 2,
            max_subscribers: 3,
            overflow: Overflow::DropOldest,
        },
    ),
    spec(Topic::VoDelta, "vision/vo_delta", 5, Process(Vision), discard(16)),
    spec(Topic::Marker, "vision/markers", 6, Process(Vision), discard(16)),
    spec(
        Topic::FilterState,
        "filter/state",
        7,
        Process(Filter),
        TopicQos { overflow: Overflow::DropOldest, ..discard(256) },
    ),
    spec(Topic::FrameSwitchRequest, "mapper/frame_switch_request", 8, Process(Mapper), discard(8)),
    spec(Topic::FrameSwitch, "filter/frame_switch", 9, Process(Filter), discard(8)),
    spec(Topic::ToComms, "mapper/to_comms", 10, Process(Mapper), discard(64)),
    spec(Topic::ToMapper, "comms/to_mapper", 11, Process(Comms), discard(64)),
    spec(
        Topic::TaskStats,
        "telemetry/tasks",
        12,
        Every,
        TopicQos { max_publishers: 8, overflow: Overflow::DropOldest, ..discard(16) },
    ),
    spec(
        Topic::HeadCommand,
        "control/head",
        13,
        Process(Vision),
        TopicQos { overflow: Overflow::DropOldest, ..discard(8) },
    ),
    spec(
        Topic::Hazards,
        "vision/hazards",
        14,
        Process(Vision),
        TopicQos { overflow: Overflow::DropOldest, ..discard(2) },
    ),
];

impl Topic {
    pub const ALL: [Topic; 14] = {
        let mut all = [Topic::Imu; 14];
        let mut i = 0;
        while i < TOPICS.len() {
            all[i] = TOPICS[i].topic;
            i += 1;
        }
        all
    };

    /// The topic's row of the registry.
    pub fn spec(self) -> &'static TopicSpec {
        &TOPICS[self as usize]
    }

    /// Path below `rover/{id}/`.
    pub fn path(self) -> &'static str {
        self.spec().path
    }

    /// The iceoryx2 service name of this topic for one robot.
    pub fn service_name(self, robot_id: u16) -> String {
        format!("rover/{robot_id}/{}", self.path())
    }

    /// Stable number of the topic in recordings (never reused).
    pub fn code(self) -> u8 {
        self.spec().code
    }

    pub fn from_code(code: u8) -> Option<Topic> {
        TOPICS.iter().find(|s| s.code == code).map(|s| s.topic)
    }

    pub fn qos(self) -> TopicQos {
        self.spec().qos
    }
}

/// The topics process `kind` publishes (its node's outputs and its task telemetry).
pub fn published_by(kind: NodeKind) -> Vec<Topic> {
    TOPICS
        .iter()
        .filter(|s| match s.publisher {
            Process(k) => k == kind,
            Every => true,
        })
        .map(|s| s.topic)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_registry_is_in_topic_order_with_unique_paths_and_codes() {
        for (i, s) in TOPICS.iter().enumerate() {
            assert_eq!(s.topic as usize, i, "{:?} out of order", s.topic);
            assert_eq!(Topic::from_code(s.code), Some(s.topic));
            assert!(TOPICS.iter().filter(|o| o.path == s.path || o.code == s.code).count() == 1, "{s:?}");
            assert!(s.qos.subscriber_borrow <= s.qos.subscriber_buffer, "{s:?}");
        }
        assert_eq!(Topic::from_code(0), None);
    }

    #[test]
    fn every_topic_but_telemetry_has_one_publishing_process() {
        for kind in NodeKind::ALL {
            assert!(published_by(kind).contains(&Topic::TaskStats));
        }
        for topic in Topic::ALL.into_iter().filter(|&t| t != Topic::TaskStats) {
            let publishers = NodeKind::ALL.into_iter().filter(|&k| published_by(k).contains(&topic)).count();
            assert_eq!(publishers, 1, "{topic:?}");
        }
    }
}
