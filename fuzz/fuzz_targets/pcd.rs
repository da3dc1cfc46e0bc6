//! PCD reader: as a cloud (read_cloud) and as a model (read_model).
#![no_main]

use libfuzzer_sys::fuzz_target;

mod common;

fuzz_target!(|data: &[u8]| {
    match binpick_cloud::io::read_cloud_with_colors_from_bytes(data, "fuzz.pcd") {
        Ok(c) => common::check_cloud(&c),
        Err(e) => common::check_err(&e, "fuzz.pcd"),
    }
    common::model(data, "fuzz.pcd");
});
