//! PLY reader: the `vertex` element's positions (and intensity or the project's obstacle colour).
//!
//! Elements before `vertex` (rare, but legal) are walked over, list properties included; the ones
//! after it (faces) are not read at all.

use super::scalar::{Endian, Scalar, parse_ascii};
use super::{CloudFile, CloudFormat, CloudParseError, PointSink, grey_level};

const FORMAT: &str = "ply";

/// The obstacle colour of `export::point_colour`.
const OBSTACLE_RGB: [u8; 3] = [255, 0, 0];

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Encoding {
    Ascii,
    Binary(Endian),
}

#[derive(Debug, Clone, PartialEq, Eq)]
enum PropertyKind {
    Scalar(Scalar),
    /// `property list COUNT_TYPE ITEM_TYPE name`
    List {
        count: Scalar,
        item: Scalar,
    },
}

#[derive(Debug, Clone, PartialEq, Eq)]
struct Property {
    name: String,
    kind: PropertyKind,
}

#[derive(Debug, Clone, PartialEq, Eq)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

#[derive(Debug)]
struct Header {
    encoding: Encoding,
    elements: Vec<Element>,
    /// The project's export names itself in a comment (`export::write_ply`).
    project_export: bool,
    data_start: usize,
}

fn header_error(message: impl Into<String>) -> CloudParseError {
    CloudParseError::Header { format: FORMAT, message: message.into() }
}

fn data_error(what: impl Into<String>, message: impl Into<String>) -> CloudParseError {
    CloudParseError::Data { format: FORMAT, what: what.into(), message: message.into() }
}

pub(super) fn parse(bytes: &[u8]) -> Result<CloudFile, CloudParseError> {
    let header = parse_header(bytes)?;
    let data = bytes.get(header.data_start..).unwrap_or_default();
    let mut cursor = match header.encoding {
        Encoding::Ascii => Cursor::Ascii(
            std::str::from_utf8(data).map_err(|e| data_error("data", e.to_string()))?.split_ascii_whitespace(),
        ),
        Encoding::Binary(endian) => Cursor::Binary { data, offset: 0, endian },
    };
    for element in &header.elements {
        if element.name == "vertex" {
            return read_vertices(element, &header, &mut cursor, data.len());
        }
        skip_element(element, &mut cursor)?;
    }
    Err(header_error("no vertex element"))
}

fn parse_header(bytes: &[u8]) -> Result<Header, CloudParseError> {
    // The header is ASCII and ends at the line `end_header`; the data follows its newline.
    let mut offset = 0;
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut project_export = false;
    for raw_line in bytes.split_inclusive(|&b| b == b'\n') {
        offset += raw_line.len();
        let line = std::str::from_utf8(raw_line).map_err(|_| header_error("not ASCII before end_header"))?.trim();
        let mut words = line.split_ascii_whitespace();
        match words.next() {
            Some("end_header") => {
                let encoding = encoding.ok_or_else(|| header_error("no format line"))?;
                return Ok(Header { encoding, elements, project_export, data_start: offset });
            }
            Some("format") => {
                encoding = Some(match words.next() {
                    Some("ascii") => Encoding::Ascii,
                    Some("binary_little_endian") => Encoding::Binary(Endian::Little),
                    Some("binary_big_endian") => Encoding::Binary(Endian::Big),
                    other => return Err(header_error(format!("unknown format {:?}", other.unwrap_or("")))),
                });
            }
            Some("comment") => project_export |= line.contains("voxel cloud"),
            Some("element") => {
                let (Some(name), Some(count)) = (words.next(), words.next()) else {
                    return Err(header_error(format!("bad element line '{line}'")));
                };
                let count = count.parse().map_err(|_| header_error(format!("bad element count in '{line}'")))?;
                elements.push(Element { name: name.to_owned(), count, properties: Vec::new() });
            }
            Some("property") => {
                let element = elements.last_mut().ok_or_else(|| header_error("property before any element"))?;
                element.properties.push(parse_property(line, &mut words)?);
            }
            Some("ply" | "obj_info") | None => {}
            Some(other) => return Err(header_error(format!("unknown header keyword '{other}'"))),
        }
    }
    Err(header_error("no end_header line"))
}

fn parse_property<'a>(line: &str, words: &mut impl Iterator<Item = &'a str>) -> Result<Property, CloudParseError> {
    let bad_type = |t: &str| header_error(format!("unknown type '{t}' in '{line}'"));
    let first = words.next().ok_or_else(|| header_error(format!("bad property line '{line}'")))?;
    let kind = if first == "list" {
        let (Some(count), Some(item)) = (words.next(), words.next()) else {
            return Err(header_error(format!("bad list property '{line}'")));
        };
        PropertyKind::List {
            count: Scalar::from_ply(count).ok_or_else(|| bad_type(count))?,
            item: Scalar::from_ply(item).ok_or_else(|| bad_type(item))?,
        }
    } else {
        PropertyKind::Scalar(Scalar::from_ply(first).ok_or_else(|| bad_type(first))?)
    };
    let name = words.next().ok_or_else(|| header_error(format!("property without a name: '{line}'")))?;
    Ok(Property { name: name.to_owned(), kind })
}

