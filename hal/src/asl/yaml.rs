//! The few YAML constructs ASL `sensor.yaml` files use: `key: scalar` mappings nested by
//! indentation, flow sequences of numbers (`[a, b, c]`, possibly over several lines), `#`
//! comments, the `%YAML:1.0` directive and `!!tags` (ignored). Anything else is kept as text or
//! skipped; a key the reader needs and cannot find or understand is reported with file and line.

use std::path::Path;

use crate::sensor::SensorError;

/// One `key: value` of a document; `path` joins the keys of the enclosing mappings with `.`.
#[derive(Debug, Clone, PartialEq)]
struct Entry {
    path: String,
    value: String,
    line: usize,
}

/// A parsed `sensor.yaml`: flat `dotted.path → value` entries.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Yaml {
    file: String,
    entries: Vec<Entry>,
}

/// Line of the first byte that is not valid UTF-8 (1-based).
pub(crate) fn utf8_error_line(bytes: &[u8], error: &std::str::Utf8Error) -> usize {
    bytes[..error.valid_up_to()].iter().filter(|&&b| b == b'\n').count() + 1
}

/// A token shortened for error messages: untrusted input must not flood a log.
pub(crate) fn excerpt(token: &str) -> String {
    let mut out: String = token.chars().take(40).collect();
    if out.len() < token.len() {
        out.push('…');
    }
    out
}

/// The text before a `#` that starts a comment (at the start or after whitespace, outside quotes).
fn strip_comment(line: &str) -> &str {
    let mut quote: Option<char> = None;
    let mut previous_is_space = true;
    for (i, c) in line.char_indices() {
        match quote {
            Some(q) if c == q => quote = None,
            Some(_) => {}
            None if c == '"' || c == '\'' => quote = Some(c),
            None if c == '#' && previous_is_space => return &line[..i],
            None => {}
        }
        previous_is_space = c.is_whitespace();
    }
    line
}

/// Net `[` minus `]` outside quotes.
fn bracket_balance(text: &str) -> i64 {
    let mut quote: Option<char> = None;
    let mut depth = 0i64;
    for c in text.chars() {
        match quote {
            Some(q) if c == q => quote = None,
            Some(_) => {}
            None if c == '"' || c == '\'' => quote = Some(c),
            None if c == '[' => depth += 1,
            None if c == ']' => depth -= 1,
            None => {}
        }
    }
    depth
}

/// The position of the `:` that separates a key from its value (followed by a space or the end).
fn key_separator(content: &str) -> Option<usize> {
    let bytes = content.as_bytes();
    bytes
        .iter()
        .enumerate()
        .find_map(|(i, &b)| (b == b':' && bytes.get(i + 1).is_none_or(|n| n.is_ascii_whitespace())).then_some(i))
}

/// A [`SensorError::Format`] naming `file` and `line` (0 = the file as a whole).
pub(crate) fn format_error(file: &str, line: usize, reason: impl Into<String>) -> SensorError {
    let context = if line == 0 { file.to_owned() } else { format!("{file}:{line}") };
    SensorError::Format { context, reason: reason.into() }
}

impl Yaml {
    /// Parses `bytes` (the contents of `file`, named in errors). Never panics.
    pub fn parse(bytes: &[u8], file: &Path) -> Result<Yaml, SensorError> {
        let name = file.display().to_string();
        let text = std::str::from_utf8(bytes)
            .map_err(|e| format_error(&name, utf8_error_line(bytes, &e), "not valid UTF-8"))?;
        let mut entries: Vec<Entry> = Vec::new();
        // Open mappings: (indent, key).
        let mut parents: Vec<(usize, String)> = Vec::new();
        // A flow sequence being continued over lines: (entry index, bracket depth so far).
        let mut open_sequence: Option<(usize, i64)> = None;
        for (index, raw) in text.split('\n').enumerate() {
            let line_no = index + 1;
            let content = strip_comment(raw.trim_end_matches('\r'));
            if let Some((entry, depth)) = open_sequence.as_mut() {
                let text = content.trim();
                *depth += bracket_balance(text);
                if let Some(e) = entries.get_mut(*entry) {
                    e.value.push(' ');
                    e.value.push_str(text);
                }
                if *depth <= 0 {
                    open_sequence = None;
                }
                continue;
            }
            let trimmed = content.trim();
            if trimmed.is_empty() || trimmed.starts_with('%') || trimmed == "---" || trimmed == "..." {
                continue;
            }
            // Block-sequence items are not used by any field we read.
            if trimmed.starts_with("- ") || trimmed == "-" {
                continue;
            }
            let indent = content.len() - content.trim_start().len();
            let Some(colon) = key_separator(trimmed) else {
                return Err(format_error(
                    &name,
                    line_no,
                    format!("expected `key: value`, found `{}`", excerpt(trimmed)),
                ));
            };
            let key = trimmed[..colon].trim().trim_matches(|c| c == '"' || c == '\'');
            if key.is_empty() {
                return Err(format_error(&name, line_no, "empty key"));
            }
            let value = trimmed[colon + 1..].trim();
            while parents.last().is_some_and(|(i, _)| *i >= indent) {
                parents.pop();
            }
            let mut path = String::new();
            for (_, parent) in &parents {
                path.push_str(parent);
                path.push('.');
            }
            path.push_str(key);
            if entries.iter().any(|e| e.path == path) {
                return Err(format_error(&name, line_no, format!("duplicate key `{}`", excerpt(&path))));
            }
            // `key:` or `key: !!tag` opens a nested mapping.
            if value.is_empty() || (value.starts_with("!!") && !value.contains(char::is_whitespace)) {
                parents.push((indent, key.to_owned()));
                continue;
            }
            let depth = bracket_balance(value);
            entries.push(Entry { path, value: value.to_owned(), line: line_no });
            if value.starts_with('[') && depth > 0 {
                open_sequence = Some((entries.len() - 1, depth));
            }
        }
        if let Some((entry, _)) = open_sequence {
            let line = entries.get(entry).map_or(0, |e| e.line);
            return Err(format_error(&name, line, "flow sequence `[` is never closed"));
        }
        Ok(Yaml { file: name, entries })
    }

