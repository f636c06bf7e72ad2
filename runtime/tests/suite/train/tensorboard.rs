//! TensorBoard's event files (`train::log::tensorboard`): CRC32C,
//! TFRecord framing, the protobuf layout of an event.

use sdfl_runtime::train::log::tensorboard::*;

#[test]
fn crc32c_matches_the_standard_check_values() {
    // The CRC catalogue's check value and RFC 3720's 32 zero bytes.
    assert_eq!(crc32c::crc32c(b"123456789"), 0xe306_9283);
    assert_eq!(crc32c::crc32c(&[0u8; 32]), 0x8a91_36aa);
    // The mask by its definition: (crc >> 15 | crc << 17) + 0xa282ead8,
    // worked by hand for the check value.
    assert_eq!(masked_crc(b"123456789"), 0xc78a_b0e5);
}

#[test]
fn a_record_is_framed_as_tfrecord() {
    let r = record(b"abc");
    assert_eq!(r.len(), 8 + 4 + 3 + 4);
    assert_eq!(&r[..8], &3u64.to_le_bytes());
    assert_eq!(&r[8..12], &masked_crc(&3u64.to_le_bytes()).to_le_bytes());
    assert_eq!(&r[12..15], b"abc");
    assert_eq!(&r[15..], &masked_crc(b"abc").to_le_bytes());
    // Two records read back; a torn third or a flipped byte stops reading.
    let mut two = [record(b"abc"), record(b"")].concat();
    assert_eq!(records(&two).len(), 2);
    let whole = two.len();
    two.extend_from_slice(&record(b"torn")[..10]);
    assert_eq!(records(&two).last().map(|r| r.0), Some(whole));
    two[13] ^= 1;
    assert_eq!(records(&two).len(), 0);
}

#[test]
fn a_scalar_event_has_the_protobuf_layout_of_event_proto() {
    let e = scalars_event(1.5, 300, &[("loss", 0.25)]);
    // Event: 1 wall_time (fixed64), 2 step (varint 300 = ac 02),
    // 5 summary { 1 value { 1 tag "loss", 2 simple_value (fixed32) } }.
    let mut want = vec![0x09];
    want.extend_from_slice(&1.5f64.to_le_bytes());
    want.extend_from_slice(&[0x10, 0xac, 0x02, 0x2a, 0x0d, 0x0a, 0x0b, 0x0a, 0x04]);
    want.extend_from_slice(b"loss");
    want.push(0x15);
    want.extend_from_slice(&0.25f32.to_le_bytes());
    assert_eq!(e, want);
    assert_eq!(event_step(&e).unwrap(), 300);
    let v = version_event(2.0);
    let f = fields(&v).unwrap();
    assert_eq!(f[2], (3, Field::Bytes(b"brain.Event:2")));
    assert_eq!(event_step(&v).unwrap(), 0);
    // A truncated message is an error, not a panic.
    assert!(fields(&e[..e.len() - 1]).is_err());
}