/// The data after the header, read value by value.
enum Cursor<'a> {
    Ascii(std::str::SplitAsciiWhitespace<'a>),
    Binary { data: &'a [u8], offset: usize, endian: Endian },
}

impl Cursor<'_> {
    /// The next value of type `scalar`; `None` at the end of the data or on a malformed token.
    fn next(&mut self, scalar: Scalar) -> Result<f64, String> {
        match self {
            Cursor::Ascii(tokens) => {
                let token = tokens.next().ok_or("the data ends early")?;
                parse_ascii(token).ok_or_else(|| format!("'{token}' is not a number"))
            }
            Cursor::Binary { data, offset, endian } => {
                let value =
                    scalar.decode(data.get(*offset..).unwrap_or_default(), *endian).ok_or("the data ends early")?;
                *offset += scalar.size();
                Ok(value)
            }
        }
    }

    /// Reads one property, returning its value (a list's values are skipped: `None`).
    fn property(&mut self, kind: &PropertyKind) -> Result<Option<f64>, String> {
        match kind {
            PropertyKind::Scalar(scalar) => self.next(*scalar).map(Some),
            PropertyKind::List { count, item } => {
                let n = self.next(*count)?;
                if !(n >= 0.0 && n.fract() == 0.0) {
                    return Err(format!("list length {n} is not a count"));
                }
                match self {
                    // Binary lists are skipped in one step; a huge length ends the data.
                    Cursor::Binary { data, offset, .. } => {
                        let len = (n as usize).checked_mul(item.size()).ok_or("list length overflows")?;
                        *offset =
                            offset.checked_add(len).filter(|end| *end <= data.len()).ok_or("the data ends early")?;
                    }
                    Cursor::Ascii(_) => {
                        for _ in 0..n as usize {
                            self.next(*item)?;
                        }
                    }
                }
                Ok(None)
            }
        }
    }
}

fn skip_element(element: &Element, cursor: &mut Cursor<'_>) -> Result<(), CloudParseError> {
    // An element without properties occupies no data, whatever its count says.
    if element.properties.is_empty() {
        return Ok(());
    }
    for index in 0..element.count {
        for property in &element.properties {
            cursor.property(&property.kind).map_err(|m| data_error(format!("{} {index}", element.name), m))?;
        }
    }
    Ok(())
}

/// Where the vertex element keeps what we read.
#[derive(Debug, Default)]
struct VertexLayout {
    xyz: [Option<usize>; 3],
    intensity: Option<usize>,
    rgb: [Option<usize>; 3],
}

fn read_vertices(
    element: &Element,
    header: &Header,
    cursor: &mut Cursor<'_>,
    data_len: usize,
) -> Result<CloudFile, CloudParseError> {
    let mut layout = VertexLayout::default();
    for (i, property) in element.properties.iter().enumerate() {
        let slot = match property.name.as_str() {
            "x" => &mut layout.xyz[0],
            "y" => &mut layout.xyz[1],
            "z" => &mut layout.xyz[2],
            "intensity" | "scalar_intensity" => &mut layout.intensity,
            "red" => &mut layout.rgb[0],
            "green" => &mut layout.rgb[1],
            "blue" => &mut layout.rgb[2],
            _ => continue,
        };
        if matches!(property.kind, PropertyKind::List { .. }) {
            return Err(header_error(format!("vertex property '{}' is a list", property.name)));
        }
        *slot = Some(i);
    }
    let [Some(ix), Some(iy), Some(iz)] = layout.xyz else {
        return Err(header_error("the vertex element lacks x, y or z"));
    };
    let colour = match layout.rgb {
        [Some(r), Some(g), Some(b)] if header.project_export => Some([r, g, b]),
        _ => None,
    };
    let format = if colour.is_some() { CloudFormat::ProjectPly } else { CloudFormat::Ply };
    let min_record = match header.encoding {
        Encoding::Ascii => 2 * element.properties.len(),
        Encoding::Binary(_) => element.properties.len(),
    };
    let mut sink = PointSink::with_capacity(element.count, data_len, min_record);
    let mut values = vec![0.0; element.properties.len()];
    for index in 0..element.count {
        if element.properties.is_empty() {
            break;
        }
        for (value, property) in values.iter_mut().zip(&element.properties) {
            *value =
                cursor.property(&property.kind).map_err(|m| data_error(format!("vertex {index}"), m))?.unwrap_or(0.0);
        }
        let xyz = [values[ix], values[iy], values[iz]];
        match colour {
            Some([r, g, b]) => {
                let rgb = [values[r], values[g], values[b]].map(grey_level);
                let obstacle = rgb == OBSTACLE_RGB;
                // The export writes non-obstacles as grey (r = g = b = intensity).
                sink.push(xyz, if obstacle { 0 } else { rgb[0] }, obstacle);
            }
            None => sink.push(xyz, layout.intensity.map_or(0, |i| grey_level(values[i])), true),
        }
    }
    sink.finish(format)
}
