//! PCD reader (PCL's format, v0.5 to v0.7): `DATA ascii` and `DATA binary`; `binary_compressed`
//! (LZF) is refused with a message. Every point is an obstacle.

use super::scalar::{Endian, Scalar, parse_ascii};
use super::{CloudFile, CloudFormat, CloudParseError, PointSink, grey_level};

const FORMAT: &str = "pcd";

fn header_error(message: impl Into<String>) -> CloudParseError {
    CloudParseError::Header { format: FORMAT, message: message.into() }
}

fn data_error(what: impl Into<String>, message: impl Into<String>) -> CloudParseError {
    CloudParseError::Data { format: FORMAT, what: what.into(), message: message.into() }
}

#[derive(Debug, Clone, PartialEq, Eq)]
struct Field {
    name: String,
    scalar: Scalar,
    /// Values per point (`COUNT`; e.g. 33 for an FPFH histogram).
    count: usize,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum DataKind {
    Ascii,
    Binary,
}

#[derive(Debug)]
struct Header {
    fields: Vec<Field>,
    points: usize,
    kind: DataKind,
    data_start: usize,
}

pub(super) fn parse(bytes: &[u8]) -> Result<CloudFile, CloudParseError> {
    let header = parse_header(bytes)?;
    let data = bytes.get(header.data_start..).unwrap_or_default();
    // Offsets of x, y, z and intensity in a record's values (ASCII) or bytes (binary).
    let mut value_index = 0;
    let mut byte_offset = 0usize;
    let mut slots: [Option<(usize, usize, Scalar)>; 4] = [None; 4];
    for field in &header.fields {
        let slot = match field.name.as_str() {
            "x" => Some(0),
            "y" => Some(1),
            "z" => Some(2),
            "intensity" => Some(3),
            _ => None,
        };
        if let Some(slot) = slot {
            slots[slot] = Some((value_index, byte_offset, field.scalar));
        }
        value_index += field.count;
        byte_offset = field
            .scalar
            .size()
            .checked_mul(field.count)
            .and_then(|n| n.checked_add(byte_offset))
            .ok_or_else(|| header_error("record size overflows"))?;
    }
    let [Some(x), Some(y), Some(z), intensity] = slots else {
        return Err(header_error("FIELDS lacks x, y or z"));
    };
    let (values_per_point, record_len) = (value_index, byte_offset);
    match header.kind {
        DataKind::Ascii => read_ascii(data, &header, values_per_point, [x.0, y.0, z.0], intensity.map(|i| i.0)),
        DataKind::Binary => {
            let at = |s: (usize, usize, Scalar)| (s.1, s.2);
            read_binary(data, &header, record_len, [at(x), at(y), at(z)], intensity.map(at))
        }
    }
}

fn parse_header(bytes: &[u8]) -> Result<Header, CloudParseError> {
    let mut offset = 0;
    let (mut names, mut sizes, mut types, mut counts) = (Vec::new(), Vec::new(), Vec::new(), None);
    let (mut width, mut height, mut points) = (None, None, None);
    for raw_line in bytes.split_inclusive(|&b| b == b'\n') {
        offset += raw_line.len();
        let line = std::str::from_utf8(raw_line).map_err(|_| header_error("not ASCII before DATA"))?.trim();
        let mut words = line.split_ascii_whitespace();
        let keyword = words.next();
        let rest: Vec<&str> = words.collect();
        let number = |what: &str| -> Result<usize, CloudParseError> {
            rest.first().and_then(|w| w.parse().ok()).ok_or_else(|| header_error(format!("bad {what} line '{line}'")))
        };
        match keyword {
            None => {}
            Some(k) if k.starts_with('#') => {}
            Some("VERSION" | "VIEWPOINT") => {}
            Some("FIELDS" | "COLUMNS") => names = rest.iter().map(|s| (*s).to_owned()).collect(),
            Some("SIZE") => sizes = rest.iter().map(|s| (*s).to_owned()).collect(),
            Some("TYPE") => types = rest.iter().map(|s| (*s).to_owned()).collect(),
            Some("COUNT") => {
                let parsed: Option<Vec<usize>> = rest.iter().map(|s| s.parse().ok()).collect();
                counts = Some(parsed.ok_or_else(|| header_error(format!("bad COUNT line '{line}'")))?);
            }
            Some("WIDTH") => width = Some(number("WIDTH")?),
            Some("HEIGHT") => height = Some(number("HEIGHT")?),
            Some("POINTS") => points = Some(number("POINTS")?),
            Some("DATA") => {
                let kind = match rest.first().copied() {
                    Some("ascii") => DataKind::Ascii,
                    Some("binary") => DataKind::Binary,
                    Some("binary_compressed") => {
                        return Err(header_error("DATA binary_compressed is not supported (save as ascii or binary)"));
                    }
                    other => return Err(header_error(format!("unknown DATA {:?}", other.unwrap_or("")))),
                };
                let counts = counts.unwrap_or_else(|| vec![1; names.len()]);
                if sizes.len() != names.len() || types.len() != names.len() || counts.len() != names.len() {
                    return Err(header_error("FIELDS, SIZE, TYPE and COUNT differ in length"));
                }
                let mut fields = Vec::with_capacity(names.len());
                for (((name, size), kind), count) in names.into_iter().zip(&sizes).zip(&types).zip(counts) {
                    let scalar = Scalar::from_pcd(kind, size)
                        .ok_or_else(|| header_error(format!("field {name}: unknown TYPE {kind} SIZE {size}")))?;
                    fields.push(Field { name, scalar, count });
                }
                // POINTS is authoritative; older files give only WIDTH and HEIGHT.
                let points = match (points, width, height) {
                    (Some(p), _, _) => p,
                    (None, Some(w), Some(h)) => {
                        w.checked_mul(h).ok_or_else(|| header_error("WIDTH·HEIGHT overflows"))?
                    }
                    _ => return Err(header_error("neither POINTS nor WIDTH and HEIGHT")),
                };
                return Ok(Header { fields, points, kind, data_start: offset });
            }
            Some(other) => return Err(header_error(format!("unknown header keyword '{other}'"))),
        }
    }
    Err(header_error("no DATA line"))
}

fn read_ascii(
    data: &[u8],
    header: &Header,
    values_per_point: usize,
    xyz: [usize; 3],
    intensity: Option<usize>,
) -> Result<CloudFile, CloudParseError> {
    let text = std::str::from_utf8(data).map_err(|e| data_error("data", e.to_string()))?;
    let mut sink = PointSink::with_capacity(header.points, data.len(), 2 * values_per_point);
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    let mut values = Vec::with_capacity(values_per_point);
    for index in 0..header.points {
        let line = lines.next().ok_or_else(|| data_error(format!("point {index}"), "the data ends early"))?;
        values.clear();
        for token in line.split_ascii_whitespace() {
            // PCL writes "nan" for no return; Rust spells it "NaN" too, both parse.
            values.push(
                parse_ascii(token)
                    .ok_or_else(|| data_error(format!("point {index}"), format!("'{token}' is not a number")))?,
            );
        }
        if values.len() != values_per_point {
            return Err(data_error(
                format!("point {index}"),
                format!("{} values, the header says {values_per_point}", values.len()),
            ));
        }
        let xyz_value = xyz.map(|i| values[i]);
        sink.push(xyz_value, intensity.map_or(0, |i| grey_level(values[i])), true);
    }
    sink.finish(CloudFormat::Pcd)
}

fn read_binary(
    data: &[u8],
    header: &Header,
    record_len: usize,
    xyz: [(usize, Scalar); 3],
    intensity: Option<(usize, Scalar)>,
) -> Result<CloudFile, CloudParseError> {
    if record_len == 0 {
        return Err(header_error("zero-size records"));
    }
    let needed = record_len.checked_mul(header.points).ok_or_else(|| header_error("POINTS·record size overflows"))?;
    if data.len() < needed {
        return Err(data_error(
            "data",
            format!("{} bytes for {} points of {record_len} bytes", data.len(), header.points),
        ));
    }
    let mut sink = PointSink::with_capacity(header.points, data.len(), record_len);
    for record in data.chunks_exact(record_len).take(header.points) {
        let value = |(offset, scalar): (usize, Scalar)| {
            record.get(offset..).and_then(|b| scalar.decode(b, Endian::Little)).unwrap_or(f64::NAN)
        };
        sink.push(xyz.map(value), intensity.map_or(0, |i| grey_level(value(i))), true);
    }
    sink.finish(CloudFormat::Pcd)
}
