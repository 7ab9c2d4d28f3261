//! Opening a recorded dataset by its layout.

use std::path::Path;

use filter::config::ImuNoise;
use hal::asl::AslDataset;
use hal::kitti::{self, KittiDataset};
use hal::sensor::{SensorError, SensorEvent, SensorSource, StereoCalibration, StereoFrame};

use super::VioError;

/// The layouts the pipeline reads.
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

    fn next_event(&mut self, frame: &mut StereoFrame) -> Result<Option<SensorEvent>, SensorError> {
        match self {
            DatasetSource::Asl(d) => d.next_event(frame),
            DatasetSource::Kitti(d) => d.next_event(frame),
        }
    }
}

/// An opened dataset and what the pipeline needs to know about it up front.
#[derive(Debug)]
pub struct Dataset {
    pub kind: DatasetKind,
    pub source: DatasetSource,
    pub calibration: StereoCalibration,
    /// Capture stamps of the stereo pairs, in replay order.
    pub image_stamps_ns: Vec<u64>,
    pub imu_samples: usize,
    pub wheel_samples: usize,
    /// Noise densities of `imu0/sensor.yaml`, when given.
    pub imu_noise: Option<ImuNoise>,
}

/// Opens `dir` as KITTI (image folders present) or EuRoC/ASL (anything else that `AslDataset`
/// accepts). A dataset without stereo pairs is an error.
pub fn open_dataset(dir: &Path) -> Result<Dataset, VioError> {
    if !dir.is_dir() {
        return Err(VioError::Input(format!("{}: no such dataset directory", dir.display())));
    }
    let dataset = if kitti::is_kitti_dir(dir) {
        let source = KittiDataset::open(dir)?;
        Dataset {
            kind: DatasetKind::Kitti,
            calibration: *source.calibration(),
            image_stamps_ns: source.frames().iter().map(|f| f.stamp_ns).collect(),
            imu_samples: 0,
            wheel_samples: 0,
            imu_noise: None,
            source: DatasetSource::Kitti(source),
        }
    } else {
        let source = AslDataset::open(dir)?;
        let calibration = source
            .stereo_calibration()
            .ok_or_else(|| VioError::Input(format!("{}: the dataset has no cam0/ and cam1/", dir.display())))?;
        let imu_noise = source.imu_noise().map(ImuNoise::from);
        Dataset {
            kind: DatasetKind::Asl,
            calibration,
            image_stamps_ns: source.pairs().iter().map(|p| p.stamp_ns).collect(),
            imu_samples: source.imu_samples().len(),
            wheel_samples: source.wheel_samples().len(),
            imu_noise,
            source: DatasetSource::Asl(source),
        }
    };
    if dataset.image_stamps_ns.is_empty() {
        return Err(VioError::Input(format!("{}: no stereo pairs", dir.display())));
    }
    Ok(dataset)
}
