//! Fuzzes the predictions-file reader `evaluate` uses: any bytes must give
//! either arrays or an error message, never a panic, an abort or an
//! allocation beyond the cap the expected shapes set (here 4,096 values an
//! array, as for a 64-car scenario's edge scores).
#![no_main]

use causalcity::analysis::predictions::read_npz_from;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(arrays) = read_npz_from(std::io::Cursor::new(data), |_| Ok(4096)) {
        for array in arrays {
            let values: usize = array.shape.iter().product();
            assert_eq!(values, array.values.len(), "{}: shape and values disagree", array.name);
        }
    }
});
