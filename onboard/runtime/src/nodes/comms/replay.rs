//! Persistence of the command replay guard: one line `<sender node id> <last counter>` per
//! sender, rewritten atomically (temporary file, fsync, rename) before a command is executed.
//!
//! A missing file is an empty guard (first start). A file that does not parse is an error, not
//! an empty guard: starting over would accept every command recorded before the restart again.

use std::io::Write;
use std::path::{Path, PathBuf};

use protocol::{NodeId, ReplayGuard};

/// Senders the guard tracks (the ground station, a backup station, a few relays).
pub const MAX_SENDERS: usize = 8;
/// A guard file larger than this is not ours.
const MAX_FILE_BYTES: u64 = 4096;

#[derive(Debug, thiserror::Error)]
pub enum ReplayStateError {
    #[error("replay guard file {}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "replay guard file {} is corrupt at line {line}; refusing to start with an empty guard \
         (that would re-accept recorded commands): restore it or remove it deliberately",
        path.display()
    )]
    Corrupt { path: PathBuf, line: usize },
}

/// Reads the guard from `path`; a missing file gives an empty guard.
pub fn load(path: &Path) -> Result<ReplayGuard<MAX_SENDERS>, ReplayStateError> {
    let io = |source| ReplayStateError::Io { path: path.to_path_buf(), source };
    let bytes = match std::fs::metadata(path) {
        Err(error) if error.kind() == std::io::ErrorKind::NotFound => return Ok(ReplayGuard::new()),
        Err(error) => return Err(io(error)),
        Ok(meta) if meta.len() > MAX_FILE_BYTES => {
            return Err(ReplayStateError::Corrupt { path: path.to_path_buf(), line: 0 });
        }
        Ok(_) => std::fs::read(path).map_err(io)?,
    };
    parse(&bytes).map_err(|line| ReplayStateError::Corrupt { path: path.to_path_buf(), line })
}

/// Parses the file's text; `Err(line)` names the first bad line (1-based). Total.
pub fn parse(bytes: &[u8]) -> Result<ReplayGuard<MAX_SENDERS>, usize> {
    let text = std::str::from_utf8(bytes).map_err(|_| 1usize)?;
    let mut entries = Vec::new();
    for (number, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let mut fields = line.split_ascii_whitespace();
        let entry = match (fields.next(), fields.next(), fields.next()) {
            (Some(node), Some(counter), None) => node.parse::<u8>().ok().zip(counter.parse::<u64>().ok()),
            _ => None,
        };
        let (node, counter) = entry.ok_or(number + 1)?;
        entries.push((NodeId(node), counter));
    }
    ReplayGuard::restore(&entries).map_err(|_| MAX_SENDERS + 1)
}

/// Writes the guard atomically.
pub fn save(path: &Path, guard: &ReplayGuard<MAX_SENDERS>) -> Result<(), ReplayStateError> {
    let io = |source| ReplayStateError::Io { path: path.to_path_buf(), source };
    let mut text = String::new();
    for (node, counter) in guard.entries() {
        text.push_str(&format!("{} {counter}\n", node.0));
    }
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    let mut file = std::fs::File::create(&tmp).map_err(io)?;
    file.write_all(text.as_bytes()).map_err(io)?;
    file.sync_all().map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)
}
