//! Map evaluation: PLY point-cloud and height-grid readers, height error of a map against a
//! ground-truth heightfield, and obstacle precision/recall against the simulator's true obstacles.
//!
//! Everything here works on bytes and text already in memory; reading files is the caller's job.
//! Coordinates are world metres: `x`, `y` horizontal, `z` up.

use std::collections::{HashMap, HashSet};
use std::fmt::Write as _;

use nalgebra::{Point2, Point3};

// ---------------------------------------------------------------------------------------------
// PLY point clouds
// ---------------------------------------------------------------------------------------------

/// Why a PLY file could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlyError {
    #[error("not a PLY file: the first line must be `ply`")]
    NotPly,
    #[error("the header has no `end_header` line")]
    UnterminatedHeader,
    #[error("header line {line}: {reason}")]
    Header { line: usize, reason: String },
    #[error("unsupported PLY format `{0}`: only `ascii` and `binary_little_endian` are read")]
    UnsupportedFormat(String),
    #[error("the header has no `format` line")]
    MissingFormat,
    #[error("the header declares no `vertex` element")]
    NoVertexElement,
    #[error("the vertex element has no scalar `{0}` property")]
    MissingCoordinate(&'static str),
    #[error("data ends inside element `{element}` number {index}")]
    Truncated { element: String, index: usize },
    #[error("element `{element}` number {index}: `{token}` is not a number of the declared type")]
    BadValue { element: String, index: usize, token: String },
    #[error("element `{element}` number {index}: list length {length} is not a non-negative integer")]
    BadListLength { element: String, index: usize, length: f64 },
    #[error("vertex {index} has a non-finite coordinate")]
    NonFinite { index: usize },
}

/// The two PLY encodings this module reads and writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlyFormat {
    Ascii,
    BinaryLittleEndian,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn size_bytes(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    fn is_integer(self) -> bool {
        !matches!(self, Self::F32 | Self::F64)
    }

    /// Decodes one little-endian value from the front of `bytes`.
    fn read_le(self, bytes: &[u8]) -> Option<f64> {
        fn arr<const N: usize>(bytes: &[u8]) -> Option<[u8; N]> {
            bytes.get(..N)?.try_into().ok()
        }
        Some(match self {
            Self::I8 => f64::from(i8::from_le_bytes(arr(bytes)?)),
            Self::U8 => f64::from(u8::from_le_bytes(arr(bytes)?)),
            Self::I16 => f64::from(i16::from_le_bytes(arr(bytes)?)),
            Self::U16 => f64::from(u16::from_le_bytes(arr(bytes)?)),
            Self::I32 => f64::from(i32::from_le_bytes(arr(bytes)?)),
            Self::U32 => f64::from(u32::from_le_bytes(arr(bytes)?)),
            Self::F32 => f64::from(f32::from_le_bytes(arr(bytes)?)),
            Self::F64 => f64::from_le_bytes(arr(bytes)?),
        })
    }
}

#[derive(Debug, Clone)]
enum Property {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug, Clone)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<(String, Property)>,
}

struct Header {
    format: PlyFormat,
    elements: Vec<Element>,
    /// Offset of the first data byte.
    data_start: usize,
}

fn parse_ply_header(bytes: &[u8]) -> Result<Header, PlyError> {
    let mut pos = 0;
    let mut line_no = 0;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        let Some(len) = bytes.get(pos..).and_then(|rest| rest.iter().position(|&b| b == b'\n')) else {
            return Err(if line_no == 0 { PlyError::NotPly } else { PlyError::UnterminatedHeader });
        };
        let raw = &bytes[pos..pos + len];
        pos += len + 1;
        line_no += 1;
        // Writers on Windows end header lines with CRLF; the data after `end_header` is untouched.
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        let header_err = |reason: &str| PlyError::Header { line: line_no, reason: reason.to_owned() };
        let Ok(line) = std::str::from_utf8(raw) else {
            return Err(if line_no == 1 { PlyError::NotPly } else { header_err("not ASCII text") });
        };
        if line_no == 1 {
            if line.trim_end() != "ply" {
                return Err(PlyError::NotPly);
            }
            continue;
        }
        let mut words = line.split_ascii_whitespace();
        match words.next() {
            None | Some("comment" | "obj_info") => {}
            Some("format") => {
                let name = words.next().ok_or_else(|| header_err("`format` without a name"))?;
                format = Some(match name {
                    "ascii" => PlyFormat::Ascii,
                    "binary_little_endian" => PlyFormat::BinaryLittleEndian,
                    other => return Err(PlyError::UnsupportedFormat(other.to_owned())),
                });
            }
            Some("element") => {
                let (Some(name), Some(count), None) = (words.next(), words.next(), words.next()) else {
                    return Err(header_err("expected `element <name> <count>`"));
                };
                let count = count.parse().map_err(|_| header_err("element count is not a non-negative integer"))?;
                elements.push(Element { name: name.to_owned(), count, properties: Vec::new() });
            }
            Some("property") => {
                let element = elements.last_mut().ok_or_else(|| header_err("`property` before any `element`"))?;
                let words: Vec<&str> = words.collect();
                let scalar = |name: &str| Scalar::from_name(name).ok_or_else(|| header_err("unknown property type"));
                let (name, property) = match words.as_slice() {
                    ["list", count, item, name] => {
                        let count = scalar(count)?;
                        if !count.is_integer() {
                            return Err(header_err("list length type must be an integer type"));
                        }
                        (*name, Property::List { count, item: scalar(item)? })
                    }
                    [ty, name] => (*name, Property::Scalar(scalar(ty)?)),
                    _ => {
                        return Err(header_err(
                            "expected `property <type> <name>` or `property list <type> <type> <name>`",
                        ));
                    }
                };
                element.properties.push((name.to_owned(), property));
            }
            Some("end_header") => break,
            Some(_) => return Err(header_err("unknown header keyword")),
        }
    }
    let format = format.ok_or(PlyError::MissingFormat)?;
    Ok(Header { format, elements, data_start: pos })
}

