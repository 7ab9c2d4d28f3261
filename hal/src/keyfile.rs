//! Loading the command-authentication key from a file.
//!
//! The file holds the key as hex text (32 to 128 hex digits, i.e. 16 to 64 bytes); whitespace
//! and newlines anywhere are ignored, so a key may be wrapped or end with a newline. The key
//! never appears in an error or a log: errors name the file and what is wrong with it, never the
//! digits.

use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

use protocol::AuthKey;
use protocol::auth::{MAX_KEY_BYTES, MIN_KEY_BYTES};

/// Fewest hex digits accepted (two per key byte).
pub const MIN_KEY_HEX_DIGITS: usize = 2 * MIN_KEY_BYTES;
/// Most hex digits accepted (two per key byte).
pub const MAX_KEY_HEX_DIGITS: usize = 2 * MAX_KEY_BYTES;
/// A key file larger than this is certainly not a key file; refusing it early keeps a mistaken
/// path (a log, a disk image) from being read into memory.
const MAX_FILE_BYTES: u64 = 4096;

#[derive(Debug, thiserror::Error)]
pub enum KeyFileError {
    #[error("key file {} does not exist", path.display())]
    Missing { path: PathBuf },
    #[error("cannot read key file {}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error(
        "key file {} has permissions {mode:04o}, accessible by group or others; \
         refusing to use it (run `chmod 600 {}`)",
        path.display(),
        path.display()
    )]
    TooPermissive { path: PathBuf, mode: u32 },
    #[error("key file {} is {bytes} bytes, too large to be a key file (at most {MAX_FILE_BYTES})", path.display())]
    TooLarge { path: PathBuf, bytes: u64 },
    #[error(
        "key file {} is not hex text: invalid character at byte offset {offset} \
         (expected 0-9, a-f, A-F or whitespace)",
        path.display()
    )]
    BadHex { path: PathBuf, offset: usize },
    #[error(
        "key file {} holds {digits} hex digits; a key must be an even number of digits \
         from {MIN_KEY_HEX_DIGITS} to {MAX_KEY_HEX_DIGITS}",
        path.display()
    )]
    WrongLength { path: PathBuf, digits: usize },
}

/// Reads the authentication key from `path`.
///
/// On unix the file must not be accessible by group or others (as ssh demands of private
/// keys): a key that other accounts can read or replace authenticates nothing.
pub fn load_auth_key(path: impl AsRef<Path>) -> Result<AuthKey, KeyFileError> {
    let path = path.as_ref();
    let io_error = |source: std::io::Error| {
        if source.kind() == std::io::ErrorKind::NotFound {
            KeyFileError::Missing { path: path.to_path_buf() }
        } else {
            KeyFileError::Io { path: path.to_path_buf(), source }
        }
    };
    let file = File::open(path).map_err(io_error)?;
    let metadata = file.metadata().map_err(io_error)?;
    check_permissions(path, &metadata)?;
    if metadata.len() > MAX_FILE_BYTES {
        return Err(KeyFileError::TooLarge { path: path.to_path_buf(), bytes: metadata.len() });
    }
    let mut text = Vec::with_capacity(metadata.len() as usize);
    // Bounded again while reading: the file may grow between metadata() and read.
    let read = file.take(MAX_FILE_BYTES + 1).read_to_end(&mut text);
    let result = match read {
        Err(source) => Err(io_error(source)),
        Ok(_) if text.len() as u64 > MAX_FILE_BYTES => {
            Err(KeyFileError::TooLarge { path: path.to_path_buf(), bytes: text.len() as u64 })
        }
        Ok(_) => parse_key(path, &text),
    };
    wipe(&mut text);
    result
}

#[cfg(unix)]
fn check_permissions(path: &Path, metadata: &std::fs::Metadata) -> Result<(), KeyFileError> {
    use std::os::unix::fs::PermissionsExt;
    let mode = metadata.permissions().mode() & 0o7777;
    if mode & 0o077 != 0 {
        return Err(KeyFileError::TooPermissive { path: path.to_path_buf(), mode });
    }
    Ok(())
}

#[cfg(not(unix))]
fn check_permissions(_path: &Path, _metadata: &std::fs::Metadata) -> Result<(), KeyFileError> {
    // No portable notion of "group or others" elsewhere; ACLs are the operator's business.
    Ok(())
}

fn parse_key(path: &Path, text: &[u8]) -> Result<AuthKey, KeyFileError> {
    let mut bytes = [0u8; MAX_KEY_BYTES];
    let mut digits = 0usize;
    let mut result = Ok(());
    for (offset, &c) in text.iter().enumerate() {
        if c.is_ascii_whitespace() {
            continue;
        }
        let Some(nibble) = hex_value(c) else {
            result = Err(KeyFileError::BadHex { path: path.to_path_buf(), offset });
            break;
        };
        // Keep counting past the maximum so the error reports the real length.
        if let Some(byte) = bytes.get_mut(digits / 2) {
            *byte = (*byte << 4) | nibble;
        }
        digits += 1;
    }
    let result = result.and_then(|()| {
        if !digits.is_multiple_of(2) || !(MIN_KEY_HEX_DIGITS..=MAX_KEY_HEX_DIGITS).contains(&digits) {
            return Err(KeyFileError::WrongLength { path: path.to_path_buf(), digits });
        }
        // The length was checked just above, so from_bytes cannot refuse it; map anyway rather
        // than trust two checks to stay in step.
        AuthKey::from_bytes(&bytes[..digits / 2])
            .map_err(|_| KeyFileError::WrongLength { path: path.to_path_buf(), digits })
    });
    wipe(&mut bytes);
    result
}

fn hex_value(c: u8) -> Option<u8> {
    match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'a'..=b'f' => Some(c - b'a' + 10),
        b'A'..=b'F' => Some(c - b'A' + 10),
        _ => None,
    }
}

/// Best-effort removal of key material from memory we are about to free: `black_box` keeps the
/// compiler from dropping the writes as dead stores.
fn wipe(buf: &mut [u8]) {
    buf.fill(0);
    std::hint::black_box(buf);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_wrapped_mixed_case_hex() {
        let text = b"00112233445566778899AABBCCDDEEFF\n  0011 2233\t4455\r\n";
        let key = parse_key(Path::new("k"), text);
        assert!(key.is_ok(), "{key:?}");
    }

    #[test]
    fn odd_digit_count_is_a_length_error() {
        let text = b"00112233445566778899aabbccddeeff0";
        assert!(matches!(parse_key(Path::new("k"), text), Err(KeyFileError::WrongLength { digits: 33, .. })));
    }

    #[test]
    fn too_many_digits_reports_real_length() {
        let text = [b'a'; 130];
        assert!(matches!(parse_key(Path::new("k"), &text), Err(KeyFileError::WrongLength { digits: 130, .. })));
    }

    #[test]
    fn bad_hex_names_offset_not_character() {
        let text = b"0011zz";
        let err = parse_key(Path::new("k"), text);
        assert!(matches!(err, Err(KeyFileError::BadHex { offset: 4, .. })));
        if let Err(err) = err {
            assert!(!err.to_string().contains('z'));
        }
    }
}
