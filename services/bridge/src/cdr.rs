//! OMG CDR (XCDR1, little endian): the payload encoding of every ROS 2
//! message on rmw_zenoh (rmw_zenoh's `docs/design.md`, "Serialization").
//!
//! A message is a 4-byte encapsulation header (`00 01 00 00`: plain CDR,
//! little endian) and the body. In the body each primitive is aligned to
//! its own size (8 at most), counted from the start of the body; a string is
//! a `u32` length that counts its terminating NUL, the bytes and the NUL; a
//! sequence is a `u32` element count and the elements; a fixed array is its
//! elements alone.

/// The encapsulation header of little-endian plain CDR.
pub const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Builds one CDR message.
#[derive(Debug, Default)]
pub struct Writer {
    buf: Vec<u8>,
}

impl Writer {
    /// An empty message with its encapsulation header.
    pub fn new() -> Self {
        let mut buf = Vec::with_capacity(256);
        buf.extend_from_slice(&CDR_LE);
        Self { buf }
    }

    fn align(&mut self, n: usize) {
        let body = self.buf.len() - CDR_LE.len();
        let pad = (n - body % n) % n;
        self.buf.resize(self.buf.len() + pad, 0);
    }

    /// Appends a byte.
    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }
    /// Appends an `int32` (aligned).
    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// Appends a `uint32` (aligned).
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// Appends a `float32` (aligned).
    pub fn f32(&mut self, v: f32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// Appends a `float64` (aligned).
    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// Appends a string (length with its terminating zero, bytes, zero).
    pub fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }
    /// A sequence's element count (the elements follow).
    pub fn len(&mut self, n: usize) {
        self.u32(n as u32);
    }
    /// A `uint8[]` / `byte[]` sequence.
    pub fn bytes(&mut self, b: &[u8]) {
        self.len(b.len());
        self.buf.extend_from_slice(b);
    }
    /// The message's bytes.
    pub fn finish(self) -> Vec<u8> {
        self.buf
    }
}

/// Why a message could not be read: what was being read and where.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CdrError {
    /// Another encapsulation than little-endian plain CDR.
    #[error("not little-endian plain CDR (encapsulation {0:02x?})")]
    Encapsulation([u8; 4]),
    /// The message ends before a field does.
    #[error("truncated: {what} at byte {at} needs {need} bytes, {left} left")]
    Truncated {
        /// The field.
        what: &'static str,
        /// Where it starts (bytes after the encapsulation).
        at: usize,
        /// Bytes it needs.
        need: usize,
        /// Bytes left.
        left: usize,
    },
    /// A field whose value is not allowed.
    #[error("{what} at byte {at}: {problem}")]
    Invalid {
        /// The field.
        what: &'static str,
        /// Where it starts.
        at: usize,
        /// What is wrong with it.
        problem: String,
    },
}

