//! Zero-copy shown, not claimed: the disparity map the mapper reads lies in a `/dev/shm` file
//! that the vision process has mapped too, and the pixels are the ones vision wrote.
//!
//! The test binary re-executes itself as the vision process (env var `ONBOARD_ZC_ROLE`).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use msgs::{DisparityHeader, DisparityPixel};
use onboard::bus::{Bus, ImageGeometry, purge_robot, robot_prefix};
use onboard::nodes::{Message, Outbox, Topic};

const ROLE: &str = "ONBOARD_ZC_ROLE";
const ROBOT: &str = "ONBOARD_ZC_ROBOT";
const GEOMETRY: ImageGeometry = ImageGeometry { width_px: 1024, height_px: 508 };
const SENT: &str = "ZERO_COPY_SENT";

fn pattern(i: usize) -> DisparityPixel {
    DisparityPixel {
        disparity_q4: (i.wrapping_mul(2_654_435_761) >> 9) as u16,
        labels: (i % 251) as u8,
        reserved: (i / 1024) as u8,
    }
}

fn header() -> DisparityHeader {
    DisparityHeader {
        stamp_ns: 123_456_789,
        sequence: 7,
        pan_rad: 0.25,
        tilt_rad: -0.5,
        width_px: GEOMETRY.width_px,
        height_px: GEOMETRY.height_px,
    }
}

/// The vision role: publishes one map, then stays alive (its mappings readable) until stdin closes.
#[test]
fn vision_child() {
    let Ok(robot) = std::env::var(ROBOT) else { return };
    assert_eq!(std::env::var(ROLE).as_deref(), Ok("vision"));
    let bus = Bus::open(robot.parse().unwrap(), "vision", GEOMETRY).unwrap();
    let mut outbox = bus.outbox(&[Topic::Disparity]).unwrap();
    let pixels: Vec<DisparityPixel> = (0..1024 * 508).map(pattern).collect();
    let header = header();
    outbox.publish(Message::Disparity(&header, &pixels)).unwrap();
    println!("{SENT}");
    std::io::stdout().flush().unwrap();
    let mut line = String::new();
    while std::io::stdin().read_line(&mut line).unwrap() > 0 {}
}

/// One line of `/proc/<pid>/maps`.
#[derive(Debug)]
struct Mapping {
    start: usize,
    end: usize,
    inode: u64,
    path: String,
}

fn maps(pid: &str) -> Vec<Mapping> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/maps")).unwrap();
    text.lines()
        .filter_map(|line| {
            let mut fields = line.split_whitespace();
            let (start, end) = fields.next()?.split_once('-')?;
            let inode = fields.nth(3)?.parse().ok()?;
            let path = fields.collect::<Vec<_>>().join(" ");
            Some(Mapping {
                start: usize::from_str_radix(start, 16).ok()?,
                end: usize::from_str_radix(end, 16).ok()?,
                inode,
                path,
            })
        })
        .collect()
}

struct KillOnDrop(Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn mapper_reads_the_disparity_map_in_the_vision_process_shared_memory() {
    let robot = 20_000 + (std::process::id() % 20_000) as u16;
    let bus = Bus::open(robot, "mapper", GEOMETRY).unwrap();
    // Subscribed before vision starts, so its single publish reaches us.
    let mut inbox = bus.inbox(&[Topic::Disparity]).unwrap();

    let child = Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "vision_child", "--nocapture", "--test-threads=1"])
        .env(ROLE, "vision")
        .env(ROBOT, robot.to_string())
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut child = KillOnDrop(child);
    let child_pid = child.0.id().to_string();
    let stdout = child.0.stdout.take().unwrap();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if line.contains(SENT) {
                let _ = tx.send(());
            }
        }
    });
    rx.recv_timeout(Duration::from_secs(30)).expect("vision child did not publish");
    assert!(inbox.wait(Duration::from_secs(10)).unwrap(), "no sample arrived");

    let mut checked = 0;
    inbox
        .drain(&mut |message| {
            let Message::Disparity(h, pixels) = message else { panic!("unexpected {:?}", message.topic()) };
            assert_eq!(*h, header());
            assert_eq!(pixels.len(), 1024 * 508);
            assert!(pixels.iter().enumerate().all(|(i, p)| *p == pattern(i)), "pattern differs");

            let start = pixels.as_ptr() as usize;
            let end = start + std::mem::size_of_val(pixels);
            let own = maps("self");
            let mapping = own
                .iter()
                .find(|m| m.start <= start && end <= m.end)
                .unwrap_or_else(|| panic!("slice {start:#x}..{end:#x} is in no mapping"));
            assert!(
                mapping.path.starts_with(&format!("/dev/shm/{}", robot_prefix(robot))),
                "slice lies in {mapping:?}, not in the robot's shared memory"
            );
            let in_child = maps(&child_pid);
            assert!(
                in_child.iter().any(|m| m.path == mapping.path && m.inode == mapping.inode),
                "vision process does not map {}",
                mapping.path
            );
            eprintln!(
                "disparity slice {start:#x}..{end:#x} in {} (inode {}), mapped by vision pid {child_pid}",
                mapping.path, mapping.inode
            );
            checked += 1;
            Ok(())
        })
        .unwrap();
    assert_eq!(checked, 1);
    assert_eq!(inbox.counters(Topic::Disparity).received, 1);

    drop(child.0.stdin.take());
    let status = child.0.wait().unwrap();
    assert!(status.success(), "vision child failed: {status}");
    drop((inbox, bus));
    purge_robot(robot).unwrap();
}
