//! OBJ mesh reader (read_model), then surface sampling of what it returns.
#![no_main]

use libfuzzer_sys::fuzz_target;

mod common;

fuzz_target!(|data: &[u8]| {
    common::model(data, "fuzz.obj");
});
