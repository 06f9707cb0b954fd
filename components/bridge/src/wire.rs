//! What crosses the network: one Zenoh message per sample, a 16-byte header then the sample's
//! exact shared-memory bytes (`LAYOUT.md`), so the receiving side republishes the same bytes —
//! header fields (`seq`, `tick`, `t_origin_ns`) included.
//!
//! ```text
//! offset 0  magic    "BWZ1"
//!        4  type_id  u32 LE: FNV-1a of the payload type's name, record kind and size
//!        8  len      u32 LE: bytes that follow
//!       12  reserved u32 (0)
//!       16  body     the sample (or an RGBD frame header then its payload)
//! ```
//!
//! `type_id` makes two builds with different layouts refuse each other's samples instead of
//! misreading them.

use bowden_interfaces::RgbdFrameHeader;
use bowden_runtime::record::{fnv1a32, service_type, KIND_FRAME};

pub const MAGIC: [u8; 4] = *b"BWZ1";
pub const HEADER_LEN: usize = 16;

/// A message that cannot be a sample of the service it arrived on.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    #[error("{len} bytes: shorter than the 16-byte bridge header")]
    Short { len: usize },
    #[error("bad magic {got:02x?} (expected \"BWZ1\"): not a bowden bridge message")]
    Magic { got: [u8; 4] },
    #[error("type id {got:#010x}, this build expects {expected:#010x}: the peer runs a build with another layout")]
    Type { got: u32, expected: u32 },
    #[error("header says {declared} body bytes, {actual} arrived")]
    Length { declared: usize, actual: usize },
    #[error("body of {actual} bytes, the sample type has {expected}")]
    SampleSize { actual: usize, expected: usize },
    #[error("frame: {0}")]
    Frame(String),
}

/// How a service's samples look on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WireType {
    pub type_id: u32,
    /// Fixed-size sample (`Some(size)`) or an RGBD frame (`None`).
    pub sample_size: Option<usize>,
}

impl WireType {
    /// The wire type of a bowden service, `None` for an unknown service.
    pub fn of(service: &str) -> Option<WireType> {
        let (name, kind, size) = service_type(service)?;
        let mut id_bytes = Vec::with_capacity(name.len() + 6);
        id_bytes.extend_from_slice(name.as_bytes());
        id_bytes.extend_from_slice(&kind.to_le_bytes());
        id_bytes.extend_from_slice(&size.to_le_bytes());
        Some(WireType {
            type_id: fnv1a32(&id_bytes),
            sample_size: (kind != KIND_FRAME).then_some(size as usize),
        })
    }
}

/// One message: the header, then `parts` concatenated.
pub fn encode(ty: WireType, parts: &[&[u8]]) -> Vec<u8> {
    let len: usize = parts.iter().map(|p| p.len()).sum();
    let mut out = Vec::with_capacity(HEADER_LEN + len);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&ty.type_id.to_le_bytes());
    out.extend_from_slice(&(len as u32).to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    for p in parts {
        out.extend_from_slice(p);
    }
    out
}

/// The body of a message of type `ty`, checked: magic, type, declared and actual length, and
/// for a sample its exact size.
pub fn decode(ty: WireType, msg: &[u8]) -> Result<&[u8], WireError> {
    if msg.len() < HEADER_LEN {
        return Err(WireError::Short { len: msg.len() });
    }
    let word = |o: usize| u32::from_le_bytes([msg[o], msg[o + 1], msg[o + 2], msg[o + 3]]);
    let magic = [msg[0], msg[1], msg[2], msg[3]];
    if magic != MAGIC {
        return Err(WireError::Magic { got: magic });
    }
    let got = word(4);
    if got != ty.type_id {
        return Err(WireError::Type {
            got,
            expected: ty.type_id,
        });
    }
    let declared = word(8) as usize;
    let body = &msg[HEADER_LEN..];
    if declared != body.len() {
        return Err(WireError::Length {
            declared,
            actual: body.len(),
        });
    }
    if let Some(expected) = ty.sample_size {
        if body.len() != expected {
            return Err(WireError::SampleSize {
                actual: body.len(),
                expected,
            });
        }
    }
    Ok(body)
}