/// Reads one CDR message. Every length is checked against the bytes that
/// are left before anything is allocated, so a hostile length (4 GB of
/// transforms in 40 bytes) is an error, never an allocation.
#[derive(Debug)]
pub struct Reader<'a> {
    body: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    /// A reader of `message`, after checking its encapsulation header.
    pub fn new(message: &'a [u8]) -> Result<Self, CdrError> {
        if message.len() < 4 {
            return Err(CdrError::Truncated {
                what: "encapsulation header",
                at: 0,
                need: 4,
                left: message.len(),
            });
        }
        let head = [message[0], message[1], message[2], message[3]];
        if head[..2] != CDR_LE[..2] {
            return Err(CdrError::Encapsulation(head));
        }
        Ok(Self {
            body: &message[4..],
            at: 0,
        })
    }

    fn take(&mut self, what: &'static str, align: usize, n: usize) -> Result<&'a [u8], CdrError> {
        let start = self.at.div_ceil(align) * align;
        let left = self.body.len().saturating_sub(start);
        if n > left {
            return Err(CdrError::Truncated {
                what,
                at: start + 4,
                need: n,
                left,
            });
        }
        self.at = start + n;
        Ok(&self.body[start..start + n])
    }

    /// Reads a byte (`what`: the field, for errors).
    pub fn u8(&mut self, what: &'static str) -> Result<u8, CdrError> {
        Ok(self.take(what, 1, 1)?[0])
    }
    /// Reads an `int32`.
    pub fn i32(&mut self, what: &'static str) -> Result<i32, CdrError> {
        let b = self.take(what, 4, 4)?;
        Ok(i32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    /// Reads a `uint32`.
    pub fn u32(&mut self, what: &'static str) -> Result<u32, CdrError> {
        let b = self.take(what, 4, 4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    /// Reads a `float64`.
    pub fn f64(&mut self, what: &'static str) -> Result<f64, CdrError> {
        let b = self.take(what, 8, 8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(f64::from_le_bytes(a))
    }
    /// Reads a string (UTF-8, zero-terminated, length checked against what is left).
    pub fn string(&mut self, what: &'static str) -> Result<String, CdrError> {
        let n = self.u32(what)? as usize;
        let at = self.at + 4;
        let b = self.take(what, 1, n)?;
        match b.split_last() {
            Some((0, text)) => String::from_utf8(text.to_vec()).map_err(|_| CdrError::Invalid {
                what,
                at,
                problem: "not UTF-8".into(),
            }),
            _ => Err(CdrError::Invalid {
                what,
                at,
                problem: "a string without its terminating NUL".into(),
            }),
        }
    }
    /// A sequence's element count, checked against the bytes left given
    /// the smallest size of one element.
    pub fn len(&mut self, what: &'static str, min_element: usize) -> Result<usize, CdrError> {
        let n = self.u32(what)? as usize;
        let left = self.body.len() - self.at;
        if n.saturating_mul(min_element.max(1)) > left {
            return Err(CdrError::Invalid {
                what,
                at: self.at,
                problem: format!(
                    "{n} elements of at least {min_element} bytes cannot fit in the {left} bytes left"
                ),
            });
        }
        Ok(n)
    }
    /// A `uint8[]` sequence, borrowed.
    pub fn bytes(&mut self, what: &'static str) -> Result<&'a [u8], CdrError> {
        let n = self.len(what, 1)?;
        self.take(what, 1, n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn primitives_are_aligned_from_the_body_start() {
        let mut w = Writer::new();
        w.u8(7);
        w.f64(1.5);
        w.string("ab");
        w.i32(-3);
        let b = w.finish();
        // header 4, u8 at 0, pad to 8, f64 8..16, len 16..20, "ab\0" 20..23, pad, i32 24..28
        assert_eq!(b.len(), 4 + 28);
        assert_eq!(&b[..4], &CDR_LE);
        assert_eq!(b[4], 7);
        assert_eq!(&b[12..20], &1.5f64.to_le_bytes());
        assert_eq!(&b[20..24], &3u32.to_le_bytes());
        assert_eq!(&b[24..27], b"ab\0");
        let mut r = Reader::new(&b).unwrap();
        assert_eq!(r.u8("a").unwrap(), 7);
        assert_eq!(r.f64("b").unwrap(), 1.5);
        assert_eq!(r.string("c").unwrap(), "ab");
        assert_eq!(r.i32("d").unwrap(), -3);
        assert!(matches!(r.u8("e"), Err(CdrError::Truncated { .. })));
    }

    #[test]
    fn hostile_lengths_are_errors_not_allocations() {
        let mut w = Writer::new();
        w.u32(u32::MAX);
        let b = w.finish();
        assert!(Reader::new(&b).unwrap().string("s").is_err());
        assert!(Reader::new(&b).unwrap().len("seq", 8).is_err());
        assert!(Reader::new(&b).unwrap().bytes("data").is_err());
        assert!(matches!(
            Reader::new(&[0, 0, 0, 0]),
            Err(CdrError::Encapsulation(_))
        ));
        assert!(Reader::new(&[0, 1]).is_err());
    }
}