/// Reads the vertex positions of a PLY point cloud.
///
/// Accepts `ascii` and `binary_little_endian` files; the vertex element must have scalar `x`, `y`
/// and `z` properties of any numeric type (normally `float` or `double`). Other properties and
/// other elements are skipped. Non-finite coordinates are an error rather than silently dropped,
/// because a NaN in a map file means the writer is broken.
pub fn parse_ply(bytes: &[u8]) -> Result<Vec<Point3<f64>>, PlyError> {
    let header = parse_ply_header(bytes)?;
    let vertex_at = header.elements.iter().position(|e| e.name == "vertex").ok_or(PlyError::NoVertexElement)?;
    let vertex = &header.elements[vertex_at];
    let coordinate = |axis: &'static str| {
        vertex
            .properties
            .iter()
            .position(|(name, p)| name == axis && matches!(p, Property::Scalar(_)))
            .ok_or(PlyError::MissingCoordinate(axis))
    };
    let xyz = [coordinate("x")?, coordinate("y")?, coordinate("z")?];
    let data = bytes.get(header.data_start..).unwrap_or_default();
    let mut reader: Box<dyn ValueReader + '_> = match header.format {
        PlyFormat::Ascii => {
            Box::new(AsciiReader { tokens: data.split(u8::is_ascii_whitespace).filter(|t| !t.is_empty()) })
        }
        PlyFormat::BinaryLittleEndian => Box::new(BinaryReader { data, pos: 0 }),
    };
    // Elements before the vertex element have to be walked over: list properties give them a
    // variable size, so there is no way to jump.
    for element in &header.elements[..vertex_at] {
        for index in 0..element.count {
            if element.properties.is_empty() {
                break; // Nothing to consume, however many instances the header claims.
            }
            let ctx = Ctx { element: &element.name, index };
            for (_, property) in &element.properties {
                reader.skip_property(property, &ctx)?;
            }
        }
    }
    // The header's count is untrusted: reserve no more than the data could hold.
    let max_possible = data.len() / vertex.properties.len().max(1);
    let mut points = Vec::with_capacity(vertex.count.min(max_possible));
    let mut values = vec![0.0; vertex.properties.len()];
    for index in 0..vertex.count {
        let ctx = Ctx { element: &vertex.name, index };
        for (slot, (_, property)) in values.iter_mut().zip(&vertex.properties) {
            match property {
                Property::Scalar(ty) => *slot = reader.scalar(*ty, &ctx)?,
                list => reader.skip_property(list, &ctx)?,
            }
        }
        let point = Point3::new(values[xyz[0]], values[xyz[1]], values[xyz[2]]);
        if !point.iter().all(|v| v.is_finite()) {
            return Err(PlyError::NonFinite { index });
        }
        points.push(point);
    }
    Ok(points)
}

struct Ctx<'a> {
    element: &'a str,
    index: usize,
}

impl Ctx<'_> {
    fn truncated(&self) -> PlyError {
        PlyError::Truncated { element: self.element.to_owned(), index: self.index }
    }
}

