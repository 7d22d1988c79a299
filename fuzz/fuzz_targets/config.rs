#![no_main]
//! Fuzzes the gateway's configuration reader (`drivebus serve --config`, `drivebus config
//! check`): any text is either a configuration or one error line naming the place, never a panic.

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    if let Err(e) = drivebus_gateway::GatewayConfig::from_toml("fuzz.toml", text) {
        let line = e.to_string();
        assert!(line.starts_with("fuzz.toml"), "the error names the file: {line}");
        assert!(!line.contains('\n'), "one line: {line:?}");
    }
});
