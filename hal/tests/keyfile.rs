//! Loading the authentication key from real files.

// Helpers outside #[test] functions are test code too; clippy.toml only exempts the latter.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::fs;
use std::os::unix::fs::PermissionsExt;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};

use hal::keyfile::{KeyFileError, load_auth_key};
use protocol::AuthKey;

const KEY_HEX: &str = "00112233445566778899aabbccddeeff0f1e2d3c4b5a69788796a5b4c3d2e1f0";

/// A file in the temp directory, removed on drop.
struct TempFile(PathBuf);

impl TempFile {
    fn new(contents: &str, mode: u32) -> TempFile {
        static NEXT: AtomicUsize = AtomicUsize::new(0);
        let name = format!("hal-keyfile-{}-{}.key", std::process::id(), NEXT.fetch_add(1, Ordering::Relaxed));
        let path = std::env::temp_dir().join(name);
        fs::write(&path, contents).unwrap();
        fs::set_permissions(&path, fs::Permissions::from_mode(mode)).unwrap();
        TempFile(path)
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = fs::remove_file(&self.0);
    }
}

fn key_bytes(hex: &str) -> Vec<u8> {
    (0..hex.len()).step_by(2).map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap()).collect()
}

/// The same tag as a key built from the expected bytes: the loaded key is that key.
fn assert_same_key(loaded: &AuthKey, hex: &str) {
    let expected = AuthKey::from_bytes(&key_bytes(hex)).unwrap();
    assert_eq!(loaded.tag(b"probe"), expected.tag(b"probe"));
}

#[test]
fn good_key_with_newline_and_wrapping_loads() {
    let wrapped = format!("{}\n  {}\n", &KEY_HEX[..32], KEY_HEX[32..].to_uppercase());
    let file = TempFile::new(&wrapped, 0o600);
    let key = load_auth_key(&file.0).unwrap();
    assert_same_key(&key, KEY_HEX);
    assert!(!format!("{key:?}").contains("0011"), "key leaked into Debug");
}

#[test]
fn shortest_and_longest_keys_load() {
    let short = &KEY_HEX[..32];
    assert_same_key(&load_auth_key(&TempFile::new(short, 0o400).0).unwrap(), short);
    let long = KEY_HEX.repeat(2);
    assert_same_key(&load_auth_key(&TempFile::new(&long, 0o600).0).unwrap(), &long);
}

#[test]
fn bad_hex_is_refused_without_echoing_the_key() {
    let text = format!("{}g{}", &KEY_HEX[..10], &KEY_HEX[11..]);
    let file = TempFile::new(&text, 0o600);
    let error = load_auth_key(&file.0).unwrap_err();
    assert!(matches!(error, KeyFileError::BadHex { offset: 10, .. }), "{error}");
    let message = error.to_string();
    assert!(message.contains("not hex") && message.contains(&file.0.display().to_string()), "{message}");
    assert!(!message.contains(&KEY_HEX[..10]), "key leaked into the error: {message}");
}

#[test]
fn short_long_and_odd_keys_are_refused() {
    for (text, digits) in [(&KEY_HEX[..30], 30), (&KEY_HEX[..33], 33), (&KEY_HEX.repeat(3)[..130], 130), ("", 0)] {
        let file = TempFile::new(text, 0o600);
        let error = load_auth_key(&file.0).unwrap_err();
        assert!(matches!(error, KeyFileError::WrongLength { digits: d, .. } if d == digits), "{error}");
        assert!(error.to_string().contains("from 32 to 128"), "{error}");
    }
}

#[test]
fn permissive_permissions_are_refused() {
    for mode in [0o644, 0o640, 0o604, 0o660, 0o620] {
        let file = TempFile::new(KEY_HEX, mode);
        let error = load_auth_key(&file.0).unwrap_err();
        assert!(matches!(error, KeyFileError::TooPermissive { mode: m, .. } if m == mode), "{error}");
        assert!(error.to_string().contains("chmod 600"), "{error}");
    }
}

#[test]
fn missing_file_is_named() {
    let path = std::env::temp_dir().join(format!("hal-keyfile-{}-missing.key", std::process::id()));
    let error = load_auth_key(&path).unwrap_err();
    assert!(matches!(error, KeyFileError::Missing { .. }), "{error}");
    assert!(error.to_string().contains(&path.display().to_string()));
}

#[test]
fn huge_file_is_refused_unread() {
    let file = TempFile::new(&"a".repeat(10_000), 0o600);
    assert!(matches!(load_auth_key(&file.0).unwrap_err(), KeyFileError::TooLarge { bytes: 10_000, .. }));
}