/// One source of values for both encodings, so the element walk above is written once.
trait ValueReader {
    fn scalar(&mut self, ty: Scalar, ctx: &Ctx<'_>) -> Result<f64, PlyError>;
    fn skip(&mut self, ty: Scalar, n: usize, ctx: &Ctx<'_>) -> Result<(), PlyError>;

    fn skip_property(&mut self, property: &Property, ctx: &Ctx<'_>) -> Result<(), PlyError> {
        match *property {
            Property::Scalar(ty) => self.skip(ty, 1, ctx),
            Property::List { count, item } => {
                let length = self.scalar(count, ctx)?;
                if !(length >= 0.0 && length.fract() == 0.0 && length <= usize::MAX as f64) {
                    return Err(PlyError::BadListLength { element: ctx.element.to_owned(), index: ctx.index, length });
                }
                self.skip(item, length as usize, ctx)
            }
        }
    }
}

struct AsciiReader<I> {
    tokens: I,
}

impl<'a, I: Iterator<Item = &'a [u8]>> ValueReader for AsciiReader<I> {
    fn scalar(&mut self, _ty: Scalar, ctx: &Ctx<'_>) -> Result<f64, PlyError> {
        let token = self.tokens.next().ok_or_else(|| ctx.truncated())?;
        std::str::from_utf8(token).ok().and_then(|s| s.parse::<f64>().ok()).ok_or_else(|| PlyError::BadValue {
            element: ctx.element.to_owned(),
            index: ctx.index,
            token: String::from_utf8_lossy(token).chars().take(40).collect(),
        })
    }

    fn skip(&mut self, _ty: Scalar, n: usize, ctx: &Ctx<'_>) -> Result<(), PlyError> {
        // Each step consumes a token or stops, so a huge claimed list length ends at the data's end.
        for _ in 0..n {
            self.tokens.next().ok_or_else(|| ctx.truncated())?;
        }
        Ok(())
    }
}

struct BinaryReader<'a> {
    data: &'a [u8],
    pos: usize,
}

impl ValueReader for BinaryReader<'_> {
    fn scalar(&mut self, ty: Scalar, ctx: &Ctx<'_>) -> Result<f64, PlyError> {
        let value = self.data.get(self.pos..).and_then(|rest| ty.read_le(rest)).ok_or_else(|| ctx.truncated())?;
        self.pos += ty.size_bytes();
        Ok(value)
    }

    fn skip(&mut self, ty: Scalar, n: usize, ctx: &Ctx<'_>) -> Result<(), PlyError> {
        let end = n.checked_mul(ty.size_bytes()).and_then(|len| self.pos.checked_add(len));
        match end {
            Some(end) if end <= self.data.len() => {
                self.pos = end;
                Ok(())
            }
            _ => Err(ctx.truncated()),
        }
    }
}

/// Encodes points as a PLY file with one `vertex` element of `double` x, y, z. The simulator and
/// the tests use it; [`parse_ply`] reads it back bit-exactly.
pub fn ply_bytes(points: &[Point3<f64>], format: PlyFormat) -> Vec<u8> {
    let name = match format {
        PlyFormat::Ascii => "ascii",
        PlyFormat::BinaryLittleEndian => "binary_little_endian",
    };
    let mut out = format!(
        "ply\nformat {name} 1.0\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nend_header\n",
        points.len()
    )
    .into_bytes();
    for p in points {
        match format {
            // `{:?}` prints the shortest text that parses back to the same f64.
            PlyFormat::Ascii => out.extend_from_slice(format!("{:?} {:?} {:?}\n", p.x, p.y, p.z).as_bytes()),
            PlyFormat::BinaryLittleEndian => p.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes())),
        }
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Height grids
// ---------------------------------------------------------------------------------------------

/// A regular grid of terrain heights, NaN where unknown.
///
/// Cell `(col, row)` is centred at `origin_m + (col, row) · resolution_m` and covers half a cell
/// either side of its centre; rows run along +y, columns along +x. `heights_m` is row-major:
/// index `row · cols + col`.
#[derive(Debug, Clone, PartialEq)]
pub struct HeightGrid {
    pub resolution_m: f64,
    /// World (x, y) of the centre of cell (0, 0).
    pub origin_m: (f64, f64),
    pub cols: usize,
    pub rows: usize,
    pub heights_m: Vec<f32>,
}

/// Why a height grid could not be built or read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum HeightGridError {
    #[error("the first line must be `HEIGHTGRID v1 <cols> <rows> <resolution_m> <origin_x_m> <origin_y_m>`")]
    BadMagic,
    #[error("header field `{field}`: {reason}")]
    BadHeader { field: &'static str, reason: &'static str },
    #[error("{len} heights do not fill a {cols} × {rows} grid")]
    SizeMismatch { len: usize, cols: usize, rows: usize },
    #[error("line {line}: {found} heights, expected {expected}")]
    RowLength { line: usize, found: usize, expected: usize },
    #[error("line {line}, value {value}: `{token}` is neither a finite number nor `nan`")]
    BadHeight { line: usize, value: usize, token: String },
    #[error("{found} rows of heights, expected {expected}")]
    RowCount { found: usize, expected: usize },
}

