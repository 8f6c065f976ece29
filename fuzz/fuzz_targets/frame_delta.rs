//! A frame's stored delta bytes (§5.13): zstd blocks of difference-coded
//! columns, or version 4's plain records. Input: a flag byte (bit 0:
//! columns), 4 bytes of record count (little-endian), then the bytes.
#![no_main]

use illumnet::archive::deltas::decode_frame;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if data.len() < 5 {
        return;
    }
    let columns = data[0] & 1 == 1;
    let count = u32::from_le_bytes(data[1..5].try_into().unwrap()) as u64;
    if let Ok(records) = decode_frame(&data[5..], count, columns) {
        assert_eq!(records.len() as u64, count);
    }
});
