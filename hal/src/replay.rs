//! Replaying a recorded dataset as the rover's sensors: the firmware's `replay` driver. The layout
//! is recognised from the folder (EuRoC/ASL or KITTI odometry); the dataset brings its own
//! calibration and, for EuRoC, its IMU's noise densities.

use std::path::Path;

use crate::asl::{AslDataset, ImuNoiseDensities};
use crate::kitti::{self, KittiDataset};
use crate::sensor::{SensorError, SensorEvent, SensorSource, StereoCalibration};

/// The layouts a replay reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DatasetKind {
    /// EuRoC/ASL (`mav0/…` or a folder with `cam0/`), real EuRoC or a `sim record` output.
    Asl,
    /// KITTI odometry (`image_l`/`image_r` or `image_0`/`image_1`, `calib.txt`).
    Kitti,
}

impl DatasetKind {
    pub fn name(self) -> &'static str {
        match self {
            DatasetKind::Asl => "asl",
            DatasetKind::Kitti => "kitti",
        }
    }
}

/// The replay source of either layout.
#[derive(Debug)]
pub enum DatasetSource {
    Asl(AslDataset),
    Kitti(KittiDataset),
}

impl SensorSource for DatasetSource {
    fn stereo_calibration(&self) -> Option<StereoCalibration> {
        match self {
            DatasetSource::Asl(d) => d.stereo_calibration(),
            DatasetSource::Kitti(d) => d.stereo_calibration(),
        }
    }

    fn next_event(&mut self) -> Result<Option<SensorEvent>, SensorError> {
        match self {
            DatasetSource::Asl(d) => d.next_event(),
            DatasetSource::Kitti(d) => d.next_event(),
        }
    }

    fn read_stereo(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), SensorError> {
        match self {
            DatasetSource::Asl(d) => d.read_stereo(left, right),
            DatasetSource::Kitti(d) => d.read_stereo(left, right),
        }
    }
}

/// An opened dataset and what its consumers need to know about it up front.
#[derive(Debug)]
pub struct Dataset {
    pub kind: DatasetKind,
    pub source: DatasetSource,
    pub calibration: StereoCalibration,
    /// Capture stamps of the stereo pairs, in replay order.
    pub image_stamps_ns: Vec<u64>,
    /// The stamp of the replay's first event (image, IMU or wheel sample).
    pub first_stamp_ns: u64,
    pub imu_samples: usize,
    pub wheel_samples: usize,
    /// Noise densities of `imu0/sensor.yaml`, when given.
    pub imu_noise: Option<ImuNoiseDensities>,
}

/// Opens `dir` as KITTI (image folders present) or EuRoC/ASL (anything else that `AslDataset`
/// accepts). A dataset without stereo pairs is an error.
pub fn open_dataset(dir: &Path) -> Result<Dataset, SensorError> {
    let format_error = |reason: &str| SensorError::Format { context: dir.display().to_string(), reason: reason.into() };
    if !dir.is_dir() {
        return Err(format_error("no such dataset directory"));
    }
    let dataset = if kitti::is_kitti_dir(dir) {
        let source = KittiDataset::open(dir)?;
        Dataset {
            kind: DatasetKind::Kitti,
            calibration: *source.calibration(),
            image_stamps_ns: source.frames().iter().map(|f| f.stamp_ns).collect(),
            first_stamp_ns: source.frames().first().map_or(0, |f| f.stamp_ns),
            imu_samples: 0,
            wheel_samples: 0,
            imu_noise: None,
            source: DatasetSource::Kitti(source),
        }
    } else {
        let source = AslDataset::open(dir)?;
        let calibration =
            source.stereo_calibration().ok_or_else(|| format_error("the dataset has no cam0/ and cam1/"))?;
        let imu_noise = source.imu_noise();
        Dataset {
            kind: DatasetKind::Asl,
            calibration,
            image_stamps_ns: source.pairs().iter().map(|p| p.stamp_ns).collect(),
            first_stamp_ns: [
                source.pairs().first().map(|p| p.stamp_ns),
                source.imu_samples().first().map(|s| s.stamp_ns),
                source.wheel_samples().first().map(|s| s.stamp_ns),
            ]
            .into_iter()
            .flatten()
            .min()
            .unwrap_or(0),
            imu_samples: source.imu_samples().len(),
            wheel_samples: source.wheel_samples().len(),
            imu_noise,
            source: DatasetSource::Asl(source),
        }
    };
    if dataset.image_stamps_ns.is_empty() {
        return Err(format_error("no stereo pairs"));
    }
    Ok(dataset)
}