/// The magic word and version that open the text format.
pub const HEIGHT_GRID_MAGIC: &str = "HEIGHTGRID v1";

impl HeightGrid {
    /// Builds a grid, checking that the geometry is usable and the heights fill it.
    pub fn new(
        resolution_m: f64,
        origin_m: (f64, f64),
        cols: usize,
        rows: usize,
        heights_m: Vec<f32>,
    ) -> Result<Self, HeightGridError> {
        if !(resolution_m.is_finite() && resolution_m > 0.0) {
            return Err(HeightGridError::BadHeader { field: "resolution_m", reason: "must be finite and positive" });
        }
        if !origin_m.0.is_finite() || !origin_m.1.is_finite() {
            return Err(HeightGridError::BadHeader { field: "origin", reason: "must be finite" });
        }
        if cols == 0 || rows == 0 {
            return Err(HeightGridError::BadHeader { field: "cols/rows", reason: "a grid needs at least one cell" });
        }
        if cols.checked_mul(rows) != Some(heights_m.len()) {
            return Err(HeightGridError::SizeMismatch { len: heights_m.len(), cols, rows });
        }
        Ok(Self { resolution_m, origin_m, cols, rows, heights_m })
    }

    /// Reads the text format:
    ///
    /// ```text
    /// HEIGHTGRID v1 <cols> <rows> <resolution_m> <origin_x_m> <origin_y_m>
    /// <row 0: cols heights in m, whitespace-separated, `nan` = unknown>
    /// ...
    /// <row rows-1>
    /// ```
    ///
    /// Row 0 is the southernmost (smallest y) row; trailing blank lines are allowed.
    pub fn parse(text: &str) -> Result<Self, HeightGridError> {
        let mut lines = text.lines().enumerate().map(|(i, line)| (i + 1, line));
        let header = lines.next().map(|(_, l)| l).unwrap_or_default();
        let fields: Vec<&str> = header.split_ascii_whitespace().collect();
        let ["HEIGHTGRID", "v1", cols, rows, resolution, origin_x, origin_y] = fields.as_slice() else {
            return Err(HeightGridError::BadMagic);
        };
        let count = |field, s: &str| {
            s.parse::<usize>().map_err(|_| HeightGridError::BadHeader { field, reason: "not a non-negative integer" })
        };
        let real =
            |field, s: &str| s.parse::<f64>().map_err(|_| HeightGridError::BadHeader { field, reason: "not a number" });
        let (cols, rows) = (count("cols", cols)?, count("rows", rows)?);
        let resolution_m = real("resolution_m", resolution)?;
        let origin_m = (real("origin_x_m", origin_x)?, real("origin_y_m", origin_y)?);
        let total = cols.checked_mul(rows).ok_or(HeightGridError::SizeMismatch { len: 0, cols, rows })?;
        // The header is untrusted: never reserve more than the text could hold (two bytes a value).
        let mut heights_m = Vec::with_capacity(total.min(text.len() / 2 + 1));
        let mut rows_found = 0;
        for (line_no, line) in lines {
            if line.trim().is_empty() {
                continue;
            }
            if rows_found == rows {
                return Err(HeightGridError::RowCount { found: rows_found + 1, expected: rows });
            }
            let before = heights_m.len();
            for (i, token) in line.split_ascii_whitespace().enumerate() {
                heights_m.push(parse_height(token).ok_or_else(|| HeightGridError::BadHeight {
                    line: line_no,
                    value: i + 1,
                    token: token.chars().take(40).collect(),
                })?);
            }
            let found = heights_m.len() - before;
            if found != cols {
                return Err(HeightGridError::RowLength { line: line_no, found, expected: cols });
            }
            rows_found += 1;
        }
        if rows_found != rows {
            return Err(HeightGridError::RowCount { found: rows_found, expected: rows });
        }
        Self::new(resolution_m, origin_m, cols, rows, heights_m)
    }

    /// Writes the text format read by [`HeightGrid::parse`]; heights round-trip exactly.
    pub fn to_text(&self) -> String {
        let mut out = format!(
            "{HEIGHT_GRID_MAGIC} {} {} {:?} {:?} {:?}\n",
            self.cols, self.rows, self.resolution_m, self.origin_m.0, self.origin_m.1
        );
        for row in self.heights_m.chunks(self.cols.max(1)) {
            for (i, h) in row.iter().enumerate() {
                let sep = if i == 0 { "" } else { " " };
                // `{:?}` is the shortest text that parses back to the same f32.
                let _ = if h.is_nan() { write!(out, "{sep}nan") } else { write!(out, "{sep}{h:?}") };
            }
            out.push('\n');
        }
        out
    }

