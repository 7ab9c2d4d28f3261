//! The `data.csv` files of an ASL dataset: one sample per line, comma-separated, the first field
//! the timestamp in integer nanoseconds; lines starting with `#` (the header) and blank lines are
//! skipped; `\r\n` line ends are accepted. Stamps must strictly increase within a file.

use std::path::Path;

use nalgebra::Vector3;

use super::yaml::{excerpt, format_error, parse_finite, utf8_error_line};
use crate::sensor::{ImuSample, SensorError, WheelOdomSample};

/// One row of `cam0/data.csv`: an image's stamp and its file name inside `data/`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CameraRow {
    pub stamp_ns: u64,
    pub file_name: String,
    /// Line in `data.csv`, for messages about the image.
    pub line: usize,
}

/// One row of `pantilt0/data.csv` (our extension): the head's angles at a stereo frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PanTiltRow {
    pub stamp_ns: u64,
    pub pan_rad: f64,
    pub tilt_rad: f64,
}

/// Fields of one data line, and where it is.
struct Row<'a> {
    line: usize,
    fields: Vec<&'a str>,
}

/// The data lines of a CSV file, split into exactly `columns` fields, stamps checked increasing.
fn rows<'a>(bytes: &'a [u8], file: &str, columns: usize) -> Result<Vec<(u64, Row<'a>)>, SensorError> {
    let text =
        std::str::from_utf8(bytes).map_err(|e| format_error(file, utf8_error_line(bytes, &e), "not valid UTF-8"))?;
    let mut out = Vec::new();
    let mut previous: Option<u64> = None;
    for (index, raw) in text.split('\n').enumerate() {
        let line = index + 1;
        let content = raw.trim();
        if content.is_empty() || content.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = content.split(',').map(str::trim).collect();
        if fields.len() != columns {
            return Err(format_error(
                file,
                line,
                format!("{} comma-separated fields, expected {columns}", fields.len()),
            ));
        }
        let stamp_ns = fields[0].parse::<u64>().map_err(|_| {
            format_error(file, line, format!("timestamp `{}` is not a whole number of nanoseconds", excerpt(fields[0])))
        })?;
        if let Some(previous) = previous
            && stamp_ns <= previous
        {
            return Err(format_error(file, line, format!("timestamp {stamp_ns} does not increase (after {previous})")));
        }
        previous = Some(stamp_ns);
        out.push((stamp_ns, Row { line, fields }));
    }
    Ok(out)
}

impl Row<'_> {
    /// The finite number in column `column` (0 = the stamp), named `name` in errors.
    fn number(&self, file: &str, column: usize, name: &str) -> Result<f64, SensorError> {
        let token = self.fields.get(column).copied().unwrap_or_default();
        parse_finite(token).ok_or_else(|| {
            format_error(
                file,
                self.line,
                format!("`{name}` (field {}): `{}` is not a finite number", column + 1, excerpt(token)),
            )
        })
    }

    fn vector(&self, file: &str, first: usize, names: [&str; 3]) -> Result<Vector3<f64>, SensorError> {
        Ok(Vector3::new(
            self.number(file, first, names[0])?,
            self.number(file, first + 1, names[1])?,
            self.number(file, first + 2, names[2])?,
        ))
    }
}

/// Reads `cam*/data.csv`: `#timestamp [ns],filename`. File names must be plain names in `data/`.
pub fn parse_camera_csv(bytes: &[u8], file: &Path) -> Result<Vec<CameraRow>, SensorError> {
    let name = file.display().to_string();
    rows(bytes, &name, 2)?
        .into_iter()
        .map(|(stamp_ns, row)| {
            let file_name = row.fields[1];
            // A name that leaves `data/` would make a dataset read files it does not contain.
            let plain =
                !file_name.is_empty() && !file_name.contains(['/', '\\']) && file_name != "." && file_name != "..";
            if !plain {
                return Err(format_error(
                    &name,
                    row.line,
                    format!("`{}` is not a plain file name in data/", excerpt(file_name)),
                ));
            }
            Ok(CameraRow { stamp_ns, file_name: file_name.to_owned(), line: row.line })
        })
        .collect()
}

