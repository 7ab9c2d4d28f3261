//! Trajectory files: TUM, KITTI and EuRoC ground-truth CSV readers, TUM and KITTI writers, and
//! format detection from the content.
//!
//! | format | row | stamps |
//! |---|---|---|
//! | TUM | `t x y z qx qy qz qw` (whitespace separated) | seconds, in the row |
//! | KITTI | 3×4 `[R \| t]` row-major (12 numbers) | separate times file (one stamp per line), or the row index |
//! | EuRoC | `#timestamp[ns], p_RS_R_x, y, z, q_RS_w, x, y, z, …` (comma separated, extra columns ignored) | nanoseconds, in the row |
//!
//! Rules shared by all readers, chosen to read what evo reads: blank lines and lines starting
//! with `#` are skipped (the EuRoC header and the `# timestamp tx …` header of evo's TUM files),
//! a leading UTF-8 byte-order mark is ignored, quaternions of any non-zero norm are normalized (as
//! evo's `quaternion_matrix` does: files print rounded components). Unlike evo, stamps must be
//! finite and must not decrease, because association and interpolation assume sorted stamps.
//! A repeated stamp is accepted, unlike in [`Trajectory::new`]: real estimator logs have them
//! (evo's own `V102.txt` repeats 4 of its 807 stamps) and evo keeps both rows, so dropping
//! either would change the pairs and every statistic. Use [`repeated_stamps`] to report them.
//!
//! Every reader is total: any text gives a trajectory or a [`ParseError`] naming the 1-based
//! line, never a panic.

use core::fmt;

use nalgebra::{DMatrix, Isometry3, Matrix3, Quaternion, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::trajectory::Trajectory;

/// Trajectory file formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Tum,
    Kitti,
    Euroc,
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Tum => "TUM",
            Self::Kitti => "KITTI",
            Self::Euroc => "EuRoC CSV",
        })
    }
}

impl core::str::FromStr for Format {
    type Err = UnknownFormatName;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        match name.to_ascii_lowercase().as_str() {
            "tum" => Ok(Self::Tum),
            "kitti" => Ok(Self::Kitti),
            "euroc" => Ok(Self::Euroc),
            _ => Err(UnknownFormatName(name.chars().take(MAX_QUOTED_CHARS).collect())),
        }
    }
}

/// A format name other than `tum`, `kitti` or `euroc`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown trajectory format `{0}` (expected tum, kitti or euroc)")]
pub struct UnknownFormatName(pub String);

/// A read failure. `line` is 1-based; 0 means the file as a whole (e.g. no poses at all).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub struct ParseError {
    pub line: usize,
    pub kind: ParseErrorKind,
}

impl fmt::Display for ParseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.line == 0 { write!(f, "{}", self.kind) } else { write!(f, "line {}: {}", self.line, self.kind) }
    }
}

/// What was wrong. Quoted tokens are cut to a few dozen characters: a corrupt file can hold
/// arbitrarily long ones.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParseErrorKind {
    #[error("{format} row has {found} fields, expected {expected}")]
    FieldCount { format: Format, expected: &'static str, found: usize },
    #[error("field `{field}`: `{token}` is not a number")]
    BadNumber { field: &'static str, token: String },
    #[error("field `{field}`: `{token}` is not finite")]
    NonFinite { field: &'static str, token: String },
    #[error("quaternion norm is zero, too small or too large to define a rotation")]
    BadQuaternion,
    #[error("the 3x3 block is not a rotation matrix (|RᵀR − I| = {deviation:.3e}, det = {det:.6})")]
    NotRotation { deviation: f64, det: f64 },
    #[error("stamp {stamp_s} s is earlier than the previous row's {previous_s} s")]
    Decreasing { stamp_s: f64, previous_s: f64 },
    #[error("{found} stamps in the times file but {expected} poses")]
    TimesCount { expected: usize, found: usize },
    #[error("no poses")]
    Empty,
    #[error("cannot tell the format from a row of {fields} fields (TUM has 8, KITTI 12, EuRoC CSV is comma separated)")]
    UnknownFormat { fields: usize },
}

/// Longest token quoted back in an error.
const MAX_QUOTED_CHARS: usize = 40;

/// Quaternions with a norm below this are rejected: files print about six decimals, so such a
/// quaternion's direction is rounding noise, and real writers never produce one.
const MIN_QUATERNION_NORM: f64 = 1e-6;

/// Largest accepted deviation |RᵀR − I| (Frobenius) of a KITTI rotation block. KITTI files
/// print 6–9 significant digits, which leaves ~1e-6; a block further off is not a rotation.
const MAX_ROTATION_DEVIATION: f64 = 1e-3;

const FIELDS_TUM: [&str; 8] = ["t", "x", "y", "z", "qx", "qy", "qz", "qw"];
const FIELDS_KITTI: [&str; 12] = ["r11", "r12", "r13", "tx", "r21", "r22", "r23", "ty", "r31", "r32", "r33", "tz"];
const FIELDS_EUROC: [&str; 8] = ["timestamp_ns", "p_x", "p_y", "p_z", "q_w", "q_x", "q_y", "q_z"];

/// The data lines of a file: (1-based line number, trimmed content), without blank and `#` lines.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    text.lines().enumerate().filter_map(|(index, raw)| {
        let line = raw.trim();
        (!line.is_empty() && !line.starts_with('#')).then_some((index + 1, line))
    })
}