    /// World (x, y) of a cell's centre.
    pub fn cell_centre_m(&self, col: usize, row: usize) -> Point2<f64> {
        Point2::new(self.origin_m.0 + col as f64 * self.resolution_m, self.origin_m.1 + row as f64 * self.resolution_m)
    }

    /// The cell whose footprint contains (x, y), if inside the grid.
    pub fn cell_at(&self, x_m: f64, y_m: f64) -> Option<(usize, usize)> {
        let col = ((x_m - self.origin_m.0) / self.resolution_m).round();
        let row = ((y_m - self.origin_m.1) / self.resolution_m).round();
        // NaN fails both comparisons, so non-finite input lands outside.
        let inside = |v: f64, n: usize| v >= 0.0 && v < n as f64;
        (inside(col, self.cols) && inside(row, self.rows)).then_some((col as usize, row as usize))
    }

    /// The height of a cell, `None` if unknown or outside the grid.
    pub fn height_at_cell_m(&self, col: usize, row: usize) -> Option<f64> {
        if col >= self.cols || row >= self.rows {
            return None;
        }
        let h = *self.heights_m.get(row * self.cols + col)?;
        (!h.is_nan()).then_some(f64::from(h))
    }

    /// Height at (x, y) by bilinear interpolation between the four surrounding cell centres.
    ///
    /// `None` when the cell containing (x, y) is unknown or outside the grid. Unknown neighbours
    /// are left out and the remaining weights renormalised, so the map's known border cells still
    /// get a height instead of shrinking the usable area by half a cell.
    pub fn sample_bilinear_m(&self, x_m: f64, y_m: f64) -> Option<f64> {
        let (col, row) = self.cell_at(x_m, y_m)?;
        self.height_at_cell_m(col, row)?;
        // Between the outermost centre and the grid edge there is nothing to interpolate towards:
        // clamping holds the height constant there.
        let fx = ((x_m - self.origin_m.0) / self.resolution_m).clamp(0.0, (self.cols - 1) as f64);
        let fy = ((y_m - self.origin_m.1) / self.resolution_m).clamp(0.0, (self.rows - 1) as f64);
        let (c0, r0) = (fx.floor() as usize, fy.floor() as usize);
        let (c1, r1) = ((c0 + 1).min(self.cols - 1), (r0 + 1).min(self.rows - 1));
        let (ax, ay) = (fx - c0 as f64, fy - r0 as f64);
        let corners = [
            (c0, r0, (1.0 - ax) * (1.0 - ay)),
            (c1, r0, ax * (1.0 - ay)),
            (c0, r1, (1.0 - ax) * ay),
            (c1, r1, ax * ay),
        ];
        let (mut sum, mut weight) = (0.0, 0.0);
        for (c, r, w) in corners {
            if let Some(h) = self.height_at_cell_m(c, r) {
                sum += w * h;
                weight += w;
            }
        }
        // The containing cell is the nearest corner, weight ≥ 1/4, so `weight` is positive.
        (weight > 0.0).then(|| sum / weight)
    }

    /// Number of cells with a known height.
    pub fn known_cells(&self) -> usize {
        self.heights_m.iter().filter(|h| !h.is_nan()).count()
    }

    /// Centres of the known cells whose value satisfies `predicate`: e.g. obstacle cells of a
    /// flag grid stored in this format with 1 = obstacle, 0 = free.
    pub fn cell_centres_where(&self, predicate: impl Fn(f64) -> bool) -> Vec<Point2<f64>> {
        let mut out = Vec::new();
        for row in 0..self.rows {
            for col in 0..self.cols {
                if self.height_at_cell_m(col, row).is_some_and(&predicate) {
                    out.push(self.cell_centre_m(col, row));
                }
            }
        }
        out
    }
}

fn parse_height(token: &str) -> Option<f32> {
    if token.eq_ignore_ascii_case("nan") {
        return Some(f32::NAN);
    }
    // Rust also parses "inf" and "NaN" spellings: only finite numbers are heights.
    token.parse::<f32>().ok().filter(|h| h.is_finite())
}

// ---------------------------------------------------------------------------------------------
// Height error
// ---------------------------------------------------------------------------------------------

/// Summary of signed errors (map − ground truth), in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorStats {
    pub count: usize,
    pub rmse_m: f64,
    /// Mean signed error: the map's bias (positive = map above ground truth).
    pub mean_m: f64,
    /// Standard deviation of the signed error around its mean.
    pub std_m: f64,
    pub median_abs_m: f64,
    pub p95_abs_m: f64,
    pub max_abs_m: f64,
}

