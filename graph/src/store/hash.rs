//! Content hashes: the [`Hash`] type, its hex form, and the blake3 hash of a file.

use crate::error::{io, EngineError};
use std::fs::{self, File};
use std::path::Path;

/// A blake3 hash.
pub type Hash = [u8; 32];

/// Lower-case hex of a hash.
pub fn hex(h: &Hash) -> String {
    let mut s = String::with_capacity(64);
    for b in h {
        s.push_str(&format!("{b:02x}"));
    }
    s
}

/// Parses 64 hex digits.
pub fn unhex(s: &str) -> Option<Hash> {
    if s.len() != 64 {
        return None;
    }
    let mut h = [0u8; 32];
    for (i, b) in h.iter_mut().enumerate() {
        *b = u8::from_str_radix(s.get(2 * i..2 * i + 2)?, 16).ok()?;
    }
    Some(h)
}

/// Hashes a file with blake3 (memory-mapped and multi-threaded on the current rayon pool for
/// large files). Returns hex.
pub fn hash_file(path: &Path) -> Result<String, EngineError> {
    let mut h = blake3::Hasher::new();
    let len = fs::metadata(path).map_err(io("reading", path))?.len();
    if len >= 1 << 20 {
        h.update_mmap_rayon(path).map_err(io("hashing", path))?;
    } else {
        h.update_reader(File::open(path).map_err(io("opening", path))?)
            .map_err(io("hashing", path))?;
    }
    Ok(h.finalize().to_hex().to_string())
}