fn quote(token: &str) -> String {
    token.chars().take(MAX_QUOTED_CHARS).collect()
}

fn parse_number(token: &str, field: &'static str) -> Result<f64, ParseErrorKind> {
    let value: f64 = token.parse().map_err(|_| ParseErrorKind::BadNumber { field, token: quote(token) })?;
    if value.is_finite() { Ok(value) } else { Err(ParseErrorKind::NonFinite { field, token: quote(token) }) }
}

/// Parses the first `N` of `tokens` as the numbers named by `fields` (the caller checked the count).
fn parse_fields<const N: usize>(tokens: &[&str], fields: &[&'static str; N]) -> Result<[f64; N], ParseErrorKind> {
    let mut out = [0.0; N];
    for ((slot, token), field) in out.iter_mut().zip(tokens).zip(fields) {
        *slot = parse_number(token, field)?;
    }
    Ok(out)
}

/// A quaternion whose squared norm is this close to 1 is kept as is: normalizing any finite
/// quaternion leaves its squared norm within a few ε of 1, and re-dividing by the computed norm
/// would move the last bits, so [`write_tum`] output would not read back bit for bit.
const UNIT_NORM_SQUARED_TOLERANCE: f64 = 8.0 * f64::EPSILON;

fn unit_quaternion(w: f64, x: f64, y: f64, z: f64) -> Result<UnitQuaternion<f64>, ParseErrorKind> {
    let q = Quaternion::new(w, x, y, z);
    let norm_squared = q.norm_squared();
    if (norm_squared - 1.0).abs() <= UNIT_NORM_SQUARED_TOLERANCE {
        return Ok(UnitQuaternion::new_unchecked(q));
    }
    let norm = norm_squared.sqrt();
    // A finite quaternion can still overflow its norm; then its direction is not computable.
    if !(norm.is_finite() && norm >= MIN_QUATERNION_NORM) {
        return Err(ParseErrorKind::BadQuaternion);
    }
    Ok(UnitQuaternion::new_unchecked(q / norm))
}

/// Checks that stamps do not decrease, reporting the offending line.
struct StampOrder {
    previous_s: Option<f64>,
}

impl StampOrder {
    fn check(&mut self, stamp_s: f64) -> Result<(), ParseErrorKind> {
        if let Some(previous_s) = self.previous_s
            && stamp_s < previous_s
        {
            return Err(ParseErrorKind::Decreasing { stamp_s, previous_s });
        }
        self.previous_s = Some(stamp_s);
        Ok(())
    }
}

/// Builds the trajectory directly rather than through [`Trajectory::new`], which would reject
/// the repeated stamps the readers accept (see the module documentation); everything else it
/// checks (equal lengths, finite sorted stamps) holds by construction here.
fn finish(stamps_s: Vec<f64>, poses: Vec<Isometry3<f64>>) -> Result<Trajectory, ParseError> {
    if poses.is_empty() {
        return Err(ParseError { line: 0, kind: ParseErrorKind::Empty });
    }
    Ok(Trajectory { stamps_s, poses })
}

/// Number of stamps equal to their predecessor.
pub fn repeated_stamps(trajectory: &Trajectory) -> usize {
    trajectory.stamps_s.windows(2).filter(|w| w[1] == w[0]).count()
}

/// Reads a TUM file: `t x y z qx qy qz qw` per row, stamps in seconds.
pub fn parse_tum(text: &str) -> Result<Trajectory, ParseError> {
    let mut stamps_s = Vec::new();
    let mut poses = Vec::new();
    let mut order = StampOrder { previous_s: None };
    for (line, content) in data_lines(text) {
        let mut row = || -> Result<(f64, Isometry3<f64>), ParseErrorKind> {
            let tokens: Vec<&str> = content.split_whitespace().collect();
            if tokens.len() != FIELDS_TUM.len() {
                return Err(ParseErrorKind::FieldCount { format: Format::Tum, expected: "8", found: tokens.len() });
            }
            let [t, x, y, z, qx, qy, qz, qw] = parse_fields(&tokens, &FIELDS_TUM)?;
            order.check(t)?;
            let rotation = unit_quaternion(qw, qx, qy, qz)?;
            Ok((t, Isometry3::from_parts(Translation3::new(x, y, z), rotation)))
        };
        let (t, pose) = row().map_err(|kind| ParseError { line, kind })?;
        stamps_s.push(t);
        poses.push(pose);
    }
    finish(stamps_s, poses)
}

/// Reads an EuRoC ground-truth CSV (`state_groundtruth_estimate0/data.csv`): timestamp in
/// nanoseconds, position, quaternion `w x y z`, then any number of ignored columns.
///
/// The stamp is converted as evo does (the decimal string rounded to `f64`, divided by 1e9), so
/// association ties break identically; the rounding (≤ 0.3 µs at EuRoC's epoch stamps) is far
/// below any clock's accuracy.
pub fn parse_euroc(text: &str) -> Result<Trajectory, ParseError> {
    let mut stamps_s = Vec::new();
    let mut poses = Vec::new();
    let mut order = StampOrder { previous_s: None };
    for (line, content) in data_lines(text) {
        let mut row = || -> Result<(f64, Isometry3<f64>), ParseErrorKind> {
            let tokens: Vec<&str> = content.split(',').map(str::trim).collect();
            if tokens.len() < FIELDS_EUROC.len() {
                return Err(ParseErrorKind::FieldCount {
                    format: Format::Euroc,
                    expected: "at least 8",
                    found: tokens.len(),
                });
            }
            let [t_ns, x, y, z, qw, qx, qy, qz] = parse_fields(&tokens, &FIELDS_EUROC)?;
            let t = t_ns / 1e9;
            order.check(t)?;
            let rotation = unit_quaternion(qw, qx, qy, qz)?;
            Ok((t, Isometry3::from_parts(Translation3::new(x, y, z), rotation)))
        };
        let (t, pose) = row().map_err(|kind| ParseError { line, kind })?;
        stamps_s.push(t);
        poses.push(pose);
    }
    finish(stamps_s, poses)
}

/// Reads KITTI poses (3×4 `[R | t]` row-major per row). Stamps come from `times` (a KITTI
/// `times.txt`: one stamp in seconds per data line) when given; otherwise the row index is the
/// stamp in seconds, so two untimed KITTI files associate row by row (with any `max_diff` < 0.5 s),
/// which is how KITTI results are compared.
///
/// Errors in `times` are reported with the times file's line numbers.
pub fn parse_kitti(text: &str, times: Option<&str>) -> Result<Trajectory, ParseError> {
    let mut poses = Vec::new();
    for (line, content) in data_lines(text) {
        let row = || -> Result<Isometry3<f64>, ParseErrorKind> {
            let tokens: Vec<&str> = content.split_whitespace().collect();
            if tokens.len() != FIELDS_KITTI.len() {
                return Err(ParseErrorKind::FieldCount { format: Format::Kitti, expected: "12", found: tokens.len() });
            }
            let v = parse_fields(&tokens, &FIELDS_KITTI)?;
            let r = Matrix3::new(v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]);
            let rotation = nearest_rotation(&r)?;
            Ok(Isometry3::from_parts(Translation3::new(v[3], v[7], v[11]), rotation))
        };
        poses.push(row().map_err(|kind| ParseError { line, kind })?);
    }
    let stamps_s = match times {
        Some(times) => parse_times(times, poses.len())?,
        None => (0..poses.len()).map(|i| i as f64).collect(),
    };
    finish(stamps_s, poses)
}