impl ErrorStats {
    /// Statistics of the finite values in `errors_m`; `None` if there are none. Percentiles
    /// interpolate linearly between order statistics (NumPy's default), so the median of two
    /// values is their mean.
    pub fn from_errors(errors_m: &[f64]) -> Option<Self> {
        let finite: Vec<f64> = errors_m.iter().copied().filter(|e| e.is_finite()).collect();
        if finite.is_empty() {
            return None;
        }
        let n = finite.len() as f64;
        let mean_m = finite.iter().sum::<f64>() / n;
        let rmse_m = (finite.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
        let std_m = (finite.iter().map(|e| (e - mean_m).powi(2)).sum::<f64>() / n).sqrt();
        let mut abs: Vec<f64> = finite.iter().map(|e| e.abs()).collect();
        abs.sort_by(f64::total_cmp);
        Some(Self {
            count: finite.len(),
            rmse_m,
            mean_m,
            std_m,
            median_abs_m: percentile_sorted(&abs, 0.5),
            p95_abs_m: percentile_sorted(&abs, 0.95),
            max_abs_m: abs.last().copied().unwrap_or(0.0),
        })
    }
}

fn percentile_sorted(sorted: &[f64], q: f64) -> f64 {
    let Some(last) = sorted.len().checked_sub(1) else { return f64::NAN };
    let rank = q * last as f64;
    let (lo, hi) = (rank.floor() as usize, rank.ceil() as usize);
    let (a, b) = (sorted[lo.min(last)], sorted[hi.min(last)]);
    a + (b - a) * (rank - lo as f64)
}

/// Height error of a map against a ground-truth heightfield.
#[derive(Debug, Clone, PartialEq)]
pub struct HeightErrorReport {
    /// Statistics over the compared points or cells; `None` if nothing could be compared.
    pub stats: Option<ErrorStats>,
    /// Map points (or known map cells) outside the ground truth's extent, or with a non-finite
    /// coordinate. Reported apart so a map that drifts off the world is visible, not averaged in.
    pub outside_gt: usize,
    /// Map points (or cells) inside the extent where the ground truth is unknown.
    pub unknown_gt: usize,
    /// Fraction of the known ground-truth cells the map covers (0 when the ground truth has none).
    pub coverage_fraction: f64,
}

/// Per-point vertical error `z − h_gt(x, y)` of a point cloud, with `h_gt` sampled bilinearly.
///
/// A ground-truth cell counts as covered when at least one point falls in it. Obstacles are not
/// treated specially; to score terrain only, filter first with [`points_away_from_obstacles`].
pub fn cloud_height_error(points: &[Point3<f64>], gt: &HeightGrid) -> HeightErrorReport {
    let mut errors_m = Vec::with_capacity(points.len());
    let mut covered = HashSet::new();
    let (mut outside_gt, mut unknown_gt) = (0, 0);
    for p in points {
        let cell = if p.iter().all(|v| v.is_finite()) { gt.cell_at(p.x, p.y) } else { None };
        let Some((col, row)) = cell else {
            outside_gt += 1;
            continue;
        };
        match gt.sample_bilinear_m(p.x, p.y) {
            Some(h) => {
                errors_m.push(p.z - h);
                covered.insert((col, row));
            }
            None => unknown_gt += 1,
        }
    }
    HeightErrorReport {
        stats: ErrorStats::from_errors(&errors_m),
        outside_gt,
        unknown_gt,
        coverage_fraction: fraction(covered.len(), gt.known_cells()),
    }
}

/// Per-cell error of a height-grid map: at every known map cell, map height minus the ground
/// truth sampled bilinearly at the cell's centre. The grids may differ in resolution and origin.
///
/// A known ground-truth cell counts as covered when the map cell containing its centre is known.
pub fn grid_height_error(map: &HeightGrid, gt: &HeightGrid) -> HeightErrorReport {
    let mut errors_m = Vec::new();
    let (mut outside_gt, mut unknown_gt) = (0, 0);
    for row in 0..map.rows {
        for col in 0..map.cols {
            let Some(h_map) = map.height_at_cell_m(col, row) else { continue };
            let c = map.cell_centre_m(col, row);
            if gt.cell_at(c.x, c.y).is_none() {
                outside_gt += 1;
            } else if let Some(h_gt) = gt.sample_bilinear_m(c.x, c.y) {
                errors_m.push(h_map - h_gt);
            } else {
                unknown_gt += 1;
            }
        }
    }
    let mut covered = 0;
    for row in 0..gt.rows {
        for col in 0..gt.cols {
            if gt.height_at_cell_m(col, row).is_none() {
                continue;
            }
            let c = gt.cell_centre_m(col, row);
            if map.cell_at(c.x, c.y).and_then(|(mc, mr)| map.height_at_cell_m(mc, mr)).is_some() {
                covered += 1;
            }
        }
    }
    HeightErrorReport {
        stats: ErrorStats::from_errors(&errors_m),
        outside_gt,
        unknown_gt,
        coverage_fraction: fraction(covered, gt.known_cells()),
    }
}

fn fraction(part: usize, whole: usize) -> f64 {
    if whole == 0 { 0.0 } else { part as f64 / whole as f64 }
}

// ---------------------------------------------------------------------------------------------
// Obstacles
// ---------------------------------------------------------------------------------------------

/// A true obstacle from the simulator: a rock with a horizontal footprint of a disc.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrueObstacle {
    pub centre_m: Point2<f64>,
    pub radius_m: f64,
}