/// Splits a frame body into its header and payload, checked against the header's own sizes
/// and `max_payload`.
pub fn split_frame(body: &[u8], max_payload: usize) -> Result<(RgbdFrameHeader, &[u8]), WireError> {
    use bowden_runtime::Message;
    let hl = core::mem::size_of::<RgbdFrameHeader>();
    if body.len() < hl {
        return Err(WireError::Frame(format!(
            "{} bytes, less than its {hl}-byte header",
            body.len()
        )));
    }
    let h = RgbdFrameHeader::from_bytes(&body[..hl]).ok_or_else(|| WireError::Frame("unreadable header".into()))?;
    let payload = &body[hl..];
    let expected = RgbdFrameHeader::payload_len_for(h.width, h.height);
    if h.payload_len as usize != payload.len() || expected != payload.len() {
        return Err(WireError::Frame(format!(
            "{}x{} frame: header says {} payload bytes, RGB8+depth16 needs {expected}, {} arrived",
            h.width,
            h.height,
            h.payload_len,
            payload.len()
        )));
    }
    if payload.len() > max_payload {
        return Err(WireError::Frame(format!(
            "{} payload bytes exceed the bridge's max_frame_bytes = {max_payload}",
            payload.len()
        )));
    }
    Ok((h, payload))
}

#[cfg(test)]
mod tests {
    use super::*;
    use bowden_interfaces::{services, JointEstimate};
    use bowden_runtime::Message;

    #[test]
    fn a_sample_round_trips_byte_for_byte() {
        let ty = WireType::of(services::JOINT_ESTIMATE).unwrap();
        let mut e = JointEstimate::default();
        e.header.seq = 41;
        e.header.tick = 1234;
        e.header.t_origin_ns = 987_654_321;
        e.n_joints = 5;
        e.q_phy_deg[2] = -12.5;
        let msg = encode(ty, &[e.as_bytes()]);
        let body = decode(ty, &msg).unwrap();
        assert_eq!(JointEstimate::from_bytes(body).unwrap().as_bytes(), e.as_bytes());
    }

    #[test]
    fn malformed_messages_are_refused_with_the_reason() {
        let ty = WireType::of(services::JOINT_ESTIMATE).unwrap();
        let other = WireType::of(services::JOINT_COMMAND).unwrap();
        assert_ne!(ty.type_id, other.type_id);
        let good = encode(ty, &[JointEstimate::default().as_bytes()]);
        assert!(matches!(decode(ty, &good[..10]), Err(WireError::Short { len: 10 })));
        let mut bad = good.clone();
        bad[0] = b'X';
        assert!(matches!(decode(ty, &bad), Err(WireError::Magic { .. })));
        assert!(matches!(decode(other, &good), Err(WireError::Type { .. })));
        let mut trunc = good.clone();
        trunc.pop();
        assert!(matches!(decode(ty, &trunc), Err(WireError::Length { .. })));
        let short = encode(ty, &[&[0u8; 8]]);
        assert!(matches!(
            decode(ty, &short),
            Err(WireError::SampleSize { actual: 8, .. })
        ));
    }

    #[test]
    fn frames_are_checked_against_their_header() {
        let ty = WireType::of(services::RGBD_FRAME).unwrap();
        assert_eq!(ty.sample_size, None);
        let mut h = RgbdFrameHeader {
            width: 4,
            height: 2,
            ..Default::default()
        };
        let payload = vec![7u8; RgbdFrameHeader::payload_len_for(4, 2)];
        h.payload_len = payload.len() as u64;
        let msg = encode(ty, &[h.as_bytes(), &payload]);
        let (h2, p2) = split_frame(decode(ty, &msg).unwrap(), 1 << 20).unwrap();
        assert_eq!(h2, h);
        assert_eq!(p2, &payload[..]);
        // A payload that does not match the header's size, or is larger than allowed.
        let msg = encode(ty, &[h.as_bytes(), &payload[1..]]);
        assert!(split_frame(decode(ty, &msg).unwrap(), 1 << 20).is_err());
        let msg = encode(ty, &[h.as_bytes(), &payload]);
        assert!(split_frame(decode(ty, &msg).unwrap(), 8).is_err());
    }
}
