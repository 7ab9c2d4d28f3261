//! XYZ text: one point per line, `x y z` first (further columns, e.g. normals, are ignored),
//! separated by blanks or commas. Every point is an obstacle.

use super::scalar::parse_ascii;
use super::{CloudFile, CloudFormat, CloudParseError, PointSink};

const FORMAT: &str = "xyz";

pub(super) fn parse(bytes: &[u8]) -> Result<CloudFile, CloudParseError> {
    let data_error = |what: String, message: String| CloudParseError::Data { format: FORMAT, what, message };
    let text = std::str::from_utf8(bytes).map_err(|e| data_error("file".to_owned(), format!("not text: {e}")))?;
    let mut sink = PointSink::default();
    for (number, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with("//") {
            continue;
        }
        let mut tokens = line.split(|c: char| c.is_ascii_whitespace() || c == ',').filter(|t| !t.is_empty());
        let mut xyz = [0.0; 3];
        for value in &mut xyz {
            let token = tokens
                .next()
                .ok_or_else(|| data_error(format!("line {}", number + 1), "fewer than 3 values".to_owned()))?;
            *value = parse_ascii(token)
                .ok_or_else(|| data_error(format!("line {}", number + 1), format!("'{token}' is not a number")))?;
        }
        sink.push(xyz, 0, true);
    }
    sink.finish(CloudFormat::Xyz)
}