impl TrueObstacle {
    fn reaches(&self, p: &Point2<f64>, tolerance_m: f64) -> bool {
        (p - self.centre_m).norm() <= self.radius_m + tolerance_m
    }
}

/// Points whose horizontal position is farther than `radius + margin_m` from every obstacle: the
/// terrain-only part of a cloud, for a height error not dominated by rocks the ground truth's
/// heightfield may not contain.
pub fn points_away_from_obstacles(
    points: &[Point3<f64>],
    obstacles: &[TrueObstacle],
    margin_m: f64,
) -> Vec<Point3<f64>> {
    points.iter().filter(|p| !obstacles.iter().any(|o| o.reaches(&p.xy(), margin_m))).copied().collect()
}

/// The obstacles the map could have seen: those with at least one known map cell whose centre
/// lies within the obstacle's footprint (or whose own centre's cell is known, for rocks smaller
/// than a cell). Pass the result to [`evaluate_obstacles`] for recall over the mapped area only.
pub fn obstacles_in_mapped_area(obstacles: &[TrueObstacle], map: &HeightGrid) -> Vec<TrueObstacle> {
    let known_at = |x: f64, y: f64| map.cell_at(x, y).and_then(|(c, r)| map.height_at_cell_m(c, r)).is_some();
    // Index range of the cell centres within [centre - r, centre + r] along one axis, clamped to
    // the grid so a huge radius costs at most the grid's size.
    let span = |centre: f64, origin: f64, r: f64, n: usize| {
        let lo = ((centre - r - origin) / map.resolution_m).ceil().max(0.0);
        let hi = ((centre + r - origin) / map.resolution_m).floor().min(n as f64 - 1.0);
        (lo <= hi).then_some(lo as usize..=hi as usize)
    };
    obstacles
        .iter()
        .filter(|o| {
            if known_at(o.centre_m.x, o.centre_m.y) {
                return true;
            }
            let cols = span(o.centre_m.x, map.origin_m.0, o.radius_m, map.cols);
            let rows = span(o.centre_m.y, map.origin_m.1, o.radius_m, map.rows);
            let (Some(cols), Some(rows)) = (cols, rows) else { return false };
            rows.clone().any(|row| {
                cols.clone()
                    .any(|col| map.height_at_cell_m(col, row).is_some() && o.reaches(&map.cell_centre_m(col, row), 0.0))
            })
        })
        .copied()
        .collect()
}

/// How detections are matched to true obstacles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObstacleMatching {
    /// A detection matches an obstacle when it lies within `radius + tolerance_m` of its centre.
    pub tolerance_m: f64,
    /// Detections closer than this join one cluster (single linkage). For detections that are
    /// cell centres of a grid with resolution `r`, `1.5 · r` joins 8-connected cells.
    pub link_distance_m: f64,
}

/// Why obstacle evaluation was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ObstacleEvalError {
    #[error("tolerance {0} m must be finite and non-negative")]
    Tolerance(f64),
    #[error("link distance {0} m must be finite and positive")]
    LinkDistance(f64),
    #[error("detection {index} has a non-finite position")]
    NonFiniteDetection { index: usize },
    #[error("true obstacle {index} needs a finite centre and a finite, non-negative radius")]
    BadObstacle { index: usize },
}

/// Counts behind obstacle precision and recall.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ObstacleReport {
    pub detections: usize,
    /// Detections within `radius + tolerance` of some true obstacle.
    pub detections_matched: usize,
    pub clusters: usize,
    /// Clusters in which at least half the detections are matched.
    pub clusters_matched: usize,
    pub obstacles: usize,
    /// True obstacles with at least one matched detection.
    pub obstacles_found: usize,
}

impl ObstacleReport {
    /// Cluster precision, the headline number: matched clusters / clusters. `None` without
    /// detections, where precision is undefined rather than perfect.
    pub fn precision(&self) -> Option<f64> {
        ratio(self.clusters_matched, self.clusters)
    }

    /// Detection-level precision: matched detections / detections. Large rocks weigh more here.
    pub fn point_precision(&self) -> Option<f64> {
        ratio(self.detections_matched, self.detections)
    }

    /// Found obstacles / true obstacles; `None` without true obstacles.
    pub fn recall(&self) -> Option<f64> {
        ratio(self.obstacles_found, self.obstacles)
    }

