//! Fuzzes the dataset-spec parser and its checks: any bytes must give either
//! a spec or a SpecError, never a panic, and a spec that passes must expand
//! (plan its first scenario of every group) without panicking either.
#![no_main]

use causalcity::map::CityMap;
use causalcity::plan::Expansion;
use causalcity::spec::DatasetSpec;
use libfuzzer_sys::fuzz_target;
use std::sync::Arc;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    if let Ok(spec) = DatasetSpec::from_json(text) {
        // Keep each run cheap: the dry run plans one scenario per group.
        if spec.groups.len() <= 8 && spec.frames <= 1000 {
            let _ = Expansion::new(spec, Arc::new(CityMap::default()));
        }
    }
});
