#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| taxel_fuzz::mcap(data));