    /// Harmonic mean of [`Self::precision`] and [`Self::recall`]; 0 when both are 0.
    pub fn f1(&self) -> Option<f64> {
        let (p, r) = (self.precision()?, self.recall()?);
        Some(if p + r > 0.0 { 2.0 * p * r / (p + r) } else { 0.0 })
    }
}

fn ratio(part: usize, whole: usize) -> Option<f64> {
    (whole > 0).then(|| part as f64 / whole as f64)
}

/// Scores detected obstacle positions (cells or points, x–y in m) against the true obstacles.
///
/// Precision is counted per cluster because one rock yields many detected cells and a big rock
/// would otherwise outvote every false alarm: detections are first grouped by single linkage
/// within `link_distance_m`, and a cluster is a true positive when at least half its detections
/// lie within `radius + tolerance_m` of a true obstacle. "Half" rather than "any" keeps a large
/// spurious blob that merely touches a rock a false positive, and "half" rather than "centroid"
/// keeps a blob spanning two neighbouring rocks a true positive. Recall is the fraction of true
/// obstacles with at least one detection within `radius + tolerance_m`.
pub fn evaluate_obstacles(
    detections_m: &[Point2<f64>],
    truth: &[TrueObstacle],
    matching: &ObstacleMatching,
) -> Result<ObstacleReport, ObstacleEvalError> {
    let ObstacleMatching { tolerance_m, link_distance_m } = *matching;
    if !(tolerance_m.is_finite() && tolerance_m >= 0.0) {
        return Err(ObstacleEvalError::Tolerance(tolerance_m));
    }
    if !(link_distance_m.is_finite() && link_distance_m > 0.0) {
        return Err(ObstacleEvalError::LinkDistance(link_distance_m));
    }
    if let Some(index) = detections_m.iter().position(|p| !(p.x.is_finite() && p.y.is_finite())) {
        return Err(ObstacleEvalError::NonFiniteDetection { index });
    }
    let valid =
        |o: &TrueObstacle| o.centre_m.iter().all(|v| v.is_finite()) && o.radius_m.is_finite() && o.radius_m >= 0.0;
    if let Some(index) = truth.iter().position(|o| !valid(o)) {
        return Err(ObstacleEvalError::BadObstacle { index });
    }

    let matched: Vec<bool> = detections_m.iter().map(|p| truth.iter().any(|o| o.reaches(p, tolerance_m))).collect();
    let obstacles_found = truth
        .iter()
        .filter(|o| detections_m.iter().zip(&matched).any(|(p, &m)| m && o.reaches(p, tolerance_m)))
        .count();

    let labels = cluster_single_linkage(detections_m, link_distance_m);
    // Per cluster: (detections, matched detections).
    let mut tally: HashMap<usize, (usize, usize)> = HashMap::new();
    for (&label, &m) in labels.iter().zip(&matched) {
        let entry = tally.entry(label).or_default();
        entry.0 += 1;
        entry.1 += usize::from(m);
    }
    Ok(ObstacleReport {
        detections: detections_m.len(),
        detections_matched: matched.iter().filter(|&&m| m).count(),
        clusters: tally.len(),
        clusters_matched: tally.values().filter(|(n, m)| 2 * m >= *n).count(),
        obstacles: truth.len(),
        obstacles_found,
    })
}

/// Cluster label per point: points within `link_m` of each other share a label (transitively).
/// A hash of `link_m`-sized bins limits the pair tests to the 3 × 3 neighbouring bins.
fn cluster_single_linkage(points: &[Point2<f64>], link_m: f64) -> Vec<usize> {
    // Saturating float-to-int casts keep far-away points valid keys; they only cost extra tests.
    let bin = |p: &Point2<f64>| ((p.x / link_m).floor() as i64, (p.y / link_m).floor() as i64);
    let mut bins: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    for (i, p) in points.iter().enumerate() {
        bins.entry(bin(p)).or_default().push(i);
    }
    let mut parent: Vec<usize> = (0..points.len()).collect();
    for (i, p) in points.iter().enumerate() {
        let (bx, by) = bin(p);
        for dx in -1..=1i64 {
            for dy in -1..=1i64 {
                let Some(others) = bins.get(&(bx.saturating_add(dx), by.saturating_add(dy))) else { continue };
                for &j in others.iter().filter(|&&j| j > i) {
                    if (points[j] - p).norm() <= link_m {
                        let (ri, rj) = (find_root(&mut parent, i), find_root(&mut parent, j));
                        parent[ri.max(rj)] = ri.min(rj);
                    }
                }
            }
        }
    }
    (0..points.len()).map(|i| find_root(&mut parent, i)).collect()
}

fn find_root(parent: &mut [usize], mut i: usize) -> usize {
    while parent[i] != i {
        // Path halving keeps the trees shallow without recursion.
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    i
}