    fn entry(&self, path: &str) -> Option<&Entry> {
        self.entries.iter().find(|e| e.path == path)
    }

    /// Whether `path` holds a value.
    pub fn contains(&self, path: &str) -> bool {
        self.entry(path).is_some()
    }

    /// The scalar at `path`, quotes removed.
    pub fn string(&self, path: &str) -> Option<&str> {
        let value = self.entry(path)?.value.as_str();
        let unquoted = value
            .strip_prefix('"')
            .and_then(|v| v.strip_suffix('"'))
            .or_else(|| value.strip_prefix('\'').and_then(|v| v.strip_suffix('\'')));
        Some(unquoted.unwrap_or(value))
    }

    /// The finite number at `path` (`None` if absent).
    pub fn number(&self, path: &str) -> Result<Option<f64>, SensorError> {
        let Some(entry) = self.entry(path) else { return Ok(None) };
        parse_finite(&entry.value).map(Some).ok_or_else(|| {
            self.error(entry.line, format!("`{path}`: `{}` is not a finite number", excerpt(&entry.value)))
        })
    }

    /// The flow sequence of finite numbers at `path` (`None` if absent).
    pub fn numbers(&self, path: &str) -> Result<Option<Vec<f64>>, SensorError> {
        let Some(entry) = self.entry(path) else { return Ok(None) };
        let bad = |reason: String| self.error(entry.line, format!("`{path}`: {reason}"));
        let inner = entry
            .value
            .trim()
            .strip_prefix('[')
            .and_then(|v| v.strip_suffix(']'))
            .ok_or_else(|| bad(format!("`{}` is not a `[...]` list", excerpt(&entry.value))))?;
        if inner.trim().is_empty() {
            return Ok(Some(Vec::new()));
        }
        inner
            .split(',')
            .enumerate()
            .map(|(i, token)| {
                parse_finite(token).ok_or_else(|| {
                    bad(format!("element {}: `{}` is not a finite number", i + 1, excerpt(token.trim())))
                })
            })
            .collect::<Result<Vec<f64>, SensorError>>()
            .map(Some)
    }

    /// The flow sequence at `path`, which must hold exactly `N` numbers.
    pub fn array<const N: usize>(&self, path: &str) -> Result<Option<[f64; N]>, SensorError> {
        let Some(values) = self.numbers(path)? else { return Ok(None) };
        let line = self.line(path);
        <[f64; N]>::try_from(values.as_slice())
            .map(Some)
            .map_err(|_| self.error(line, format!("`{path}`: {} numbers, expected {N}", values.len())))
    }

    /// Line of `path` (0 if absent), for messages about its meaning.
    pub fn line(&self, path: &str) -> usize {
        self.entry(path).map_or(0, |e| e.line)
    }

    /// A format error at `line` of this file (0 = the file as a whole).
    pub fn error(&self, line: usize, reason: impl Into<String>) -> SensorError {
        format_error(&self.file, line, reason)
    }

    /// A required flow sequence of `N` numbers.
    pub fn required_array<const N: usize>(&self, path: &str) -> Result<[f64; N], SensorError> {
        self.array::<N>(path)?.ok_or_else(|| self.error(0, format!("missing `{path}`")))
    }
}

/// A finite `f64` (YAML's `.inf`/`.nan` and Rust's `inf`/`NaN` are rejected alike).
pub(crate) fn parse_finite(token: &str) -> Option<f64> {
    token.trim().parse::<f64>().ok().filter(|v| v.is_finite())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nested_mappings_and_multiline_sequences() {
        let text = "%YAML:1.0\nT_BS:\n  cols: 4\n  data: [1, 2, # c\n     3]\nrate_hz: 20 # Hz\nname: \"a # b\"\n";
        let yaml = Yaml::parse(text.as_bytes(), Path::new("x.yaml")).unwrap();
        assert_eq!(yaml.number("T_BS.cols").unwrap(), Some(4.0));
        assert_eq!(yaml.numbers("T_BS.data").unwrap(), Some(vec![1.0, 2.0, 3.0]));
        assert_eq!(yaml.number("rate_hz").unwrap(), Some(20.0));
        assert_eq!(yaml.string("name"), Some("a # b"));
        assert_eq!(yaml.line("rate_hz"), 6);
    }

    #[test]
    fn errors_name_file_and_line() {
        let err = Yaml::parse(b"a: 1\nb [1]\n", Path::new("s.yaml")).unwrap_err();
        assert!(err.to_string().starts_with("s.yaml:2:"), "{err}");
        let err = Yaml::parse(b"a: 1\nb: [1,\n", Path::new("s.yaml")).unwrap_err();
        assert!(err.to_string().starts_with("s.yaml:2:"), "{err}");
        let yaml = Yaml::parse(b"x: [1, nan]\n", Path::new("s.yaml")).unwrap();
        assert!(yaml.numbers("x").unwrap_err().to_string().contains("element 2"));
    }
}