/// Reads a KITTI times file expected to hold `expected` stamps.
pub fn parse_times(text: &str, expected: usize) -> Result<Vec<f64>, ParseError> {
    let mut stamps_s = Vec::new();
    let mut order = StampOrder { previous_s: None };
    for (line, content) in data_lines(text) {
        let mut row = || -> Result<f64, ParseErrorKind> {
            let tokens: Vec<&str> = content.split_whitespace().collect();
            if tokens.len() != 1 {
                return Err(ParseErrorKind::FieldCount {
                    format: Format::Kitti,
                    expected: "1 (a stamp)",
                    found: tokens.len(),
                });
            }
            let t = parse_number(tokens[0], "t")?;
            order.check(t)?;
            Ok(t)
        };
        stamps_s.push(row().map_err(|kind| ParseError { line, kind })?);
    }
    if stamps_s.len() != expected {
        return Err(ParseError { line: 0, kind: ParseErrorKind::TimesCount { expected, found: stamps_s.len() } });
    }
    Ok(stamps_s)
}

/// The rotation nearest (Frobenius) to a printed rotation block, which is orthonormal only up to
/// the printed digits. SVD rather than nalgebra's iterative `from_matrix`, whose identity start
/// can stall on half-turn rotations.
fn nearest_rotation(r: &Matrix3<f64>) -> Result<UnitQuaternion<f64>, ParseErrorKind> {
    let deviation = (r.transpose() * r - Matrix3::identity()).norm();
    let det = r.determinant();
    if !(deviation <= MAX_ROTATION_DEVIATION && det > 0.0) {
        return Err(ParseErrorKind::NotRotation { deviation, det });
    }
    let dynamic = DMatrix::from_column_slice(3, 3, r.as_slice());
    let svd = nalgebra::SVD::try_new(dynamic, true, true, f64::EPSILON, 1000);
    let (Some(u), Some(v_t)) = svd.map_or((None, None), |s| (s.u, s.v_t)) else {
        return Err(ParseErrorKind::NotRotation { deviation, det });
    };
    let product = u * v_t;
    let nearest = Matrix3::from_column_slice(product.as_slice());
    Ok(UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(nearest)))
}

