//! The framing of dynslam's binary files (the map file, the vocabulary):
//! an 8-byte magic, a format version (u32), the payload's length (u64) and
//! CRC-32 (u32), little-endian, then the payload. One place checks them, so
//! that both files refuse a foreign, other-version, truncated, joined or
//! corrupted file the same way.

/// Bytes before the payload.
pub const HEADER: usize = 8 + 4 + 8 + 4;

/// What is wrong with a framed file (each file type words it its way).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameProblem {
    /// Not this magic: another kind of file.
    Foreign,
    /// Another format version than this build reads.
    Version {
        /// The file's version.
        found: u32,
        /// The version this build reads.
        supported: u32,
    },
    /// Shorter than its header promises.
    Truncated {
        /// Bytes the header promises.
        expected: u64,
        /// Bytes the file has.
        found: u64,
    },
    /// Bytes after the body.
    TrailingBytes(u64),
    /// The body does not match its checksum.
    Checksum,
}

/// `payload` framed with `magic` and `version`.
pub fn frame(magic: &[u8; 8], version: u32, payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER + payload.len());
    out.extend_from_slice(magic);
    out.extend_from_slice(&version.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&crc32fast::hash(payload).to_le_bytes());
    out.extend_from_slice(payload);
    out
}

/// The payload of `bytes` and its CRC-32, checked against `magic`,
/// `version`, the length and the checksum.
pub fn unframe<'a>(
    bytes: &'a [u8],
    magic: &[u8; 8],
    version: u32,
) -> Result<(&'a [u8], u32), FrameProblem> {
    if bytes.len() < magic.len() || &bytes[..magic.len()] != magic {
        return Err(FrameProblem::Foreign);
    }
    if bytes.len() < HEADER {
        return Err(FrameProblem::Truncated {
            expected: HEADER as u64,
            found: bytes.len() as u64,
        });
    }
    let word = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap_or_default());
    let found_version = word(8);
    if found_version != version {
        return Err(FrameProblem::Version {
            found: found_version,
            supported: version,
        });
    }
    let length = u64::from_le_bytes(bytes[12..20].try_into().unwrap_or_default());
    let crc = word(20);
    let payload = &bytes[HEADER..];
    let found = payload.len() as u64;
    if found < length {
        return Err(FrameProblem::Truncated {
            expected: length,
            found,
        });
    }
    if found > length {
        return Err(FrameProblem::TrailingBytes(found - length));
    }
    if crc32fast::hash(payload) != crc {
        return Err(FrameProblem::Checksum);
    }
    Ok((payload, crc))
}
