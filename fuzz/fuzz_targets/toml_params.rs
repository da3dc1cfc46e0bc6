//! The TOML configuration: `Params::from_toml` (and over a preset) never panics; a
//! configuration that validates survives a round trip through `to_toml`.
#![no_main]

use binpick::{Params, Preset};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(p) = Params::from_toml(text) {
        if p.validate().is_ok() {
            let again = Params::from_toml(&p.to_toml()).expect("to_toml output does not parse");
            assert_eq!(again, p, "round trip changed the parameters");
        }
    }
    let _ = Params::from_toml_over(&Preset::A.params(), text).map(|p| p.validate());
});