/// Tells the format from the first data line: commas mean EuRoC CSV, otherwise 8 fields mean
/// TUM and 12 KITTI.
pub fn detect_format(text: &str) -> Result<Format, ParseError> {
    let Some((line, content)) = data_lines(text).next() else {
        return Err(ParseError { line: 0, kind: ParseErrorKind::Empty });
    };
    if content.contains(',') {
        return Ok(Format::Euroc);
    }
    match content.split_whitespace().count() {
        8 => Ok(Format::Tum),
        12 => Ok(Format::Kitti),
        fields => Err(ParseError { line, kind: ParseErrorKind::UnknownFormat { fields } }),
    }
}

/// Reads `text` in `format`, or in the detected format when `format` is `None`. KITTI files are
/// read without a times file; use [`parse_kitti`] to give one.
pub fn parse(text: &str, format: Option<Format>) -> Result<(Format, Trajectory), ParseError> {
    let format = match format {
        Some(format) => format,
        None => detect_format(text)?,
    };
    let trajectory = match format {
        Format::Tum => parse_tum(text)?,
        Format::Kitti => parse_kitti(text, None)?,
        Format::Euroc => parse_euroc(text)?,
    };
    Ok((format, trajectory))
}

/// Writes `t x y z qx qy qz qw` rows with Rust's shortest round-trip formatting, so reading the
/// output back gives the same numbers bit for bit.
pub fn write_tum(trajectory: &Trajectory, out: &mut impl fmt::Write) -> fmt::Result {
    for (t, pose) in trajectory.stamps_s.iter().zip(&trajectory.poses) {
        let p = pose.translation.vector;
        let q = pose.rotation.quaternion();
        writeln!(out, "{t} {} {} {} {} {} {} {}", p.x, p.y, p.z, q.i, q.j, q.k, q.w)?;
    }
    Ok(())
}

/// Writes the poses as KITTI rows (3×4 `[R | t]` row-major). KITTI has no stamps: write them
/// with [`write_times`].
pub fn write_kitti(trajectory: &Trajectory, out: &mut impl fmt::Write) -> fmt::Result {
    for pose in &trajectory.poses {
        let r = pose.rotation.to_rotation_matrix().into_inner();
        let t: Vector3<f64> = pose.translation.vector;
        for row in 0..3 {
            let sep = if row == 0 { "" } else { " " };
            write!(out, "{sep}{} {} {} {}", r[(row, 0)], r[(row, 1)], r[(row, 2)], t[row])?;
        }
        writeln!(out)?;
    }
    Ok(())
}

/// Writes a KITTI times file: one stamp in seconds per line.
pub fn write_times(trajectory: &Trajectory, out: &mut impl fmt::Write) -> fmt::Result {
    for t in &trajectory.stamps_s {
        writeln!(out, "{t}")?;
    }
    Ok(())
}
