//! TensorBoard event files, written by hand: no Rust crate that writes
//! them is kept up (tensorboard-rs, the best known, was last released in
//! 2022 on protobuf 2 and says it is inactive), and the format is small.
//!
//! An event file is a TFRecord stream: each record is its length (u64,
//! little-endian), the masked CRC-32C of those 8 bytes, the data, and the
//! masked CRC-32C of the data. The data is a protobuf `Event`
//! (tensorflow/core/util/event.proto): `wall_time` (field 1, double),
//! `step` (2, int64), `file_version` (3, string) or `summary` (5), whose
//! `Summary` holds repeated `value` (1), each a `tag` (1, string) and a
//! `simple_value` (2, float). Only those fields are written.

use std::io;

/// The first event of every file: the format's version.
pub const FILE_VERSION: &str = "brain.Event:2";

/// CRC-32C masked as TFRecord stores it, so that a CRC of data holding
/// CRCs is not itself a plain CRC.
pub fn masked_crc(bytes: &[u8]) -> u32 {
    let crc = crc32c::crc32c(bytes);
    crc.rotate_right(15).wrapping_add(0xa282_ead8)
}

/// One TFRecord: length, its checksum, the data, the data's checksum.
pub fn record(data: &[u8]) -> Vec<u8> {
    let len = (data.len() as u64).to_le_bytes();
    let mut out = Vec::with_capacity(data.len() + 16);
    out.extend_from_slice(&len);
    out.extend_from_slice(&masked_crc(&len).to_le_bytes());
    out.extend_from_slice(data);
    out.extend_from_slice(&masked_crc(data).to_le_bytes());
    out
}

/// Appends a protobuf varint.
fn varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// A field's key: its number and wire type (0 varint, 1 fixed64, 2
/// length-delimited, 5 fixed32).
fn key(out: &mut Vec<u8>, field: u64, wire: u64) {
    varint(out, field << 3 | wire);
}

fn bytes_field(out: &mut Vec<u8>, field: u64, bytes: &[u8]) {
    key(out, field, 2);
    varint(out, bytes.len() as u64);
    out.extend_from_slice(bytes);
}

/// An `Event`'s common fields.
fn event_head(wall_time: f64, step: i64) -> Vec<u8> {
    let mut e = Vec::new();
    key(&mut e, 1, 1);
    e.extend_from_slice(&wall_time.to_le_bytes());
    key(&mut e, 2, 0);
    // int64 as a varint: negative steps take ten bytes (never written).
    varint(&mut e, step as u64);
    e
}

/// The `Event` that opens a file.
pub fn version_event(wall_time: f64) -> Vec<u8> {
    let mut e = event_head(wall_time, 0);
    bytes_field(&mut e, 3, FILE_VERSION.as_bytes());
    e
}

/// An `Event` with one scalar per `(tag, value)`.
pub fn scalars_event(wall_time: f64, step: i64, values: &[(&str, f32)]) -> Vec<u8> {
    let mut summary = Vec::new();
    for (tag, v) in values {
        let mut value = Vec::new();
        bytes_field(&mut value, 1, tag.as_bytes());
        key(&mut value, 2, 5);
        value.extend_from_slice(&v.to_le_bytes());
        bytes_field(&mut summary, 1, &value);
    }
    let mut e = event_head(wall_time, step);
    bytes_field(&mut e, 5, &summary);
    e
}

/// The records at the start of `bytes` that are whole with valid
/// checksums, as (end offset, data): reading stops at the first torn or
/// corrupt record (what a `kill -9` mid-write leaves).
pub fn records(bytes: &[u8]) -> Vec<(usize, &[u8])> {
    let mut out = Vec::new();
    let mut at = 0;
    while let Some(head) = bytes.get(at..at + 12) {
        let (len, crc) = head.split_at(8);
        if masked_crc(len).to_le_bytes() != crc {
            break;
        }
        let n = u64::from_le_bytes(len.try_into().expect("8 bytes"));
        let Some(end) = usize::try_from(n)
            .ok()
            .and_then(|n| (at + 12).checked_add(n))
            .filter(|end| end + 4 <= bytes.len())
        else {
            break;
        };
        let data = &bytes[at + 12..end];
        if masked_crc(data).to_le_bytes() != bytes[end..end + 4] {
            break;
        }
        at = end + 4;
        out.push((at, data));
    }
    out
}

/// A protobuf field as read: its number and value (varints and fixed
/// widths as integers, length-delimited fields as bytes).
#[derive(Debug, Clone, PartialEq)]
pub enum Field<'a> {
    /// Wire type 0.
    Varint(u64),
    /// Wire type 1.
    Fixed64(u64),
    /// Wire type 2.
    Bytes(&'a [u8]),
    /// Wire type 5.
    Fixed32(u32),
}

fn read_varint(bytes: &[u8], at: &mut usize) -> io::Result<u64> {
    let mut v = 0u64;
    for shift in (0..64).step_by(7) {
        let b = *bytes
            .get(*at)
            .ok_or_else(|| bad("a varint runs past the end"))?;
        *at += 1;
        v |= ((b & 0x7f) as u64) << shift;
        if b < 0x80 {
            return Ok(v);
        }
    }
    Err(bad("a varint longer than ten bytes"))
}

fn bad(what: &str) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidData, format!("event file: {what}"))
}

/// The fields of one protobuf message, in order.
pub fn fields(bytes: &[u8]) -> io::Result<Vec<(u64, Field<'_>)>> {
    let mut out = Vec::new();
    let mut at = 0;
    while at < bytes.len() {
        let k = read_varint(bytes, &mut at)?;
        let take = |at: &mut usize, n: usize| -> io::Result<&[u8]> {
            let s = bytes
                .get(*at..at.saturating_add(n))
                .ok_or_else(|| bad("a field runs past the end"))?;
            *at += n;
            Ok(s)
        };
        let field = match k & 7 {
            0 => Field::Varint(read_varint(bytes, &mut at)?),
            1 => Field::Fixed64(u64::from_le_bytes(take(&mut at, 8)?.try_into().expect("8"))),
            2 => {
                let n = read_varint(bytes, &mut at)?;
                Field::Bytes(take(&mut at, usize::try_from(n).unwrap_or(usize::MAX))?)
            }
            5 => Field::Fixed32(u32::from_le_bytes(take(&mut at, 4)?.try_into().expect("4"))),
            w => return Err(bad(&format!("wire type {w}"))),
        };
        out.push((k >> 3, field));
    }
    Ok(out)
}

/// The `step` of an `Event` (0 where it has none, as protobuf reads it).
pub fn event_step(event: &[u8]) -> io::Result<u64> {
    Ok(fields(event)?
        .into_iter()
        .find_map(|(n, f)| match (n, f) {
            (2, Field::Varint(s)) => Some(s),
            _ => None,
        })
        .unwrap_or(0))
}