/// Reads `imu0/data.csv`: `#timestamp [ns],w_x,w_y,w_z [rad s^-1],a_x,a_y,a_z [m s^-2]`.
pub fn parse_imu_csv(bytes: &[u8], file: &Path) -> Result<Vec<ImuSample>, SensorError> {
    let name = file.display().to_string();
    rows(bytes, &name, 7)?
        .into_iter()
        .map(|(stamp_ns, row)| {
            Ok(ImuSample {
                stamp_ns,
                gyro_radps: row.vector(&name, 1, ["w_x", "w_y", "w_z"])?,
                accel_mps2: row.vector(&name, 4, ["a_x", "a_y", "a_z"])?,
            })
        })
        .collect()
}

/// Names of the wheel odometry columns after the stamp, as written in the header.
pub const WHEEL_COLUMNS: [&str; 12] = [
    "v_x [m s^-1]",
    "v_y [m s^-1]",
    "v_z [m s^-1]",
    "w_x [rad s^-1]",
    "w_y [rad s^-1]",
    "w_z [rad s^-1]",
    "sigma_vx [m s^-1]",
    "sigma_vy [m s^-1]",
    "sigma_vz [m s^-1]",
    "sigma_wx [rad s^-1]",
    "sigma_wy [rad s^-1]",
    "sigma_wz [rad s^-1]",
];

/// Reads `wheel0/data.csv` (our extension): stamp, body linear velocity, body angular velocity,
/// then the six standard deviations the odometry claims (see [`WHEEL_COLUMNS`]).
pub fn parse_wheel_csv(bytes: &[u8], file: &Path) -> Result<Vec<WheelOdomSample>, SensorError> {
    let name = file.display().to_string();
    rows(bytes, &name, 1 + WHEEL_COLUMNS.len())?
        .into_iter()
        .map(|(stamp_ns, row)| {
            let mut sigma = [0.0; 6];
            for (i, s) in sigma.iter_mut().enumerate() {
                *s = row.number(&name, 7 + i, WHEEL_COLUMNS[6 + i])?;
                if *s < 0.0 {
                    return Err(format_error(&name, row.line, format!("`{}` is negative", WHEEL_COLUMNS[6 + i])));
                }
            }
            Ok(WheelOdomSample {
                stamp_ns,
                linear_mps: row.vector(&name, 1, ["v_x", "v_y", "v_z"])?,
                angular_radps: row.vector(&name, 4, ["w_x", "w_y", "w_z"])?,
                sigma,
            })
        })
        .collect()
}

/// Reads `pantilt0/data.csv` (our extension): `#timestamp [ns],pan [rad],tilt [rad]`.
pub fn parse_pantilt_csv(bytes: &[u8], file: &Path) -> Result<Vec<PanTiltRow>, SensorError> {
    let name = file.display().to_string();
    rows(bytes, &name, 3)?
        .into_iter()
        .map(|(stamp_ns, row)| {
            Ok(PanTiltRow { stamp_ns, pan_rad: row.number(&name, 1, "pan")?, tilt_rad: row.number(&name, 2, "tilt")? })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crlf_headers_and_blank_lines() {
        let text = b"#timestamp [ns],filename\r\n10,10.png\r\n\r\n20, 20.png\r\n";
        let rows = parse_camera_csv(text, Path::new("c.csv")).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[1], CameraRow { stamp_ns: 20, file_name: "20.png".into(), line: 4 });
    }

    #[test]
    fn errors_name_file_line_and_field() {
        let err = parse_imu_csv(b"#h\n1,0,0,0,0,0,0\n2,0,0,x,0,0,0\n", Path::new("i.csv")).unwrap_err();
        let text = err.to_string();
        assert!(text.starts_with("i.csv:3:") && text.contains("w_z") && text.contains("field 4"), "{text}");
        let err = parse_imu_csv(b"2,0,0,0,0,0,0\n1,0,0,0,0,0,0\n", Path::new("i.csv")).unwrap_err();
        assert!(err.to_string().starts_with("i.csv:2:"), "{err}");
        let err = parse_camera_csv(b"1,../x.png\n", Path::new("c.csv")).unwrap_err();
        assert!(err.to_string().contains("plain file name"), "{err}");
        let err = parse_pantilt_csv(b"1,0\n", Path::new("p.csv")).unwrap_err();
        assert!(err.to_string().contains("2 comma-separated fields, expected 3"), "{err}");
    }
}
